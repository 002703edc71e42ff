"""``handeye sim-robot``: the simulated UR controller (`mocks.ur_sim`) in the foreground."""

from __future__ import annotations

import argparse

NAME = "sim-robot"
HELP = ("run the simulated UR controller (RTDE) in the foreground; "
        "other arguments go to mocks.ur_sim (--host 127.0.0.x, --model ur10, --controller 5.11)")
PASSTHROUGH = True


def add_arguments(p: argparse.ArgumentParser) -> None:
    """No options of its own: everything goes to ``mocks.ur_sim``."""


def run(args) -> int:
    from mocks import ur_sim

    return int(ur_sim.main(args.extra) or 0)
