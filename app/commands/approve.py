"""``handeye approve``: put a re-learnt calibration in use on a cell with ``[monitor] apply = "approve"``
(`handeye.app.cell_state.approve`)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

NAME = "approve"
HELP = "approve the re-learnt calibration a monitoring run holds pending: the run puts it in use and hands it on"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", nargs="?", type=Path, help="the monitoring run (its session directory or its "
                   "calibration_in_use.yaml) or a cell config (.toml: its newest run; default: the embedded cell's)")
    p.add_argument("--version", type=int, help="the version approved (refused unless it is the one pending)")
    p.add_argument("--by", help="who approves (default: user@host)")
    p.add_argument("--wait", type=float, default=0.0, metavar="SECONDS", help="wait up to this long until the run "
                   "has put it in use and every consumer reports it")


def run(args) -> int:
    from handeye.app.calibration_in_use import local_time
    from handeye.app.calibration_versions import who
    from handeye.app.cell_state import CellState, approve, resolve_run

    run_dir = resolve_run(args.run)
    t = time.time()
    version, state = approve(run_dir, args.version, args.by or who(), t)
    by = args.by or who()
    print(f"approved version {version.number} of {run_dir} (predicted error {version.error_mm:.2f} mm) as {by} at "
          f"{local_time(t)}")
    if state.ended:
        print("the run has ended: the run that continues from it (carry_over, or --reference "
              f"{run_dir}) puts it in use at its start and hands it on")
        return 0
    if version.state == "settling":
        print("it is still settling: the run puts it in use once settled")
    deadline = time.monotonic() + args.wait
    while True:
        now = CellState.read(run_dir)
        users = now.doc.get("in_use_by") or {}
        done = now.doc.get("calibration_version") == version.number and all(v == version.number
                                                                           for v in users.values())
        if done or time.monotonic() >= deadline:
            break
        time.sleep(0.5)
    print("\n".join(now.lines()))
    return 0 if done or not args.wait else 5
