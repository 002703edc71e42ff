"""``handeye monitor``: sample while something else moves the robot, keep the camera calibrated.

The run is `handeye.app.runs.monitor` (read-only: it never commands a motion); this module parses and prints.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from handeye.app import exit_status
from handeye.app.calibration_in_use import FILE_NAME as IN_USE_FILE
from handeye.app.commands.common import add_run_options, cell_command, command_with, load_config_args, pose_line
from handeye.app.runs.monitor import MonitorReport, monitor
from handeye.calib import transforms as tf
from handeye.calib.monitor import EngineState
from handeye.calib.setup import Setup

NAME = "monitor"
HELP = "passive: sample while the robot works, alarm when the camera moved"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_run_options(p)
    p.add_argument("--reference", type=Path, help="calibration session (or its result.yaml) that arms the "
                   "monitoring engine at once, or a previous monitoring run (its session) to continue from")
    p.add_argument("--duration", type=float, help="seconds to run (overrides monitor.duration_s)")
    p.add_argument("--max-samples", type=int, help="stop after this many samples")
    p.add_argument("--hook", help="command to run on an alarm (overrides monitor.alarm_hook)")
    p.add_argument("--calibration-hook", help="command to run when the calibration in use changes (armed, re-learnt, "
                   "settled after a re-learn), its file in HANDEYE_CALIBRATION (overrides monitor.calibration_hook)")


def run(args) -> int:
    cfg = load_config_args(args)
    report = monitor(cfg, reference=args.reference)
    print_monitor_summary(report, cfg.setup, next_lines(report, args, calibrate=cell_command(
        "calibrate", args.config, "--yes-move")))
    return exit_status.ALARM if report.moved_alarms else exit_status.PASS


def next_lines(report: MonitorReport, args, *, calibrate: str | None = None) -> list[str]:
    """`handeye.app.shift_record.ShiftRecord.next_steps` of a run typed as ``args``: the calibration in use to hand on,
    the verify command for it, the command that continues from this run and ``calibrate`` (None: not offered)."""
    return report.record.next_steps(report.session / IN_USE_FILE,
                                    continue_with=command_with(args, "--reference", report.session),
                                    verify_with=cell_command("verify", args.config), calibrate=calibrate)


def print_monitor_summary(report: MonitorReport, setup: Setup = Setup.EYE_TO_HAND, next_lines=()) -> None:
    """The state of the cell in plain words first (`handeye.app.shift_record.ShiftRecord.status`), every alarm with its
    local time and what became of it, the live estimate, the move since the cell's first calibration and the
    drift since the calibration in use, then the counts, the files, and ``next_lines``
    (`handeye.app.shift_record.ShiftRecord.next_steps`) with the recording to open."""
    cam = Setup(setup).camera_name
    record = report.record
    if report.estimate is None or record is None:
        print("\nNOT WATCHING: the monitoring engine was never armed: give --reference (a calibration session, or a "
              "previous monitoring run), or let it see enough distinct poses to calibrate itself")
    elif record.last is None:
        level, sentence = record.status()
        print(f"\n{level.upper()}: {sentence} (the engine was armed; the run ended before the robot held a pose "
              f"with the marker in view)")
        print(f"  {cam} in use: {pose_line(report.estimate)}")
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
        from handeye.app.viz import open_command

        lines = (lines or ["next:"]) + [f"  open the recording:  {open_command(report.session / 'recording.rrd')}"]
    if lines:
        print("\n" + "\n".join(lines))
