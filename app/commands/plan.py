"""``handeye plan``: the poses of an active run, planned without moving (dry run), for review.

The planning run is `handeye.app.runs.plan` (plan.json and a rerun recording beside it); this module parses and prints.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from handeye.app.commands.common import add_run_options, cell_command, load_config_args, until_sigma
from handeye.app.runs.plan import PlanOutput, plan

NAME = "plan"
HELP = "plan the calibration poses without moving: plan.json + a rerun recording (replay: calibrate --poses plan.json)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_run_options(p)
    p.add_argument("--prior", type=Path, help="result.json or session of an earlier calibration of this cell "
                   "(default on a simulated cell: the simulator's true mounting)")
    p.add_argument("-o", "--out", type=Path, help="plan file to write (default: plan.json in a new directory under "
                   "session.root, a recording beside it)")
    p.add_argument("--samples", type=int, help="poses at most (overrides calibrate.samples)")
    p.add_argument("--seed", type=int, help="seed of the pose candidates")
    p.add_argument("--until-sigma", type=until_sigma, metavar="MM,DEG",
                   help="plan until the expected 1-sigma is below both (overrides calibrate.target_sigma_mm/deg)")


def run(args) -> int:
    print_plan_summary(plan(load_config_args(args), args.out, prior=args.prior), config=args.config)
    return 0


def print_plan_summary(out: PlanOutput, config: Path | None = None) -> None:
    """The plan's poses, the recording to look at and the command that runs them on the cell of ``config``."""
    d = out.document
    print(f"\nplan: {out.path}   setup: {d['setup']}   prior: {d['prior']}")
    print(f"poses: {len(d['poses'])}   expected robot time: {d['expected_robot_time_s']:.1f} s")
    print("\n| pose | kind | x, y, z [mm] | marker px | expected 1-sigma [mm] | [deg] |\n|---|---|---|---|---|---|")
    for p in d["poses"]:
        xyz = np.asarray(p["T_base_flange"])[:3, 3] * 1e3
        print(f"| {p['index']} | {p['kind']} | {xyz[0]:.0f}, {xyz[1]:.0f}, {xyz[2]:.0f} | "
              f"{p['pixel'][0]:.0f}, {p['pixel'][1]:.0f} | {p['expected_sigma_mm']:.2f} | {p['expected_sigma_deg']:.3f} |")
    if out.recording is not None:
        from handeye.app.viz import open_command

        print(f"\nopen the recording:  {open_command(out.recording)}")
    print(f"replay on the robot: {cell_command('calibrate', config, '--poses', out.path)}")
