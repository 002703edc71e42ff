"""The active run: move the robot through planned (or random, or listed) poses, sample each one, solve.

Works for both setups. Eye-to-hand: static camera, marker on the flange,
``T_base_flange @ T_flange_marker = T_base_cam @ T_cam_marker``. Eye-in-hand:
camera on the flange, static marker, ``T_base_flange @ T_flange_cam @
T_cam_marker = T_base_marker``. Either way the paper's ``A_i X = Y B_i``
(eq. 1) is solved, by default with YKronT' from the marker centers alone.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from handeye.app import devices, planning, provenance, stopping
from handeye.app.acquire import take_sample
from handeye.app.config import CalibrateConfig, Config
from handeye.app.errors import SessionError
from handeye.app.progress import progress_bar, show_sigma
from handeye.app.session import SessionWriter, read_session
from handeye.app.viz import Viz
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError
from handeye.calib.observation import Observation
from handeye.calib.result import CalibrationResult
from handeye.calib.setup import Setup
from handeye.calib.vision.extract import MarkerMeasurement
from handeye.drivers.camera.base import Camera, RGBDFrame
from handeye.drivers.errors import DeviceError, LimitViolationError
from handeye.drivers.robot.base import Robot

log = logging.getLogger(__name__)

#: Samples before the first solve is tried (the fewest any solver takes; too few for one raises and is logged).
MIN_ESTIMATE_SAMPLES = 3


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


def calibrate(cfg: Config, *, resume: Path | None = None, progress: bool = True,
              confirm: Callable[[], None] = lambda: None) -> CalibrationOutput:
    """Active calibration with the configured robot and camera.

    ``resume``: a session (same setup) to continue; its samples count towards
    ``calibrate.samples`` and new ones are appended to it. ``confirm``: called
    once the robot and the camera are connected, before anything moves or a
    session is written (raises to refuse): a question asked before a
    connection that then fails would be asked for nothing.

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
        confirm()
        truth = devices.truth(camera)
        if resume is not None:
            writer = SessionWriter.resume(resume)
        else:
            writer = SessionWriter.create(cfg.session.root, cfg.setup, config=cfg.to_dict(),
                                          intrinsics=dataclasses.asdict(camera.intrinsics), truth=truth,
                                          devices=provenance.device_identity(cfg, robot, camera))
        with writer, devices.make_viz(cfg, writer.path) as viz:
            recording = viz.rrd_path
            T_true = devices.camera_truth(cfg.setup, truth)
            if T_true is not None:
                viz.truth(T_true)
            poses = planning.make_pose_source(cfg, robot, camera.intrinsics, robot.read().T_base_flange, rng)
            with progress_bar(total=cfg.calibrate.samples, initial=len(initial), enabled=progress) as bar:
                report = run_calibration(robot, camera, devices.make_measure(cfg),
                                         devices.make_solve(cfg.calibrate, cfg.setup, rng, robot.shared_error_factor,
                                                            cfg.marker),
                                         writer, cfg.calibrate,
                                         rng, viz, save_frames=cfg.session.save_frames, progress=bar,
                                         initial=initial, poses=poses)
    cell = provenance.cell(cfg.report, writer.header.get("devices"))
    files = (devices.write_result(report.result, writer.path, cfg.session.exports, cfg.frames.model_dump(),
                                  samples_from=writer.path.resolve(), cell=cell) if report.result is not None else {})
    if "json" in files:
        _add_run_summary(files["json"], report, cfg.calibrate.poses)
    if report.result is not None:
        files["report"] = write_run_report(report.result, writer.path, read_session(writer.path).observations,
                                           cfg.frames.model_dump(), samples_from=writer.path.resolve(), cell=cell)
    return CalibrationOutput(report, cfg.setup, cfg.calibrate.method, files, devices.camera_truth(cfg.setup, truth),
                             recording, cfg.frames.model_dump())


def write_run_report(result: CalibrationResult, directory: Path, observations, frames: dict | None = None, *,
                     samples_from=None, cell: dict | None = None) -> Path:
    """``report.html`` of a calibration (`handeye.app.report`) beside its result files (the document of result.yaml:
    `handeye.app.formats.result_to_dict` with the same ``samples_from`` and ``cell``)."""
    from handeye.app.formats import result_to_dict
    from handeye.app.report import write_report

    return write_report(directory, result_doc=result_to_dict(result, frames, samples_from, cell),
                        observations=observations)


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
        ``next(state, estimate, observations) -> Target | None`` (`handeye.app.planning`);
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
    run = _ActiveRun(robot, camera, measure, solve, writer, cfg, viz, save_frames, progress,
                     list(initial or []))
    if len(run.observations) >= MIN_ESTIMATE_SAMPLES:
        try:
            run.estimate = solve(run.observations, final=False)
        except CalibrationError as e:
            log.info("no estimate from the %d resumed samples: %s", len(run.observations), e)
    run.loop(poses, start)
    result = run.final_solve()
    return RunReport(result, writer.path, len(run.observations), run.n_skipped, run.stopped_by,
                     time.monotonic() - t0, dict(writer.skip_reasons), run.n_motions, run.robot_time)


