"""``handeye verify``: judge a calibration result on samples it did not see, in the base frame, mm and deg.

Active (default; ``-c cell.toml``, or the embedded simulated cell): move to
``[verify] poses`` fresh planned poses spread over the ``[calibrate]`` region,
never the calibration's, measure the marker there and compare it with the one
the result predicts. Passive (``--passive``): the same on samples taken
read-only while production moves the robot (the monitor's sampling). Offline (``--session S``): the same against another
recorded session or an imported file (the cross-session check). Either way:
pass/warn/fail against ``[verify] tolerance_mm / tolerance_deg`` (``--tolerance``),
exit status `handeye.app.exit_status.of_verdict`, ``verify.yaml`` and ``report.html`` in the
verify session (offline: a new directory under ``session.root``).

Eye-to-hand: ``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand:
``X = T_flange_cam``, ``Y = T_base_marker`` (paper eq. 1).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from handeye.app import exit_status
from handeye.app.commands.common import (add_report_options, add_run_options, confirm_motion, load_config_args, program,
                                 tolerance, verdict_lines)
from handeye.app.errors import SessionError
from handeye.app.runs.verify import verify
from handeye.app.session import read_session
from handeye.calib.errors import HandeyeError
from handeye.calib.verdict import per_pose_phrase
from handeye.calib.verify import MIN_POSES

NAME = "verify"
HELP = "judge a result on fresh poses (or another session): error in mm/deg, pass/fail, verify.yaml + report"


def expect_xyz(text: str) -> np.ndarray:
    """``--expect-xyz`` value: ``X,Y,Z`` in mm (camera origin in the base frame, flange frame eye-in-hand)."""
    try:
        xyz = np.array([float(v) for v in text.split(",")])
    except ValueError:
        xyz = np.empty(0)
    if xyz.shape != (3,) or not np.isfinite(xyz).all():
        raise argparse.ArgumentTypeError(f"expected X,Y,Z in mm (e.g. 700,-600,850), got {text!r}")
    return xyz * 1e-3


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--result", type=Path, required=True, help="result.yaml (or the session directory holding it)")
    p.add_argument("--session", type=Path, help="offline: verify against this recorded session or imported file "
                   "instead of moving the robot")
    p.add_argument("--setup", choices=["eye_to_hand", "eye_in_hand"], help="--session: setup of an imported file")
    p.add_argument("--passive", action="store_true", help="read-only: sample while production moves the robot "
                   "(as monitor: still robot, a pose unlike the recent ones) until verify.poses samples or "
                   "monitor.duration_s; never moves the robot")
    add_run_options(p)
    add_report_options(p)
    p.add_argument("--yes-move", action="store_true", help="allow robot motion without the confirmation prompt")
    # (dest: calibrate's --poses names a pose source, which the shared config overrides read as args.poses)
    p.add_argument("--poses", type=int, dest="verify_poses", metavar="K",
                   help="active: number of verification poses (overrides verify.poses)")
    p.add_argument("--seed", type=int, dest="verify_seed", metavar="SEED",
                   help="seed of the verification poses (overrides verify.seed)")
    p.add_argument("--tolerance", type=tolerance, metavar="MM,DEG",
                   help="pass/fail tolerances (override verify.tolerance_mm/_deg)")
    p.add_argument("--expect-xyz", type=expect_xyz, metavar="X,Y,Z",
                   help="rough camera position in mm (tape measure, CAD: base frame eye-to-hand, flange frame "
                   "eye-in-hand): warn if the result is far from it or its inverse fits it better")


def _config(args):
    from handeye.app.config import config_from_dict

    cfg = load_config_args(args)
    ver = {}
    if args.verify_poses is not None:
        ver["poses"] = args.verify_poses
    if args.verify_seed is not None:
        ver["seed"] = args.verify_seed
    if args.tolerance is not None:
        ver["tolerance_mm"], ver["tolerance_deg"] = args.tolerance
    data = cfg.model_dump()
    data["verify"].update(ver)
    return config_from_dict(data, "command line")


def run(args) -> int:
    if args.passive and args.session is not None:
        raise HandeyeError("--passive samples the cell, --session verifies against a recording: give one of them")
    resumable = continue_note(args.result)
    if resumable is not None:
        if not (args.result / "result.yaml" if args.result.is_dir() else args.result).exists():
            raise SessionError(f"no result to verify: {resumable}")
        print(f"note: {resumable}")
    out = verify(_config(args), args.result, session=args.session, setup=args.setup, passive=args.passive,
                 expect_xyz=args.expect_xyz, confirm=lambda: confirm_motion(args.yes_move))
    stopped = "" if args.passive else "robot stopped; "      # (passive never moves it)
    measured = f"{out.n_poses} pose{'' if out.n_poses == 1 else 's'} measured"
    if out.interrupted and out.doc is None:
        print(f"interrupted: {stopped}{measured}, fewer than the {MIN_POSES} a verification needs: nothing judged "
              f"(session {out.session})")
        return exit_status.INTERRUPTED
    if out.interrupted:
        print(f"interrupted: {stopped}{measured} (session {out.session})")
    print_verify_summary(out.doc, out.path, out.report, verbose=args.verbose > 0, verification=out.verification)
    if out.interrupted:
        return exit_status.INTERRUPTED
    return exit_status.of_verdict((out.doc.get("verdict") or {}).get("level", "pass" if out.passed else "fail"))


def continue_note(result: Path) -> str | None:
    """When ``result`` (a result file or its session) comes from a calibration stopped by Ctrl-C and not
    continued since (`handeye.app.session.Session.interrupted`): what it holds and the command that continues it."""
    directory = result if result.is_dir() else result.parent
    if not (directory / "session.json").exists():
        return None
    try:
        session = read_session(directory)
    except SessionError:
        return None  # verify itself reports an unreadable session
    if not session.interrupted:
        return None
    command = (f"{program()} demo [-c <config>] --resume {directory}" if session.truth
               else f"{program()} calibrate -c <the cell's config> --resume {directory}")
    return (f"the calibration in {directory} was interrupted (Ctrl-C) after {len(session.observations)} samples; "
            f"continue it with: {command}")


def print_verify_summary(doc: dict, path: Path, report: Path, *, verbose: bool = False,
                         verification=None) -> None:
    """The verdict first, what the per-pose errors are made of, the ROS/URDF export's and the simulator's
    figures, what to do next; ``verbose``: every pose and the statistics."""
    v = doc["verification"]
    print(f"\nverify ({doc['mode']}): {doc['result']['path']} against {doc['source']} ({doc['setup']}, "
          f"{v['n_poses']} poses)\n")
    for line in verdict_lines(doc.get("verdict")):
        print(line)
    if verification is not None:
        print(f"\n{per_pose_phrase(verification)}")
    if "rigid_export" in doc:
        r = doc["rigid_export"]
        print(f"the ROS/URDF transform (camera_transform_raw_points, uncorrected points): calibration error "
              f"{r['calibration_error_mm']:.2f} mm ({'within' if r['passed'] else 'OUTSIDE'} the tolerance)")
    if "truth" in doc:
        print(f"simulator: the result's true error over these poses is {doc['truth']['calibration_error_mm']:.2f} mm")
    if verbose:
        print_verify_statistics(doc)
    failed = (doc.get("verdict") or {}).get("level") == "fail"
    print("\nnext:\n" + ("  do not use this result: recalibrate (the reasons above say what to change)\n" if failed else "")
          + f"  hand over the report: {report}\n  verify.yaml (the figures): {path}")


def print_verify_statistics(doc: dict) -> None:
    """``--verbose``: every pose's error and the statistics of the verification."""
    v = doc["verification"]
    obs = v["observed_mm"]
    print("\n| pose | error [mm] | error [deg] |\n|---|---|---|")
    per_deg = v["per_pose_deg"] or [None] * v["n_poses"]
    repeated = set(doc.get("repeated_calibration_poses") or [])
    for i, (mm, deg) in enumerate(zip(v["per_pose_mm"], per_deg)):
        print(f"| {i}{' (repeats a calibration pose)' if i in repeated else ''} | {mm:.2f} | "
              f"{'-' if deg is None else f'{deg:.3f}'} |")
    print("\n| quantity | value |\n|---|---|")
    print(f"| observed error [mm] mean / p95 / max | {obs['mean']:.2f} / {obs['p95']:.2f} / {obs['max']:.2f} |")
    if v["observed_deg"] is not None:
        od = v["observed_deg"]
        print(f"| observed error [deg] mean / p95 / max | {od['mean']:.3f} / {od['p95']:.3f} / {od['max']:.3f} |")
    if v["measurement_noise_rms_mm"] is not None:
        print(f"| measurement noise (noise model) [mm] | {v['measurement_noise_rms_mm']:.2f} |")
    if v.get("measurement_noise_rms_deg") is not None:
        print(f"| measurement noise (noise model) [deg] | {v['measurement_noise_rms_deg']:.3f} |")
    lo, hi = v["calibration_error_ci95_mm"]
    print(f"| calibration error [mm] (noise removed), 95 % interval | {v['calibration_error_mm']:.2f} "
          f"[{lo:.2f}, {hi:.2f}] |")
    if v["calibration_error_deg"] is not None:
        lo, hi = v["calibration_error_ci95_deg"]
        print(f"| calibration error [deg] (noise removed), 95 % interval | {v['calibration_error_deg']:.3f} "
              f"[{lo:.3f}, {hi:.3f}] |")
    if not v["noise_removed"]:
        print("note: the samples carry no covariance: the calibration error is the observed RMS, noise included")
