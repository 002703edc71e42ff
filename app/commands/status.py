"""``handeye status``: the calibration in use of a monitored cell, who uses which version, what is pending, the last
alarm (`handeye.app.cell_state`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from handeye.app import exit_status

NAME = "status"
HELP = "the calibration in use of a monitored cell: its version, who uses which, pending approvals, the last alarm"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("target", nargs="?", type=Path, help="a monitoring run (its session directory or its "
                   "calibration_in_use.yaml) or a cell config (.toml: its newest run under session.root; default: "
                   "the embedded simulated cell's)")


def run(args) -> int:
    from handeye.app.cell_state import CellState, resolve_run

    state = CellState.read(resolve_run(args.target))
    print("\n".join(state.lines()))
    level = (state.doc.get("status") or {}).get("level")
    return {"moved": exit_status.ALARM, "warn": exit_status.WARN, "drifting": exit_status.WARN}.get(level,
                                                                                                  exit_status.PASS)
