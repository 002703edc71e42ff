"""Active calibration: move the robot through random poses and sample each one.

Works for both setups. Eye-to-hand: static camera, marker on the flange,
``T_base_flange @ T_flange_marker = T_base_cam @ T_cam_marker``. Eye-in-hand:
camera on the flange, static marker, ``T_base_flange @ T_flange_cam @
T_cam_marker = T_base_marker``. Either way the paper's ``A_i X = Y B_i``
(eq. 1) is solved, by default with YKronT' from the marker centers alone.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from app.config import CalibrateConfig
from app.pipeline import Measurement, predicted_pixel, sigma
from app.progress import show_sigma
from app.session import SessionWriter
from app.viz import Viz
from calib import transforms as tf
from calib.errors import CalibrationError, ExtractionError
from drivers.errors import ConnectionLostError, DeviceError, LimitViolationError, RobotStoppedError
from calib.observation import Observation
from calib.result import CalibrationResult
from calib.setup import Setup
from drivers.camera.base import Camera, RGBDFrame
from drivers.robot.base import Robot

log = logging.getLogger(__name__)


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
        ``"samples"``, ``"target_sigma"``, ``"max_attempts"`` or ``"interrupted"``.
    elapsed_s : float
    skip_reasons : dict
        ``{reason: count}`` of this run's skips.
    """

    result: CalibrationResult | None
    session: Path
    n_samples: int
    n_skipped: int
    stopped_by: str
    elapsed_s: float
    skip_reasons: dict = field(default_factory=dict)


def random_pose(T_start: np.ndarray, cfg: CalibrateConfig, rng: np.random.Generator) -> np.ndarray:
    """A flange pose around ``T_start``: each axis offset uniform in +-range, tilt <= cfg.tilt_deg.

    The rotation is applied about the flange origin (in the base frame), so the
    tilt does not swing the flange away from its sampled position.
    """
    T_start = tf.check_transform(T_start, "T_start")
    R = tf.random_rotations(1, np.deg2rad(cfg.tilt_deg), rng)[0]
    dt = rng.uniform(-cfg.translation_range_m, cfg.translation_range_m, size=3)
    return tf.make_transform(R @ T_start[:3, :3], T_start[:3, 3] + dt)


def _capture(camera: Camera, not_before: float, tries: int = 10) -> RGBDFrame:
    """First frame exposed after ``not_before`` (drops frames buffered during the motion)."""
    for _ in range(tries):
        frame = camera.read()
        if frame.t >= not_before:
            return frame
    log.warning("no frame newer than %.3f s in %d reads (camera clock behind the robot's?); using frame %d at %.3f s",
                not_before, tries, frame.index, frame.t)
    return frame


def pose_at_frame(robot: Robot, t: float, timeout: float = 1.0) -> np.ndarray:
    """``robot.pose_at(t)``, waiting up to ``timeout`` s for the robot states around ``t`` to arrive.

    A frame stamped at ``t`` often reaches us before the robot state that
    follows it (a controller tick is 2-8 ms); interpolation needs both sides.
    """
    deadline = time.monotonic() + timeout
    while True:
        try:
            return robot.pose_at(t)
        except (ConnectionLostError, RobotStoppedError):
            raise
        except DeviceError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.005)


def take_sample(
    robot: Robot,
    camera: Camera,
    measure: Callable[[RGBDFrame], Measurement],
    writer: SessionWriter,
    viz: Viz,
    *,
    not_before: float,
    save_frames: bool = True,
    check: Callable[[], str | None] | None = None,
) -> Observation | None:
    """Capture one time-synchronised sample and record it (or its skip reason).

    The robot pose is interpolated at the frame's exposure time
    (``robot.pose_at(frame.t)``), not read after the fact.

    ``check``, if given, is called after the measurement; a returned string is
    a reason to skip the sample (e.g. the robot moved during the exposure).

    Returns
    -------
    Observation or None
        None when the frame gave no measurement (recorded as a skip).
    """
    frame = _capture(camera, not_before)
    T_base_flange = pose_at_frame(robot, frame.t)
    viz.robot(frame.t, T_base_flange)
    color, depth = (frame.color, frame.depth) if save_frames else (None, None)
    try:
        m = measure(frame)
        reason = check() if check is not None else None
    except ExtractionError as e:
        reason = str(e)
    if reason is not None:
        log.info("frame %d skipped: %s", frame.index, reason)
        viz.frame(frame.t, frame.color, frame.depth, frame.intrinsics)
        viz.event(frame.t, f"skip: {reason}", "WARN")
        writer.add_skip(frame.t, reason, T_base_flange=T_base_flange, color=color, depth=depth)
        return None
    viz.frame(frame.t, frame.color, frame.depth, frame.intrinsics, marker_px=m.pixel)
    meta = {"frame_index": frame.index, **m.meta}
    if frame.truth:
        meta["truth"] = {k: np.asarray(v).tolist() for k, v in frame.truth.items()}
    obs = Observation(writer.next_index, frame.t, T_base_flange, m.point_cam, m.point_cov,
                      m.T_cam_marker, m.pose_cov, meta)
    return writer.add_sample(obs, color=color, depth=depth)


