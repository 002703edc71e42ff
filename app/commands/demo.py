"""``handeye demo``: calibrate the simulated cell and print the result beside the truth."""

from __future__ import annotations

import argparse

from app import devices
from app.commands.calibrate import CalibrationOutput, calibrate, exit_code, print_calibration_summary
from app.commands.common import add_motion_options, add_run_options, load_config_args
from app.config import Config
from app.errors import ConfigError

NAME = "demo"
HELP = "simulated UR10 + rendered camera: calibrate and compare to the truth"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_run_options(p)
    p.add_argument("--samples", type=int, help="number of samples (default from the config)")
    p.add_argument("--seed", type=int, help="seed of the pose candidates")
    add_motion_options(p)


def run(args) -> int:
    out = demo(load_config_args(args))
    print_calibration_summary(out)
    return exit_code(out)


def demo(cfg: Config, *, progress: bool = True) -> CalibrationOutput:
    """Calibrate the simulated cell: the UR simulator (started by the robot driver, driven
    through the real ur_rtde client) and the rendered camera, whose true pose is known.

    Raises
    ------
    ConfigError
        If the config names real hardware: the demo moves without asking.
    """
    if not devices.simulated(cfg):
        raise ConfigError("demo runs only a simulated cell (a simulated robot.type and camera.backend); "
                          "use 'handeye calibrate' for hardware")
    return calibrate(cfg, progress=progress)
