"""What the commands that run a cell share: the run options, config loading with overrides, motion consent."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from calib import transforms as tf
from calib.errors import HandeyeError


def add_run_options(p: argparse.ArgumentParser) -> None:
    """Options of every command that opens the configured cell (calibrate, monitor, demo)."""
    p.add_argument("-c", "--config", type=Path, help="TOML config (default: the embedded simulated cell)")
    p.add_argument("--session-root", type=Path, help="directory for sessions (overrides session.root)")
    p.add_argument("--no-viz", action="store_true", help="disable rerun logging")
    p.add_argument("--viewer", action="store_true", help="open a live rerun viewer")
    p.add_argument("--viewer-bind", help="address the live viewer listens on (default 127.0.0.1, loopback only)")
    p.add_argument("--no-frames", action="store_true", help="do not store color/depth PNGs in the session")


def apply_overrides(cfg, args):
    """Copy CLI overrides into the config, re-validating the touched sections."""
    cal = {}
    if getattr(args, "samples", None) is not None:
        cal["samples"] = args.samples
        cal["min_samples"] = min(cfg.calibrate.min_samples, args.samples)
    if getattr(args, "seed", None) is not None:
        cal["seed"] = args.seed
    if getattr(args, "method", None) is not None:
        cal["method"] = args.method
    mon = {}
    if getattr(args, "duration", None) is not None:
        mon["duration_s"] = args.duration
    if getattr(args, "max_samples", None) is not None:
        mon["max_samples"] = args.max_samples
    if getattr(args, "hook", None) is not None:
        mon["alarm_hook"] = args.hook
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
    return dataclasses.replace(
        cfg,
        calibrate=dataclasses.replace(cfg.calibrate, **cal),
        monitor=dataclasses.replace(cfg.monitor, **mon),
        viz=dataclasses.replace(cfg.viz, **viz),
        session=dataclasses.replace(cfg.session, **ses),
    )


def load_config_args(args):
    """Config file (or the embedded simulated cell) + CLI overrides, every section validated."""
    from app import devices
    from app.config import load_config

    cfg = apply_overrides(load_config(args.config), args)
    devices.validate(cfg)
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
    answer = input("The robot will move to random poses around its current pose. Continue? [y/N] ")
    if answer.strip().lower() not in ("y", "yes"):
        raise HandeyeError("robot motion not confirmed; nothing moved")


def pose_line(T: np.ndarray) -> str:
    """``xyz [mm] = [...]  quat (x,y,z,w) = [...]`` of a transform, for printing."""
    xyz, q = tf.to_xyz_quat(T)
    return (f"xyz [mm] = {np.array2string(xyz * 1e3, precision=2)}  "
            f"quat (x,y,z,w) = {np.array2string(q, precision=5)}")
