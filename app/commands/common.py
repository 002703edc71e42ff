"""What the commands that run a cell share: the run options, config loading with overrides, motion consent."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

import numpy as np

from handeye.calib import transforms as tf
from handeye.app import progress
from handeye.app.errors import ConfigError
from handeye.calib.errors import HandeyeError


def add_run_options(p: argparse.ArgumentParser) -> None:
    """Options of every command that opens the configured cell (calibrate, monitor, demo)."""
    p.add_argument("-c", "--config", type=Path, help="TOML config (default: the embedded simulated cell)")
    p.add_argument("--session-root", type=Path, help="directory for sessions (overrides session.root)")
    p.add_argument("--no-viz", action="store_true", help="disable rerun logging")
    p.add_argument("--viewer", action="store_true", help="open a live rerun viewer")
    p.add_argument("--viewer-bind", help="address the live viewer listens on (default 127.0.0.1, loopback only)")
    p.add_argument("--no-frames", action="store_true", help="do not store color/depth PNGs in the session")


def add_report_options(p: argparse.ArgumentParser) -> None:
    """Who and where, as report.html and result.yaml name them (override ``[report]``)."""
    p.add_argument("--site", help="plant, as the report names it (overrides report.site)")
    p.add_argument("--cell", help="robot cell, as the report names it (overrides report.cell)")
    p.add_argument("--operator", help="who ran it, as the report names them (overrides report.operator)")


def report_overrides(args) -> dict:
    """The ``[report]`` fields given on the command line (`add_report_options`)."""
    return {k: getattr(args, k) for k in ("site", "cell", "operator") if getattr(args, k, None) is not None}


def _mm_deg(text: str, example: str, what: str, alternative: str = "") -> tuple[float, float]:
    """``MM,DEG``, both positive and finite; `argparse.ArgumentTypeError` otherwise."""
    try:
        mm, deg = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected MM,DEG (e.g. {example}){alternative}, got {text!r}") from None
    if not (mm > 0 and deg > 0 and np.isfinite(mm) and np.isfinite(deg)):
        raise argparse.ArgumentTypeError(f"both {what} must be positive numbers, got {text!r}")
    return mm, deg


def until_sigma(text: str) -> tuple[float, float]:
    """``--until-sigma`` value: ``MM,DEG`` (e.g. ``1,0.1``) or ``off``."""
    if text.strip().lower() in ("off", "0", "0,0"):
        return 0.0, 0.0
    return _mm_deg(text, "1,0.1", "targets", " or 'off'")


def tolerance(text: str) -> tuple[float, float]:
    """``--tolerance`` value: ``MM,DEG``, both positive."""
    return _mm_deg(text, "2,0.5", "tolerances")


def marker_offset(text: str) -> tuple[float, float, float]:
    """``--marker-offset`` value: ``X,Y,Z`` in mm (e.g. ``0,0,52.5``), returned in m."""
    try:
        xyz = tuple(float(v) * 1e-3 for v in text.split(","))
    except ValueError:
        xyz = ()
    if len(xyz) != 3 or not np.isfinite(xyz).all():
        raise argparse.ArgumentTypeError(f"expected X,Y,Z in mm (e.g. 0,0,52.5), got {text!r}")
    return xyz


def add_motion_options(p: argparse.ArgumentParser) -> None:
    """Where an active run moves (calibrate, demo)."""
    p.add_argument("--poses", help="'optimal' (information-planned, default), 'random', or a plan.json "
                   "from 'handeye plan' (overrides calibrate.poses)")
    p.add_argument("--until-sigma", type=until_sigma, metavar="MM,DEG",
                   help="stop once the camera's predicted 1-sigma is below both (e.g. 1,0.1; 'off' disables; "
                   "overrides calibrate.target_sigma_mm/deg)")


def apply_overrides(cfg, args):
    """The config with the CLI overrides, validated again (`ConfigError` names the field)."""
    from handeye.app.config import config_from_dict

    cal = {}
    if getattr(args, "samples", None) is not None:
        cal["samples"] = args.samples
        cal["min_samples"] = min(cfg.calibrate.min_samples, args.samples)
    if getattr(args, "seed", None) is not None:
        cal["seed"] = args.seed
    if getattr(args, "method", None) is not None:
        cal["method"] = args.method
    if getattr(args, "poses", None) is not None:
        cal["poses"] = args.poses
    if getattr(args, "until_sigma", None) is not None:
        cal["target_sigma_mm"], cal["target_sigma_deg"] = args.until_sigma
    mon = {}
    if getattr(args, "duration", None) is not None:
        mon["duration_s"] = args.duration
    if getattr(args, "max_samples", None) is not None:
        mon["max_samples"] = args.max_samples
    if getattr(args, "hook", None) is not None:
        mon["alarm_hook"] = args.hook
    if getattr(args, "calibration_hook", None) is not None:
        mon["calibration_hook"] = args.calibration_hook
    viz = {}
    if getattr(args, "no_viz", False):
        viz["enabled"] = False
    if getattr(args, "viewer", False):
        viz["viewer"] = True
    if getattr(args, "viewer_bind", None) is not None:
        viz["viewer_bind"] = args.viewer_bind
    ses = {}
    if getattr(args, "session_root", None) is not None:
        ses["root"] = str(args.session_root)
    if getattr(args, "no_frames", False):
        ses["save_frames"] = False
    data = cfg.model_dump()
    for section, changes in (("calibrate", cal), ("monitor", mon), ("viz", viz), ("session", ses),
                             ("report", report_overrides(args))):
        data[section].update(changes)
    return config_from_dict(data, "command line")


def load_config_args(args):
    """Config file (or the embedded simulated cell) + CLI overrides, every section validated."""
    from handeye.app import devices
    from handeye.app.config import load_config
    from handeye.app.planning import check_poses_option

    cfg = apply_overrides(load_config(args.config), args)
    try:
        devices.check_session_root(cfg)
    except ConfigError as e:
        if args.config is None:
            raise
        raise ConfigError(f"{args.config}: {e}") from None
    check_poses_option(cfg.calibrate.poses)
    progress.configure(cfg.console)
    return cfg


def confirm_motion(yes_move: bool, *, stdin=None) -> None:
    """Require ``--yes-move`` or a "y" at a TTY prompt before any robot motion.

    Raises
    ------
    HandeyeError
        When refused, or when there is no TTY to ask and no flag.
    """
    if yes_move:
        return
    stdin = stdin or sys.stdin
    if not stdin.isatty():
        raise HandeyeError("refusing to move the robot: no terminal to confirm on; pass --yes-move")
    answer = input("The robot will move to calibration poses around its current pose. Continue? [y/N] ")
    if answer.strip().lower() not in ("y", "yes"):
        raise HandeyeError("robot motion not confirmed; nothing moved")


def command_with(args, option: str, value) -> str:
    """This run's command as typed (``args.argv``, set by `handeye.app.cli.main`), ``option`` (also abbreviated, or with
    ``=``) replaced by ``option value`` at the end, quoted for a shell: the line that continues the run."""
    argv, value_next = [], False
    for arg in args.argv:
        name = arg.split("=", 1)[0]
        if value_next:
            value_next = False
        elif len(name) > 2 and option.startswith(name):
            value_next = "=" not in arg
        else:
            argv.append(arg)
    return shlex.join([program(), *argv, option, str(value)])


def cell_command(name: str, config: Path | None, *extra) -> str:
    """``handeye <name> [-c config] extra...`` quoted for a shell: a command to paste for the same cell."""
    return shlex.join([program(), name, *([] if config is None else ["-c", str(config)]), *map(str, extra)])


def pose_line(T: np.ndarray, *, rpy: bool = False) -> str:
    """``xyz [mm] = [...]  quat (x,y,z,w) = [...]`` of a transform (and URDF's ``rpy [deg]``), for printing."""
    from handeye.app.formats.export import rpy_deg

    xyz, q = tf.to_xyz_quat(T)
    return (f"xyz [mm] = {np.array2string(xyz * 1e3, precision=2)}  "
            f"quat (x,y,z,w) = {np.array2string(q, precision=5)}"
            + (f"  rpy [deg] = {np.array2string(rpy_deg(T), formatter={'float_kind': '{:.3f}'.format})}"
               if rpy else ""))


def program() -> str:
    """The ``handeye`` command as the user typed it (``.venv/bin/handeye``), for the commands printed to paste."""
    typed = sys.argv[0] if sys.argv else ""
    return typed if Path(typed).name == "handeye" else "handeye"


def verdict_lines(verdict: dict | None) -> list[str]:
    """``PASS: <summary>`` and one ``  - <reason>`` line per reason (`handeye.calib.result.Verdict.to_dict`)."""
    from handeye.calib.verdict import WORDS

    if verdict is None:
        return []
    return [f"{WORDS[verdict['level']]}: {verdict['summary']}"] + [f"  - {r}" for r in verdict["reasons"]]


def next_steps(level: str, *, report: Path | None, ros2: str | None, verify: str | None) -> list[str]:
    """What to do with a judged result, as lines to paste: the report to hand over, the ROS 2 line and the
    verification for a ``pass`` or ``warn`` (after checking the reasons); for a ``fail``, not to publish it."""
    lines = ["next:"]
    if level == "fail":
        lines.append("  do not publish this result: fix what the reasons above say and calibrate again"
                     + (f"; the report shows every sample: {report}" if report is not None else ""))
        return lines
    if level == "warn":
        lines.append("  check the reasons above first")
    if report is not None:
        lines.append(f"  hand over the report: {report}  (result.yaml, URDF and ROS 2 launch file beside it)")
    if ros2 is not None:
        lines.append(f"  publish in ROS 2:    {ros2}")
    if verify is not None:
        lines.append(f"  verify on fresh poses: {verify}")
    return lines


def transform_lines(result, *, truth: np.ndarray | None = None) -> list[str]:
    """The camera transform to paste (`CalibrationResult.camera_transform_raw_points`: what the ROS and URDF
    exports carry), the simulator's truth beside it, and which transform goes with which points."""
    from handeye.app.formats.export import which_transform
    from handeye.calib.setup import Setup

    setup = Setup(result.setup)
    parent = "base" if setup == Setup.EYE_TO_HAND else "flange"
    T = result.camera_transform_raw_points
    lines = [f"{setup.camera_name} (the camera's optical frame in the {parent} frame):",
             f"  {pose_line(T, rpy=True)}"]
    if truth is not None:
        # The truth is the camera's pose: what camera_transform estimates (the other absorbs the depth error).
        rot, trans = tf.pose_error(result.camera_transform, truth)
        which = "error" if result.raw_points_fit is None else "camera_transform's error"
        lines.append(f"  truth (simulator): {pose_line(truth)}  {which} {trans * 1e3:.2f} mm / "
                     f"{np.rad2deg(rot):.3f} deg")
    lines.append(f"  {which_transform(result)}")
    return lines
