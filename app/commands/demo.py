"""``handeye demo``: calibrate the simulated cell and print the result beside the truth."""

from __future__ import annotations

import argparse
from pathlib import Path

from app import devices
from app.commands.calibrate import CalibrationOutput, calibrate, exit_code, print_calibration_summary
from app.commands.common import add_motion_options, add_run_options, load_config_args
from app.config import Config
from app.errors import ConfigError
from app.production import Bump
from calib.errors import HandeyeError

NAME = "demo"
HELP = ("simulated UR10 + rendered camera: calibrate and compare to the truth "
        "(--monitor: watch a production program, bump the camera, alarm)")
#: Monitor settings of ``handeye demo --monitor``: quick standstills and a first calibration tried every
#: 4 new poses, so the whole story (arming, bump, alarm, re-learn) fits in about a minute.
DEMO_MONITOR = {"still_s": 0.2, "poll_s": 0.02, "reestimate_samples": 4}


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_run_options(p)
    p.add_argument("--samples", type=int, help="number of samples (default from the config)")
    p.add_argument("--seed", type=int, help="seed of the pose candidates")
    add_motion_options(p)
    p.add_argument("--monitor", action="store_true", help="passive monitoring instead: the simulated robot runs a "
                   "looping production program, the camera is bumped partway; exit status 3 on the alarm")
    p.add_argument("--bump-mm", type=float, default=10.0, help="--monitor: camera shift, mm (default 10; 0 and "
                   "--bump-deg 0 for no bump)")
    p.add_argument("--bump-deg", type=float, default=0.5, help="--monitor: camera rotation, deg (default 0.5)")
    p.add_argument("--bump-after", type=int, default=16, help="--monitor: samples before the bump (default 16)")
    p.add_argument("--reference", type=Path, help="--monitor: session that arms the change detector at once")
    p.add_argument("--max-samples", type=int, help="--monitor: stop after this many samples")


def run(args) -> int:
    if args.monitor:
        return _run_monitor(args)
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


def _run_monitor(args) -> int:
    from app.commands.monitor import EXIT_ALARM, print_monitor_summary

    if args.bump_after < 1:
        raise HandeyeError(f"--bump-after must be >= 1, got {args.bump_after}")
    cfg = load_config_args(args)
    bump = Bump(args.bump_after, args.bump_mm, args.bump_deg) if (args.bump_mm or args.bump_deg) else None
    report = demo_monitor(cfg, bump=bump, reference=args.reference, max_samples=args.max_samples)
    print_monitor_summary(report, cfg.setup)
    return EXIT_ALARM if report.alarms else 0


def demo_monitor(cfg: Config, *, bump: Bump | None, reference: Path | None = None, max_samples: int | None = None,
                 progress: bool = True, publish=None):
    """Passive monitoring of the simulated cell: its controller runs a looping production program,
    the rendered camera is bumped partway (``bump``), the monitor alarms and re-estimates.

    Without ``max_samples`` the run ends a few samples after the re-estimate is due.

    Raises
    ------
    ConfigError
        If the config names real hardware.
    """
    from app.commands.monitor import monitor

    if not devices.simulated(cfg):
        raise ConfigError("demo --monitor runs only a simulated cell (a simulated robot.type and camera.backend); "
                          "use 'handeye monitor' for hardware")
    from app.config import config_from_dict

    data = cfg.model_dump()
    mon = data["monitor"]
    mon.update(DEMO_MONITOR)
    after = bump.after if bump is not None else 0
    mon["max_samples"] = max_samples or (after + 32 if bump else 30)
    mon["duration_s"] = cfg.monitor.duration_s or 300.0
    cfg = config_from_dict(data, "demo --monitor")
    return monitor(cfg, reference=reference, progress=progress, bump=bump, publish=publish)
