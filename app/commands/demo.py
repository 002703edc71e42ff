"""``handeye demo``: calibrate the simulated cell and print the result beside the truth (the run: `handeye.app.runs.demo`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from handeye.app import exit_status
from handeye.app.commands.calibrate import exit_code, print_calibration_summary, print_continue
from handeye.app.commands.common import add_motion_options, add_report_options, add_run_options, load_config_args
from handeye.app.commands.monitor import next_lines, print_monitor_summary
from handeye.app.production import Bump
from handeye.app.runs.demo import demo, demo_monitor
from handeye.calib.errors import HandeyeError

NAME = "demo"
HELP = ("simulated UR10 + rendered camera: calibrate and compare to the truth "
        "(--monitor: watch a production program, bump the camera, alarm)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_run_options(p)
    p.add_argument("--samples", type=int, help="number of samples (default from the config)")
    p.add_argument("--seed", type=int, help="seed of the pose candidates")
    add_motion_options(p)
    p.add_argument("--resume", type=Path, help="continue this demo session (e.g. after Ctrl-C) on the simulated "
                   "cell: its samples count towards --samples, new ones are appended")
    add_report_options(p)
    p.add_argument("--monitor", action="store_true", help="passive monitoring instead: the simulated robot runs a "
                   "looping production program, the camera is bumped partway; exit status 3 on the alarm")
    p.add_argument("--bump-mm", type=float, default=10.0, help="--monitor: camera shift, mm (default 10; 0 and "
                   "--bump-deg 0 for no bump)")
    p.add_argument("--bump-deg", type=float, default=0.5, help="--monitor: camera rotation, deg (default 0.5)")
    p.add_argument("--bump-after", type=int, default=16, help="--monitor: samples before the bump (default 16; the "
                   "moved test runs from the 15th without --reference, the 3rd with it: a bump before is partly taken "
                   "in as the camera watched)")
    p.add_argument("--reference", type=Path, help="--monitor: calibration session that arms the change detector at "
                   "once, or a previous monitoring run to continue from")
    p.add_argument("--max-samples", type=int, help="--monitor: stop after this many samples")


def run(args) -> int:
    if args.monitor:
        return _run_monitor(args)
    out = demo(load_config_args(args), resume=args.resume)
    print_calibration_summary(out, verbose=args.verbose > 0, config=args.config)
    print_continue(out, args)
    return exit_code(out)


def _run_monitor(args) -> int:
    if args.resume is not None:
        raise HandeyeError("--resume continues a calibration; demo --monitor records a new session each run")
    if args.bump_after < 1:
        raise HandeyeError(f"--bump-after must be >= 1, got {args.bump_after}")
    cfg = load_config_args(args)
    bump = Bump(args.bump_after, args.bump_mm, args.bump_deg) if (args.bump_mm or args.bump_deg) else None
    report = demo_monitor(cfg, bump=bump, reference=args.reference, max_samples=args.max_samples)
    # As `monitor` ends: what to hand the re-learnt camera to, how to check it and go on.
    print_monitor_summary(report, cfg.setup, next_lines(report, args))
    return exit_status.ALARM if report.moved_alarms else exit_status.PASS
