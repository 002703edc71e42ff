"""``handeye sim-robot``: the simulated UR controller (`handeye.mocks.ur_sim`) in the foreground."""

from __future__ import annotations

import argparse

from handeye.mocks import ur_sim

NAME = "sim-robot"
HELP = "run the simulated UR controller (RTDE, dashboard and script ports) in the foreground until Ctrl-C"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The simulator's own options (`handeye.mocks.ur_sim.add_arguments`), listed in ``--help``."""
    ur_sim.add_arguments(p)


def run(args) -> int:
    return ur_sim.run(args)
