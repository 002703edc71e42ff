"""Taking one sample: a fresh frame, the robot pose at its exposure time, the marker measurement.

Shared by the active run (`handeye.app.runs.calibrate`) and passive monitoring
(`handeye.app.runs.monitor`). The measurement is the same in both setups: the
marker seen from the camera, ``B_i = T_cam_marker`` (or its center) in the
paper's ``A_i X = Y B_i`` with ``A_i = T_base_flange``.
"""

from __future__ import annotations

import logging
import time
from typing import Callable

import numpy as np

from handeye.app.session import SessionWriter
from handeye.app.viz import Viz
from handeye.calib.errors import ExtractionError
from handeye.calib.observation import Observation
from handeye.calib.vision.extract import MarkerMeasurement
from handeye.drivers.camera.base import Camera, RGBDFrame
from handeye.drivers.errors import PoseTimeError
from handeye.drivers.robot.base import Robot

log = logging.getLogger(__name__)


def capture_after(camera: Camera, not_before: float, tries: int = 10) -> RGBDFrame:
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

    Raises
    ------
    PoseTimeError
        ``t`` is older than the robot states buffered, or still ahead of them
        after ``timeout``.
    """
    deadline = time.monotonic() + timeout
    while True:
        try:
            return robot.pose_at(t)
        except PoseTimeError as e:
            if not e.ahead or time.monotonic() > deadline:
                raise
            time.sleep(0.005)


def take_sample(
    robot: Robot,
    camera: Camera,
    measure: Callable[[RGBDFrame], MarkerMeasurement],
    writer: SessionWriter,
    viz: Viz,
    *,
    not_before: float,
    save_frames: bool = True,
    check: Callable[[float], str | None] | None = None,
    pose_kind: str | None = None,
) -> Observation | None:
    """Capture one time-synchronised sample and record it (or its skip reason).

    The robot pose is interpolated at the frame's exposure time
    (``robot.pose_at(frame.t)``), not read after the fact.

    ``check``, if given, is called with the frame's time after the measurement;
    a returned string is a reason to skip the sample (e.g. the robot moved
    during the exposure).
    ``pose_kind`` (e.g. ``"optimal"``, ``"bootstrap"``) is kept in the sample's meta.

    Returns
    -------
    Observation or None
        None when the frame gave no measurement (recorded as a skip).
    """
    frame = capture_after(camera, not_before)
    color, depth = (frame.color, frame.depth) if save_frames else (None, None)
    try:
        T_base_flange = pose_at_frame(robot, frame.t)
    except PoseTimeError as e:
        # The frame is older than the robot states kept (a device came back meanwhile) or the robot's stream
        # lags it by more than the wait: no pose belongs with it.
        reason = "no robot pose at the frame's time"
        log.info("frame %d skipped: %s (%s)", frame.index, reason, e)
        viz.event(frame.t, f"skip: {reason}", "WARN")
        writer.add_skip(frame.t, reason, color=color, depth=depth, detail=str(e))
        return None
    viz.robot(frame.t, T_base_flange)
    try:
        m = measure(frame)
        reason = check(frame.t) if check is not None else None
    except ExtractionError as e:
        reason = str(e)
    if reason is not None:
        log.info("frame %d skipped: %s", frame.index, reason)
        viz.frame(frame.t, frame.color, frame.depth, frame.intrinsics)
        viz.event(frame.t, f"skip: {reason}", "WARN")
        writer.add_skip(frame.t, reason, T_base_flange=T_base_flange, color=color, depth=depth)
        return None
    viz.frame(frame.t, frame.color, frame.depth, frame.intrinsics,
              marker_px=(float(m.center_px[0]), float(m.center_px[1])))
    # The joints with the sample (the robot holds still for one): what a model of its kinematic error needs.
    q = robot.read().q
    obs = Observation.from_measurement(writer.next_index, frame.t, T_base_flange, m, {"frame_index": frame.index},
                                       joints=q)
    if frame.truth:
        obs.meta["truth"] = {k: np.asarray(v).tolist() for k, v in frame.truth.items()}
    if pose_kind is not None:
        obs.meta["pose_kind"] = pose_kind
    return writer.add_sample(obs, color=color, depth=depth)
