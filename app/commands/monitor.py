"""``handeye monitor``: sample while something else moves the robot, keep the camera calibrated.

The run is `app.runs.monitor` (read-only: it never commands a motion); this module parses and prints.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from app.commands.common import add_run_options, load_config_args, pose_line
from app.runs.monitor import MonitorReport, detector_state, monitor
from calib import transforms as tf
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
    print_monitor_summary(report, cfg.setup)
    return EXIT_ALARM if report.moved_alarms else 0


def print_monitor_summary(report: MonitorReport, setup: Setup = Setup.EYE_TO_HAND) -> None:
    """Counts, detector state, live estimate with 1-sigma, drift and its rate, every alarm, the re-learnt camera."""
    cam = Setup(setup).camera_name
    print(f"\nsession: {report.session}")
    print(f"samples: {report.n_samples}   skipped: {report.n_skipped}   alarms: {len(report.alarms)}   "
          f"time: {report.elapsed_s:.1f} s   change detector: {detector_state(report.samples_until_armed)}")
    if report.estimate is None:
        print("  estimate: none yet (the monitoring engine is not armed: give --reference, or it arms itself "
              "once auto determines the camera from the samples)")
    else:
        line = f"  estimate {cam}: {pose_line(report.estimate)}"
        if report.estimate_sigma is not None:
            line += f"  1-sigma {report.estimate_sigma[1] * 1e3:.2f} mm {np.rad2deg(report.estimate_sigma[0]):.3f} deg"
        print(line)
    u = report.last
    if report.drift is not None and u is not None:
        rate = "" if u.drift_rate_mm_h is None else f"  rate {u.drift_rate_mm_h:.2f} mm/h {u.drift_rate_deg_h:.3f} deg/h"
        print(f"  drift vs. reference: {report.drift[0]:.2f} mm  {report.drift[1]:.3f} deg{rate}   "
              f"live 1-sigma over the workspace {u.sigma_mm:.2f} mm   last verification {u.verify_mm:.2f} mm")
    for a in report.alarms:
        when = time.strftime('%H:%M:%S', time.localtime(a.t))
        if a.kind == "moved":
            print(f"  ALARM camera moved at sample {a.sample_index} ({when}, "
                  f"GLR statistic {a.info.get('statistic', float('nan')):.1f})")
        else:
            print(f"  ALARM camera drifting at sample {a.sample_index} ({when}): {a.info.get('message', '')}")
    if report.last_alarm is None:
        print("  last alarm: none")
    if report.reestimate is not None:
        print(f"  re-estimate after the move (re-learnt from the production stops): "
              f"{pose_line(report.reestimate.camera_transform)}")
    if report.truth is not None and report.estimate is not None:
        rot, trans = tf.pose_error(report.estimate, report.truth)
        print(f"  simulated camera now: {pose_line(report.truth)}  live estimate {trans * 1e3:.2f} mm / "
              f"{np.rad2deg(rot):.3f} deg from it")
    if report.session is not None and (report.session / "recording.rrd").exists():
        from app.viz import open_command

        print(f"\nopen the recording:  {open_command(report.session / 'recording.rrd')}")
