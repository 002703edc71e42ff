"""``handeye calibrate``: move the robot through planned (or random, or listed) poses, sample each one, solve.

Works for both setups. Eye-to-hand: static camera, marker on the flange,
``T_base_flange @ T_flange_marker = T_base_cam @ T_cam_marker``. Eye-in-hand:
camera on the flange, static marker, ``T_base_flange @ T_flange_cam @
T_cam_marker = T_base_marker``. Either way the paper's ``A_i X = Y B_i``
(eq. 1) is solved, by default with YKronT' from the marker centers alone.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from app import devices, planning
from app.acquire import take_sample
from app.commands.common import add_motion_options, add_run_options, confirm_motion, load_config_args, pose_line
from app.config import CalibrateConfig, Config
from app.errors import SessionError
from app.progress import progress_bar, show_sigma
from app.session import SessionWriter, read_session
from app.viz import Viz
from calib import transforms as tf
from app.formats.export import model_report
from calib.errors import CalibrationError
from calib.observation import Observation
from calib.result import CalibrationResult
from calib.setup import Setup
from calib.vision.extract import MarkerMeasurement
from drivers.camera.base import Camera, RGBDFrame
from drivers.errors import DeviceError, LimitViolationError
from drivers.robot.base import Robot

log = logging.getLogger(__name__)

#: Samples before the first solve is tried (the fewest any solver takes; too few for one raises and is logged).
MIN_ESTIMATE_SAMPLES = 3

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
    return exit_code(out)


@dataclass
class RunReport:
    """What an active or passive run produced.

    Attributes
    ----------
    result : CalibrationResult or None
        Final estimate (None if there were too few samples to solve).
    session : Path
        Session directory (samples, frames, result, .rrd).
    n_samples, n_skipped : int
    stopped_by : str
        ``"samples"``, ``"target_sigma"``, ``"max_attempts"``, ``"interrupted"``, ``"no_marker"``
        (gave up after ``calibrate.max_missed_frames`` consecutive frames without a marker), or the
        pose source's end (``"plan_done"``, ``"no_valid_pose"``, ``"no_estimate_after_bootstrap"``).
    elapsed_s : float
    skip_reasons : dict
        ``{reason: count}`` of this run's skips.
    n_motions : int
        Motions the robot made to sample (the return to the start not counted).
    robot_time_s : float
        Time spent in those motions (until settled), s.
    """

    result: CalibrationResult | None
    session: Path
    n_samples: int
    n_skipped: int
    stopped_by: str
    elapsed_s: float
    skip_reasons: dict = field(default_factory=dict)
    n_motions: int = 0
    robot_time_s: float = 0.0


@dataclass
class CalibrationOutput:
    """An active run and where its outputs went."""

    report: RunReport
    setup: Setup
    method: str
    files: dict
    truth: np.ndarray | None = None
    recording: Path | None = None
    frames: dict | None = None


def calibrate(cfg: Config, *, resume: Path | None = None, progress: bool = True) -> CalibrationOutput:
    """Active calibration with the configured robot and camera (the caller confirmed motion).

    ``resume``: a session (same setup) to continue; its samples count towards
    ``calibrate.samples`` and new ones are appended to it.

    Returns
    -------
    CalibrationOutput
        The run report (result, session path, counts) and the files written.
    """
    initial = []
    if resume is not None:
        previous = read_session(resume)
        if previous.setup != cfg.setup:
            raise SessionError(f"session {resume} is {previous.setup}, the config is {cfg.setup}")
        initial = previous.observations
    # A resumed run must not replay the poses it already visited.
    rng = np.random.default_rng([cfg.calibrate.seed, len(initial)])
    devices.check_session_root(cfg)
    with devices.open_robot(cfg, read_only=False) as robot, devices.open_camera(cfg, robot) as camera:
        truth = devices.truth(camera)
        if resume is not None:
            writer = SessionWriter.resume(resume)
        else:
            writer = SessionWriter.create(cfg.session.root, cfg.setup, config=cfg.to_dict(),
                                          intrinsics=dataclasses.asdict(camera.intrinsics), truth=truth)
        with writer, devices.make_viz(cfg, writer.path) as viz:
            recording = viz.rrd_path
            T_true = devices.camera_truth(cfg.setup, truth)
            if T_true is not None:
                viz.truth(T_true)
            poses = planning.make_pose_source(cfg, robot, camera.intrinsics, robot.read().T_base_flange, rng)
            with progress_bar(total=cfg.calibrate.samples, initial=len(initial), enabled=progress) as bar:
                report = run_calibration(robot, camera, devices.make_measure(cfg),
                                         devices.make_solve(cfg.calibrate, cfg.setup, rng, robot.shared_error_factor),
                                         writer, cfg.calibrate,
                                         rng, viz, save_frames=cfg.session.save_frames, progress=bar,
                                         initial=initial, poses=poses)
    files = (devices.write_result(report.result, writer.path, cfg.session.exports, cfg.frames.model_dump())
             if report.result is not None else {})
    if "json" in files:
        _add_run_summary(files["json"], report, cfg.calibrate.poses)
    if report.result is not None:
        files["report"] = write_run_report(report.result, writer.path, read_session(writer.path).observations,
                                           cfg.frames.model_dump())
    return CalibrationOutput(report, cfg.setup, cfg.calibrate.method, files, devices.camera_truth(cfg.setup, truth),
                             recording, cfg.frames.model_dump())


def write_run_report(result: CalibrationResult, directory: Path, observations, frames: dict | None = None,
                     warnings: list[str] | None = None) -> Path:
    """``report.html`` of a calibration (`app.report`) beside its result files."""
    from app.formats import result_to_dict
    from app.report import write_report

    return write_report(directory, result_doc=result_to_dict(result, frames), observations=observations,
                        warnings=warnings)


def _add_run_summary(path: Path, report: RunReport, poses: str) -> None:
    """Record how the run ended in result.json: samples used, skips, why it stopped, which poses, robot time."""
    doc = json.loads(Path(path).read_text(encoding="utf-8"))
    doc["run"] = {"n_samples": report.n_samples, "n_skipped": report.n_skipped, "stopped_by": report.stopped_by,
                  "poses": poses, "n_motions": report.n_motions, "robot_time_s": report.robot_time_s,
                  "elapsed_s": report.elapsed_s}
    Path(path).write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")


def run_calibration(
    robot: Robot,
    camera: Camera,
    measure: Callable[[RGBDFrame], MarkerMeasurement],
    solve: Callable[..., CalibrationResult],
    writer: SessionWriter,
    cfg: CalibrateConfig,
    rng: np.random.Generator,
    viz: Viz,
    *,
    save_frames: bool = True,
    progress=None,
    initial: list[Observation] | None = None,
    poses=None,
) -> RunReport:
    """Active run: one sample per pose of ``poses``, until enough or precise enough.

    Parameters
    ----------
    robot, camera : connected devices (the robot must allow motion).
    measure : callable(RGBDFrame) -> MarkerMeasurement
        Marker extraction; raises ExtractionError to skip a frame.
    solve : callable(observations, *, final) -> CalibrationResult
        The solver to use (``final=True`` for the last, refined solve).
    writer : SessionWriter
        Every sample and skip is appended and flushed as taken.
    cfg : CalibrateConfig
    rng : numpy.random.Generator
        Source of the random poses when ``poses`` is None (seeded from config/CLI).
    viz : Viz
    progress : tqdm-like, optional
        ``update(1)`` per sample.
    initial : list[Observation], optional
        Samples already in a resumed session; they count towards ``cfg.samples``
        and give the first estimate.
    poses : pose source, optional
        ``next(state, estimate, observations) -> Target | None`` (`app.planning`);
        None draws uniform random poses around the start.

    Returns
    -------
    RunReport
        Ctrl-C stops the robot, keeps every sample and returns with
        ``stopped_by="interrupted"`` (the robot stays where it stopped).
    """
    t0 = time.monotonic()
    start = robot.read().T_base_flange
    if poses is None:
        poses = planning.RandomPoses(start, cfg, camera.intrinsics, rng)
    observations: list[Observation] = list(initial or [])
    estimate: CalibrationResult | None = None
    if len(observations) >= MIN_ESTIMATE_SAMPLES:
        try:
            estimate = solve(observations, final=False)
        except CalibrationError as e:
            log.info("no estimate from the %d resumed samples: %s", len(observations), e)
    n_skipped = n_motions = 0
    robot_time = 0.0
    missed = 0  # consecutive frames without a marker measurement
    stopped_by = "max_attempts"
    try:
        for attempt in range(cfg.max_attempts):
            if len(observations) >= cfg.samples:
                stopped_by = "samples"
                break
            target = poses.next(robot.read(), estimate, observations)
            if target is None:
                stopped_by = poses.done_reason
                break
            if target.skip is not None:
                # Not worth a motion (e.g. the marker would leave the image).
                log.debug("pose %d skipped: %s", attempt, target.skip)
                writer.add_skip(time.time(), target.skip, T_base_flange=target.T_base_flange)
                n_skipped += 1
                continue
            try:
                state = robot.read()
                rot, dist = tf.pose_error(state.T_base_flange, target.T_base_flange)
                if dist > 1e-3 or rot > np.deg2rad(0.1):  # (a target where the flange stands needs no motion)
                    t_move = time.monotonic()
                    state = robot.move_to(target.T_base_flange)
                    robot_time += time.monotonic() - t_move
                    n_motions += 1
            except LimitViolationError as e:
                log.info("pose %d skipped: %s", attempt, e)
                writer.add_skip(time.time(), f"limit: {e}", T_base_flange=target.T_base_flange)
                n_skipped += 1
                continue
            time.sleep(cfg.settle_s)
            # Only a frame exposed after the arm settled (plus settle_s for the plate to stop
            # vibrating) pairs with a still pose; older frames queued during the motion are dropped.
            obs = take_sample(robot, camera, measure, writer, viz, not_before=state.t_host + cfg.settle_s,
                              save_frames=save_frames, pose_kind=target.kind)
            if obs is None:
                n_skipped += 1
                missed += 1
                if missed >= cfg.max_missed_frames:
                    # The camera does not see the marker at all: more motions would not change that.
                    stopped_by = "no_marker"
                    saw = _what_the_camera_saw(writer.skip_reasons)
                    log.error("gave up after %d consecutive frames without a marker; the camera saw: %s", missed, saw)
                    writer.add_event(time.time(), "gave_up", missed_frames=missed, camera_saw=saw)
                    viz.event(time.time(), f"gave up: {missed} frames without a marker ({saw})", "ERROR")
                    break
                continue
            missed = 0
            observations.append(obs)
            if progress is not None:
                progress.update(1)
            if len(observations) >= MIN_ESTIMATE_SAMPLES:
                try:
                    estimate = solve(observations, final=False)
                except CalibrationError as e:
                    log.info("no estimate yet with %d samples: %s", len(observations), e)
                    estimate = None
                else:
                    viz.sample(obs, estimate.camera_transform)
                    viz.estimate(obs.t, estimate, observations)
                    show_sigma(progress, estimate)
                    if len(observations) >= cfg.min_samples and _precise_enough(estimate, cfg):
                        stopped_by = "target_sigma"
                        break
            else:
                viz.sample(obs, None)
        robot.move_to(start)
    except DeviceError as e:
        # Leave the reason in the session next to the samples it kept, then report it.
        writer.add_event(time.time(), "device_error", error=str(e), n_samples=len(observations))
        raise
    except KeyboardInterrupt:
        robot.stop()
        stopped_by = "interrupted"
        log.warning("interrupted: robot stopped, %d samples kept in %s", len(observations), writer.path)
        writer.add_event(time.time(), "interrupted", n_samples=len(observations))
        viz.event(time.time(), "interrupted by user; robot stopped", "WARN")
    if stopped_by != "interrupted":  # (an interruption has its own event)
        writer.add_event(time.time(), "stopped", stopped_by=stopped_by, n_samples=len(observations),
                         n_skipped=n_skipped, n_motions=n_motions, robot_time_s=robot_time, poses=cfg.poses)

    result = None
    if len(observations) >= 3:
        try:
            result = solve(observations, final=True)
            viz.estimate(observations[-1].t, result, observations)
            viz.result(observations[-1].t, result)
        except CalibrationError as e:
            log.error("final solve failed: %s", e)
            writer.add_event(time.time(), "solve_failed", error=str(e))
    return RunReport(result, writer.path, len(observations), n_skipped, stopped_by, time.monotonic() - t0,
                     dict(writer.skip_reasons), n_motions, robot_time)


def _what_the_camera_saw(skip_reasons: dict) -> str:
    """The most frequent skip reasons of this run, e.g. ``"10x marker 7 of DICT_4X4_50 not found"``."""
    top = sorted(skip_reasons.items(), key=lambda kv: -kv[1])[:3]
    return "; ".join(f"{n}x {why}" for why, n in top) or "nothing recorded"


def _precise_enough(estimate: CalibrationResult, cfg: CalibrateConfig) -> bool:
    """Predicted 1-sigma of the camera transform below both targets (a target of 0 disables this)."""
    if estimate.sigma is None or cfg.target_sigma_mm <= 0 or cfg.target_sigma_deg <= 0:
        return False
    s_rot, s_t = estimate.sigma
    return s_t * 1e3 <= cfg.target_sigma_mm and np.rad2deg(s_rot) <= cfg.target_sigma_deg


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
