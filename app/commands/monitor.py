"""``handeye monitor``: sample while something else moves the robot, keep the camera calibrated.

The run is `app.runs.monitor` (read-only: it never commands a motion); this module parses and prints.
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

import numpy as np

from app.calibration_in_use import FILE_NAME as IN_USE_FILE
from app.commands.common import add_run_options, command_with, load_config_args, pose_line, program
from app.runs.monitor import MonitorReport, monitor
from calib import transforms as tf
from calib.monitor import AlarmLevel, EngineState
from calib.setup import Setup

NAME = "monitor"
HELP = "passive: sample while the robot works, alarm when the camera moved"
EXIT_ALARM = 3


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_run_options(p)
    p.add_argument("--reference", type=Path, help="calibration session (or its result.yaml) that arms the "
                   "monitoring engine at once, or a previous monitoring run (its session) to continue from")
    p.add_argument("--duration", type=float, help="seconds to run (overrides monitor.duration_s)")
    p.add_argument("--max-samples", type=int, help="stop after this many samples")
    p.add_argument("--hook", help="command to run on an alarm (overrides monitor.alarm_hook)")


def run(args) -> int:
    cfg = load_config_args(args)
    report = monitor(cfg, reference=args.reference)
    config = [] if args.config is None else ["-c", str(args.config)]
    # A simulated camera starts unmoved in every process: a verification there would judge the re-learnt camera
    # against the one from before the bump.
    verify = None if report.truth is not None else shlex.join([program(), "verify", *config])
    print_monitor_summary(report, cfg.setup, monitor_next_steps(
        report, continue_with=command_with(args, "--reference", report.session), verify_with=verify,
        calibrate=shlex.join([program(), "calibrate", *config, "--yes-move"])))
    return EXIT_ALARM if report.moved_alarms else 0


def monitor_next_steps(report: MonitorReport, *, continue_with: str, verify_with: str | None = None,
                       calibrate: str | None = None) -> list[str]:
    """What to do after a monitoring run, as lines to paste (empty when the engine was never armed).

    After a move the robot program, a ROS tf or anything else given the camera transform before still holds the
    old one: it is told to take the calibration in use (the session's ``calibration_in_use.yaml``), or, while
    the move is not re-learnt yet, to let the monitor go on or recalibrate; a drift it has followed likewise.
    ``continue_with``: the command that continues from this run; ``verify_with``: ``handeye verify`` with the
    cell's config, to check the calibration in use on fresh poses (None: not offered); ``calibrate``: the
    command that recalibrates (None: not offered).
    """
    record = report.record
    if report.estimate is None or record is None or record.last is None or report.session is None:
        return []
    in_use = report.session / IN_USE_FILE
    mm, deg = record.moved_total
    moved = [a for a in record.alarms if a["alarm"] == AlarmLevel.MOVED]
    lines = ["next:"]
    if record.last.state == EngineState.RELEARNING:
        lines.append(f"  the camera moved and the production stops have not re-learnt it yet: what uses the camera "
                     f"transform (the robot program, a ROS tf) is off by about the move; let the monitor run on "
                     f"(below) to re-learn it from the stops"
                     + (f", or recalibrate when the cell is free: {calibrate}" if calibrate else ""))
    elif moved and in_use.exists():
        times = "once" if len(moved) == 1 else f"{len(moved)} times"
        lines.append(f"  the camera moved {times} this run and was re-learnt ({mm:.1f} mm / {deg:.2f} deg since the "
                     f"cell's first calibration): what still holds the camera transform from before (the robot "
                     f"program, a ROS tf) is off by that; give it the calibration in use: {in_use} (its "
                     f"ros2_static_transform_publisher line publishes it)")
        if verify_with:
            lines.append(f"  check it on fresh poses when the cell is free: {verify_with} --result "
                         f"{shlex.quote(str(in_use))} --yes-move")
    elif record.last.level == AlarmLevel.DRIFTING and in_use.exists():
        lines.append(f"  the camera is drifting: {in_use} holds where it is now; give it to what uses the camera "
                     f"transform, and find out what moves the mount")
    lines.append(f"  continue monitoring from where this run left off: {continue_with}")
    return lines


def print_monitor_summary(report: MonitorReport, setup: Setup = Setup.EYE_TO_HAND, next_lines=()) -> None:
    """The state of the cell in plain words first (`app.shift_record.ShiftRecord.status`), every alarm with its
    local time and what became of it, the live estimate, the move since the cell's first calibration and the
    drift since the calibration in use, then the counts, the files and ``next_lines`` (`monitor_next_steps`)
    with the recording to open."""
    cam = Setup(setup).camera_name
    record = report.record
    if report.estimate is None or record is None or record.last is None:
        print("\nNOT WATCHING: the monitoring engine was never armed: give --reference (a calibration session, or a "
              "previous monitoring run), or let it see enough distinct poses to calibrate itself")
    else:
        level, sentence = record.status()
        print(f"\n{level.upper()}: {sentence}")
        for line in record.alarm_lines():
            print(line)
        line = f"  live {cam}: {pose_line(report.estimate)}"
        if report.estimate_sigma is not None:
            line += f"  1-sigma {report.estimate_sigma[1] * 1e3:.2f} mm {np.rad2deg(report.estimate_sigma[0]):.3f} deg"
        print(line)
        u = report.last
        mm, deg = record.moved_total
        rate = "" if u.drift_rate_mm_h is None else f" at {u.drift_rate_mm_h:.2f} mm/h"
        print(f"  moved since the cell's first calibration: {mm:.2f} mm / {deg:.3f} deg; drift since the calibration "
              f"in use: {u.drift_mm:.2f} mm / {u.drift_deg:.3f} deg{rate}; predicted error {u.error_mm:.2f} mm; "
              f"last verification {u.verify_mm:.2f} mm")
    if report.truth is not None and report.estimate is not None:
        rot, trans = tf.pose_error(report.estimate, report.truth)
        print(f"  simulator: the true camera is {trans * 1e3:.2f} mm / {np.rad2deg(rot):.3f} deg from the live estimate")
    if record is not None and record.last is not None and record.last.state == EngineState.RELEARNING:
        watching = "the moved test waits for the re-learn"
    elif report.samples_until_armed == 0:
        watching = "the moved test runs"
    else:
        watching = f"the moved test runs from {report.samples_until_armed} more samples"
    print(f"  {report.n_samples} samples, {report.n_skipped} skipped, {report.elapsed_s:.0f} s; {watching}")
    print(f"\nsession: {report.session}")
    for name in ("report.html", "alarms.yaml", "calibration_in_use.yaml"):
        if report.session is not None and (report.session / name).exists():
            print(f"  {name}: {report.session / name}")
    lines = list(next_lines)
    if report.session is not None and (report.session / "recording.rrd").exists():
        from app.viz import open_command

        lines = (lines or ["next:"]) + [f"  open the recording:  {open_command(report.session / 'recording.rrd')}"]
    if lines:
        print("\n" + "\n".join(lines))