def run_calibration(
    robot: Robot,
    camera: Camera,
    measure: Callable[[RGBDFrame], Measurement],
    solve: Callable[..., CalibrationResult],
    writer: SessionWriter,
    cfg: CalibrateConfig,
    setup: Setup,
    rng: np.random.Generator,
    viz: Viz,
    *,
    save_frames: bool = True,
    progress=None,
    initial: list[Observation] | None = None,
) -> RunReport:
    """Active run: random poses, one sample each, until enough or precise enough.

    Parameters
    ----------
    robot, camera : connected devices (the robot must allow motion).
    measure : callable(RGBDFrame) -> Measurement
        Marker extraction; raises ExtractionError to skip a frame.
    solve : callable(observations, *, final) -> CalibrationResult
        The solver to use (``final=True`` for the last, refined solve).
    writer : SessionWriter
        Every sample and skip is appended and flushed as taken.
    cfg : CalibrateConfig
    setup : {"eye_to_hand", "eye_in_hand"}
    rng : numpy.random.Generator
        Source of the random poses (seeded from config/CLI).
    viz : Viz
    progress : tqdm-like, optional
        ``update(1)`` per sample.
    initial : list[Observation], optional
        Samples already in a resumed session; they count towards ``cfg.samples``
        and give the first estimate.

    Returns
    -------
    RunReport
        Ctrl-C stops the robot, keeps every sample and returns with
        ``stopped_by="interrupted"`` (the robot stays where it stopped).
    """
    t0 = time.monotonic()
    start = robot.read().T_base_flange
    observations: list[Observation] = list(initial or [])
    estimate: CalibrationResult | None = None
    if len(observations) >= cfg.min_samples:
        try:
            estimate = solve(observations, final=False)
        except CalibrationError as e:
            log.info("no estimate from the %d resumed samples: %s", len(observations), e)
    n_skipped = 0
    stopped_by = "max_attempts"
    intrinsics = camera.intrinsics
    try:
        for attempt in range(cfg.max_attempts):
            if len(observations) >= cfg.samples:
                stopped_by = "samples"
                break
            target = random_pose(start, cfg, rng)
            if estimate is not None:
                px = predicted_pixel(setup, estimate, target, intrinsics, cfg.image_margin_px)
                if px is None:
                    # Not worth a motion: the marker would leave the image (or face away).
                    log.debug("pose %d skipped: marker predicted outside the image", attempt)
                    writer.add_skip(time.time(), "marker predicted outside the image", T_base_flange=target)
                    n_skipped += 1
                    continue
            try:
                state = robot.move_to(target)
            except LimitViolationError as e:
                log.info("pose %d skipped: %s", attempt, e)
                writer.add_skip(time.time(), f"limit: {e}", T_base_flange=target)
                n_skipped += 1
                continue
            time.sleep(cfg.settle_s)
            # Only a frame exposed after the arm settled (plus settle_s for the plate to stop
            # vibrating) pairs with a still pose; older frames queued during the motion are dropped.
            obs = take_sample(robot, camera, measure, writer, viz, not_before=state.t_host + cfg.settle_s,
                              save_frames=save_frames)
            if obs is None:
                n_skipped += 1
                continue
            observations.append(obs)
            if progress is not None:
                progress.update(1)
            if len(observations) >= cfg.min_samples:
                try:
                    estimate = solve(observations, final=False)
                except CalibrationError as e:
                    log.info("no estimate yet with %d samples: %s", len(observations), e)
                    estimate = None
                else:
                    viz.sample(obs, estimate.camera_transform)
                    viz.estimate(obs.t, estimate, observations)
                    show_sigma(progress, estimate.cov)
                    if _precise_enough(estimate, cfg):
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
                     dict(writer.skip_reasons))


def _precise_enough(estimate: CalibrationResult, cfg: CalibrateConfig) -> bool:
    """Predicted 1-sigma of the camera transform below both targets (a target of 0 disables this)."""
    if estimate.cov is None or cfg.target_sigma_mm <= 0 or cfg.target_sigma_deg <= 0:
        return False
    s_deg, s_mm = sigma(estimate.cov)
    return s_mm <= cfg.target_sigma_mm and s_deg <= cfg.target_sigma_deg