@dataclass
class _ActiveRun:
    """The devices and running state of `run_calibration`; one method per stage of an attempt."""

    robot: Robot
    camera: Camera
    measure: Callable[[RGBDFrame], MarkerMeasurement]
    solve: Callable[..., CalibrationResult]
    writer: SessionWriter
    cfg: CalibrateConfig
    viz: Viz
    save_frames: bool
    progress: object
    observations: list[Observation]
    estimate: CalibrationResult | None = None
    n_skipped: int = 0
    n_motions: int = 0
    robot_time: float = 0.0
    missed: int = 0  # consecutive frames without a marker measurement
    stopped_by: str = "max_attempts"

    def loop(self, poses, start: np.ndarray) -> None:
        """Attempts until one returns a reason to stop, then back to ``start``; Ctrl-C stops the robot."""
        try:
            for attempt in range(self.cfg.max_attempts):
                reason = self.attempt(attempt, poses)
                if reason is not None:
                    self.stopped_by = reason
                    break
            self.robot.move_to(start)
        except DeviceError as e:
            # Leave the reason in the session next to the samples it kept, then report it.
            self.writer.add_event(time.time(), "device_error", error=str(e), n_samples=len(self.observations))
            raise
        except KeyboardInterrupt:
            stopping.winding_down()
            self.robot.stop()
            # The session is what was kept: a Ctrl-C while a sample's line was being synced to disk leaves
            # the sample in the session but not yet in this run's list.
            self.observations = read_session(self.writer.path).observations
            self.stopped_by = "interrupted"
            log.warning("interrupted: robot stopped, %d samples kept in %s", len(self.observations),
                        self.writer.path)
            self.writer.add_event(time.time(), "interrupted", n_samples=len(self.observations))
            self.viz.event(time.time(), "interrupted by user; robot stopped", "WARN")
        if self.stopped_by != "interrupted":  # (an interruption has its own event)
            self.writer.add_event(time.time(), "stopped", stopped_by=self.stopped_by,
                                  n_samples=len(self.observations), n_skipped=self.n_skipped,
                                  n_motions=self.n_motions, robot_time_s=self.robot_time, poses=self.cfg.poses)

    def attempt(self, attempt: int, poses) -> str | None:
        """One pose: plan, move, sample, estimate. Returns why the run stops, or None to go on."""
        if len(self.observations) >= self.cfg.samples:
            return "samples"
        target = poses.next(self.robot.read(), self.estimate, self.observations)
        if target is None:
            return poses.done_reason
        if target.skip is not None:
            # Not worth a motion (e.g. the marker would leave the image).
            log.debug("pose %d skipped: %s", attempt, target.skip)
            self.writer.add_skip(time.time(), target.skip, T_base_flange=target.T_base_flange)
            self.n_skipped += 1
            return None
        state = self.move(attempt, target)
        if state is None:
            return None
        time.sleep(self.cfg.settle_s)
        # Only a frame exposed after the arm settled (plus settle_s for the plate to stop
        # vibrating) pairs with a still pose; older frames queued during the motion are dropped.
        obs = take_sample(self.robot, self.camera, self.measure, self.writer, self.viz,
                          not_before=state.t_host + self.cfg.settle_s, save_frames=self.save_frames,
                          pose_kind=target.kind)
        if obs is None:
            return self.no_sample()
        self.missed = 0
        self.observations.append(obs)
        if self.progress is not None:
            self.progress.update(1)
        return self.update_estimate(obs)

    def move(self, attempt: int, target):
        """The robot state at ``target`` (no motion if the flange stands there); None, skip recorded, past a limit."""
        try:
            state = self.robot.read()
            rot, dist = tf.pose_error(state.T_base_flange, target.T_base_flange)
            if dist > 1e-3 or rot > np.deg2rad(0.1):  # (a target where the flange stands needs no motion)
                t_move = time.monotonic()
                state = self.robot.move_to(target.T_base_flange)
                self.robot_time += time.monotonic() - t_move
                self.n_motions += 1
        except LimitViolationError as e:
            log.info("pose %d skipped: %s", attempt, e)
            self.writer.add_skip(time.time(), f"limit: {e}", T_base_flange=target.T_base_flange)
            self.n_skipped += 1
            return None
        return state

    def no_sample(self) -> str | None:
        """A frame without a marker measurement: ``"no_marker"`` after ``max_missed_frames`` in a row."""
        self.n_skipped += 1
        self.missed += 1
        if self.missed < self.cfg.max_missed_frames:
            return None
        # The camera does not see the marker at all: more motions would not change that.
        saw = _what_the_camera_saw(self.writer.skip_reasons)
        log.error("gave up after %d consecutive frames without a marker; the camera saw: %s", self.missed, saw)
        self.writer.add_event(time.time(), "gave_up", missed_frames=self.missed, camera_saw=saw)
        self.viz.event(time.time(), f"gave up: {self.missed} frames without a marker ({saw})", "ERROR")
        return "no_marker"

    def update_estimate(self, obs: Observation) -> str | None:
        """Solve with the new sample; ``"target_sigma"`` once enough samples are precise enough."""
        if len(self.observations) < MIN_ESTIMATE_SAMPLES:
            self.viz.sample(obs, None)
            return None
        try:
            self.estimate = self.solve(self.observations, final=False)
        except CalibrationError as e:
            log.info("no estimate yet with %d samples: %s", len(self.observations), e)
            self.estimate = None
            return None
        self.viz.sample(obs, self.estimate.camera_transform)
        self.viz.estimate(obs.t, self.estimate, self.observations)
        show_sigma(self.progress, self.estimate)
        if len(self.observations) >= self.cfg.min_samples and precise_enough(self.estimate, self.cfg):
            return "target_sigma"
        return None

    def final_solve(self) -> CalibrationResult | None:
        """The refined solve of every sample (None with fewer than 3, or when it fails: logged and recorded;
        also None after a Ctrl-C during the solve: recorded as an interruption, the samples kept)."""
        result = None
        if len(self.observations) >= 3:
            try:
                if self.stopped_by == "interrupted":
                    with stopping.skippable():
                        result = self.solve(self.observations, final=True, stopped_early=self.stopped_early())
                else:
                    result = self.solve(self.observations, final=True)
                self.viz.estimate(self.observations[-1].t, result, self.observations)
                self.viz.result(self.observations[-1].t, result)
            except CalibrationError as e:
                log.error("final solve failed: %s", e)
                self.writer.add_event(time.time(), "solve_failed", error=str(e))
            except KeyboardInterrupt:
                # Ctrl-C (a first one, or a second after the one that stopped the robot) during the solve of
                # the kept samples: the run ends as interrupted, its --resume solves them again.
                self.stopped_by = "interrupted"
                log.warning("final solve interrupted: %d samples kept in %s", len(self.observations),
                            self.writer.path)
                self.writer.add_event(time.time(), "interrupted", n_samples=len(self.observations),
                                      stage="final solve")
        return result

    def stopped_early(self) -> str:
        """The verdict's reason for a run stopped by Ctrl-C: the samples taken, the target not reached, and why
        the progress line's 1-sigma (the camera's position) is larger than the error over the workspace."""
        cfg, n = self.cfg, len(self.observations)
        target = f"{cfg.samples} samples"
        if cfg.target_sigma_mm > 0 and cfg.target_sigma_deg > 0:
            target = (f"the camera transform's 1-sigma below {cfg.target_sigma_mm:g} mm / {cfg.target_sigma_deg:g} "
                      f"deg, at most {cfg.samples} samples")
            if self.estimate is not None and self.estimate.sigma is not None:
                s_rot, s_t = self.estimate.sigma
                target += (f"; it was {s_t * 1e3:.2f} mm / {np.rad2deg(s_rot):.3f} deg, the progress line's 1-sigma: "
                           "the camera's own position, worst axis, which the samples fix less well than the "
                           "workspace where they saw the marker")
        return (f"the run was stopped early (Ctrl-C) after {n} samples, before its target ({target}): continue it "
                "with --resume to reach the target")


def _what_the_camera_saw(skip_reasons: dict) -> str:
    """The most frequent skip reasons of this run, e.g. ``"10x marker 7 of DICT_4X4_50 not found"``."""
    top = sorted(skip_reasons.items(), key=lambda kv: -kv[1])[:3]
    return "; ".join(f"{n}x {why}" for why, n in top) or "nothing recorded"


def precise_enough(estimate: CalibrationResult, cfg: CalibrateConfig) -> bool:
    """Predicted 1-sigma of the camera transform below both targets (a target of 0 disables this)."""
    if estimate.sigma is None or cfg.target_sigma_mm <= 0 or cfg.target_sigma_deg <= 0:
        return False
    s_rot, s_t = estimate.sigma
    return s_t * 1e3 <= cfg.target_sigma_mm and np.rad2deg(s_rot) <= cfg.target_sigma_deg
