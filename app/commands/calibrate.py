"""``handeye calibrate``: move the robot through planned (or random, or listed) poses, sample each one, solve.

The run is `app.runs.calibrate`; this module parses, asks before motion and prints.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from app.commands.common import (add_motion_options, add_run_options, confirm_motion, load_config_args, pose_line,
                                 resume_command)
from app.runs.calibrate import CalibrationOutput, calibrate
from calib import transforms as tf
from app.formats.export import model_report
from calib.result import CalibrationResult
from calib.setup import Setup

NAME = "calibrate"
HELP = "active run: move the robot through planned (or random, or listed) poses and calibrate"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_run_options(p)
    p.add_argument("--yes-move", action="store_true", help="allow robot motion without the confirmation prompt")
    p.add_argument("--samples", type=int, help="number of samples (overrides calibrate.samples)")
    p.add_argument("--seed", type=int, help="seed of the random poses (overrides calibrate.seed)")
    p.add_argument("--method", help="solver, paper name (overrides calibrate.method), e.g. \"YKronT'\"")
    p.add_argument("--resume", type=Path, help="continue this session (e.g. after a crash or Ctrl-C)")
    add_motion_options(p)


def run(args) -> int:
    cfg = load_config_args(args)
    confirm_motion(args.yes_move)
    out = calibrate(cfg, resume=args.resume)
    print_calibration_summary(out)
    print_continue(out, args)
    return exit_code(out)


def print_continue(out: CalibrationOutput, args) -> None:
    """After Ctrl-C: the command that continues the run (`app.commands.common.resume_command`)."""
    if out.report.stopped_by == "interrupted":
        print(f"continue this run:   {resume_command(args, out.report.session)}")


def exit_code(out: CalibrationOutput) -> int:
    """130 after Ctrl-C (samples kept), 1 without a calibration, else 0."""
    if out.report.stopped_by == "interrupted":
        return 130
    return 0 if out.report.result is not None else 1


def print_calibration_summary(out: CalibrationOutput) -> None:
    r = out.report
    cam = Setup(out.setup).camera_name
    print(f"\nsession: {r.session}")
    print(f"setup: {out.setup}   solver: {out.method}   samples: {r.n_samples}   skipped: {r.n_skipped}   "
          f"stopped by: {r.stopped_by}   time: {r.elapsed_s:.1f} s (robot motions: {r.n_motions}, "
          f"{r.robot_time_s:.1f} s)")
    reasons = sorted(r.skip_reasons.items(), key=lambda kv: -kv[1])[:3]
    if reasons:
        print("most frequent skips: " + "; ".join(f"{n}x {why}" for why, n in reasons))
    if r.stopped_by == "no_marker":
        print("gave up: too many consecutive frames without a marker (calibrate.max_missed_frames); check that "
              "the marker is in view and the [marker] section names it")
    if r.result is None and r.stopped_by == "interrupted":
        print(f"no calibration: interrupted with {r.n_samples} samples, all kept in {r.session}")
        return
    if r.result is None:
        print(f"no calibration: {r.n_samples} samples are too few (every skip and its reason is in "
              f"{r.session / 'samples.jsonl'})")
        return
    res = r.result
    rows = [("estimate " + cam, pose_line(res.camera_transform))]
    if out.truth is not None:
        rows.append(("truth    " + cam, pose_line(out.truth)))
    for name, line in rows:
        print(f"  {name}: {line}")
    print()
    print("| quantity | value |\n|---|---|")
    print(f"| residual RMS [mm] | {res.residuals.rms_translation * 1e3:.2f} |")
    print(f"| residual max [mm] | {res.residuals.max_translation * 1e3:.2f} |")
    if res.sigma is not None:
        s_rot, s_t = res.sigma
        print(f"| 1-sigma [mm] | {s_t * 1e3:.2f} |\n| 1-sigma [deg] | {np.rad2deg(s_rot):.3f} |")
    if out.truth is not None:
        rot, trans = tf.pose_error(res.camera_transform, out.truth)
        print(f"| error vs truth [mm] | {trans * 1e3:.2f} |\n| error vs truth [deg] | {np.rad2deg(rot):.3f} |")
    for kind, path in out.files.items():
        print(f"| {kind} | {path} |")
    print_model_summary(res)
    print_next_steps(out)


def print_model_summary(res: CalibrationResult) -> None:
    """Camera correction, noise levels and the self-check of ``res`` (`app.formats.export.model_report`), then any warning."""
    rep = model_report(res)
    if rep is None:
        return
    rows = []
    for name, c in rep.get("camera_correction", {}).items():
        if c["estimated"]:
            label = name.replace("_percent", " [%]").replace("_mm", " [mm]").replace("_", " ")
            rows.append((label, f"{c['value']:+.2f} ± {c['sigma']:.2f}"))
    if "raw_points_misfit_mm" in rep:
        cam = Setup(res.setup).camera_name
        rows.append((f"ROS/URDF exports: {cam} for uncorrected points, misfit [mm]",
                     f"{rep['raw_points_misfit_mm']:.2f} (result.yaml: camera_transform_raw_points)"))
    if "noise" in rep:
        rows.append(("robot error [mm] (estimated)", f"{rep['noise']['robot_mm']:.2f}"))
    if "robot_shared_error_mm" in rep:
        rows.append(("robot kinematic error in the 1-sigma [mm]", f"{rep['robot_shared_error_mm']:.2f}"))
    check = rep.get("self_check")
    if check is not None:
        rows.append(("held-out error [mm] observed / predicted",
                     f"{check['heldout_observed_mm']:.2f} / {check['heldout_predicted_mm']:.2f}"))
        rows.append(("chi-square vs camera noise model", f"{check['chi2']:.0f} for {check['dof']} dof"))
    for name, value in rows:
        print(f"| {name} | {value} |")
    for note in rep.get("notes", []):
        print(f"note: {note}")
    if check is not None and check["warning"] and check["warning"] not in rep.get("notes", []):
        print(f"warning: {check['warning']}")


def print_next_steps(out: CalibrationOutput) -> None:
    """How to look at the run (rerun), use its result (ROS 2) and verify it, as commands to paste."""
    from app.formats import ros2_command
    from app.viz import open_command

    print()
    if out.recording is not None and out.recording.exists():
        print(f"open the recording:  {open_command(out.recording)}")
    if out.report.result is not None:
        print(f"publish in ROS 2:    {ros2_command(out.report.result, out.frames)}")
    if "yaml" in out.files:
        # The same -c as this run (the embedded simulated cell without one).
        print(f"verify on fresh poses: handeye verify [-c <config>] --result {out.files['yaml']}")
