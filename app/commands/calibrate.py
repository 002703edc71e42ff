"""``handeye calibrate``: move the robot through planned (or random, or listed) poses, sample each one, solve.

The run is `handeye.app.runs.calibrate`; this module parses, asks before motion and prints.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from handeye.app import exit_status
from handeye.app.commands.common import (add_motion_options, add_report_options, add_run_options, cell_command,
                                 command_with, confirm_motion, load_config_args, next_steps, transform_lines,
                                 verdict_lines)
from handeye.app.runs.calibrate import CalibrationOutput, calibrate
from handeye.app.formats.export import model_report
from handeye.calib.result import CalibrationResult
from handeye.calib.setup import Setup

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
    add_report_options(p)


def run(args) -> int:
    cfg = load_config_args(args)
    out = calibrate(cfg, resume=args.resume, confirm=lambda: confirm_motion(args.yes_move))
    print_calibration_summary(out, verbose=args.verbose > 0, config=args.config)
    print_continue(out, args)
    return exit_code(out)


def print_continue(out: CalibrationOutput, args) -> None:
    """After Ctrl-C: the command that continues the run (`handeye.app.commands.common.command_with` its session)."""
    if out.report.stopped_by == "interrupted":
        print(f"continue this run:   {command_with(args, '--resume', out.report.session)}")


def exit_code(out: CalibrationOutput) -> int:
    """`handeye.app.exit_status`: interrupted after Ctrl-C (samples kept), error without a calibration, else the
    verdict's."""
    if out.report.stopped_by == "interrupted":
        return exit_status.INTERRUPTED
    result = out.report.result
    if result is None:
        return exit_status.ERROR
    return exit_status.of_verdict(None if result.verdict is None else result.verdict.level)


def print_calibration_summary(out: CalibrationOutput, *, verbose: bool = False, config: Path | None = None) -> None:
    """The run in the words of the person who acts on it: the verdict, the transform to paste, what to do next;
    ``verbose``: the statistics too (residuals, 1-sigma, camera correction, self-check, files)."""
    r = out.report
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
    print()
    for line in verdict_lines(None if res.verdict is None else res.verdict.to_dict()):
        print(line)
    print()
    for line in transform_lines(res, truth=out.truth):
        print(line)
    if verbose:
        print_statistics(res, out.files)
    print_next_steps(out, config)


def print_statistics(res: CalibrationResult, files: dict) -> None:
    """``--verbose``: residuals, 1-sigma, the camera correction, noise levels, the self-check, the files written."""
    print("\n| quantity | value |\n|---|---|")
    print(f"| residual RMS [mm] | {res.residuals.rms_translation * 1e3:.2f} |")
    print(f"| residual max [mm] | {res.residuals.max_translation * 1e3:.2f} |")
    if res.sigma is not None:
        s_rot, s_t = res.sigma
        print(f"| 1-sigma of the camera transform, worst axis [mm] | {s_t * 1e3:.2f} |\n"
              f"| 1-sigma of the camera transform, worst axis [deg] | {np.rad2deg(s_rot):.3f} |")
    notes = print_model_summary(res)
    for kind, path in files.items():
        print(f"| {kind} | {path} |")
    for note in notes:
        print(f"note: {note}")


def print_model_summary(res: CalibrationResult) -> list[str]:
    """Camera correction, noise levels and the self-check of ``res`` (`handeye.app.formats.export.model_report`) as
    table rows; returns ``auto``'s notes."""
    rep = model_report(res)
    if rep is None:
        return []
    rows = []
    for name, c in rep.get("camera_correction", {}).items():
        if c["estimated"]:
            label = name.replace("_percent", " [%]").replace("_mm", " [mm]").replace("_", " ")
            rows.append((label, f"{c['value']:+.2f} ± {c['sigma']:.2f}"))
    if "raw_points_misfit_mm" in rep:
        rows.append(("camera_transform_raw_points: misfit of the rigid stand-in for the correction [mm]",
                     f"{rep['raw_points_misfit_mm']:.2f}"))
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
    return list(rep.get("notes", []))


def print_next_steps(out: CalibrationOutput, config: Path | None = None) -> None:
    """What to do with the result (`handeye.app.commands.common.next_steps`), and the recording to look at."""
    from handeye.app.formats import ros2_command
    from handeye.app.viz import open_command

    res = out.report.result
    print()
    for line in next_steps(res.verdict.level if res.verdict is not None else "warn", report=out.files.get("report"),
                           ros2=ros2_command(res, out.frames),
                           verify=cell_command("verify", config, "--result", out.files["yaml"], "--yes-move")
                           if "yaml" in out.files else None):
        print(line)
    if out.recording is not None and out.recording.exists():
        print(f"  open the recording:  {open_command(out.recording)}")
