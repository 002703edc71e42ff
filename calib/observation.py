"""One calibration sample: what the robot reported and what the camera saw.

This is the value type that flows from the extraction step into the session
store and the solvers. Eye-to-hand (static camera, marker on the flange):
``T_base_flange @ T_flange_marker = T_base_cam @ T_cam_marker``. Eye-in-hand
(camera on the flange, static marker): ``T_base_flange @ T_flange_cam @
T_cam_marker = T_base_marker``, solved with ``X = T_flange_cam`` and
``Y = T_base_marker``. In both setups ``A = T_base_flange`` and the camera
measures ``T_cam_marker`` (or just the marker center ``point_cam``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

@dataclass
class Observation:
    """A robot pose and the marker measurement taken at the same instant.

    Attributes
    ----------
    index : int
        Sample number within its session (0-based, never reused).
    t : float
        Host time of the camera frame, seconds (UNIX epoch or session clock).
    T_base_flange : ndarray, shape (4, 4)
        Robot flange pose in the base frame at time ``t`` (m).
    point_cam : ndarray, shape (3,), or None
        Marker center in the camera frame (m); the only input the point-only
        solver YKronT' needs.
    point_cov : ndarray, shape (3, 3), or None
        Covariance of ``point_cam`` (m^2).
    T_cam_marker : ndarray, shape (4, 4), or None
        Full marker pose in the camera frame, for the pose-based solvers.
    pose_cov : ndarray, shape (6, 6), or None
        Covariance of ``T_cam_marker`` as (rotation vector rad, translation m),
        left-multiplied perturbation.
    meta : dict
        Anything else worth keeping (controller time, frame file names,
        detector scores). JSON-serialisable values only.
    joints : ndarray, shape (6,), or None
        The robot's joint angles at the sample (rad), when it reports them:
        what a model of its kinematic error needs (`handeye.calib.robot_error`).
    """

    index: int
    t: float
    T_base_flange: np.ndarray
    point_cam: np.ndarray | None = None
    point_cov: np.ndarray | None = None
    T_cam_marker: np.ndarray | None = None
    pose_cov: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    joints: np.ndarray | None = None

    @classmethod
    def from_measurement(cls, index: int, t: float, T_base_flange: np.ndarray, m, meta: dict | None = None,
                         joints=None) -> "Observation":
        """The sample of a flange pose and a marker measurement (`handeye.calib.vision.extract.MarkerMeasurement`).

        ``meta`` gets the marker kind and the extraction's numeric diagnostics
        (``extract``) after the caller's own entries; ``joints`` (6,) rad when the robot reports them.
        """
        info = {k: float(v) for k, v in m.info.items() if isinstance(v, (int, float, np.floating, np.integer))}
        return cls(index, t, T_base_flange, m.point_cam, m.point_cov, m.T_cam_marker, m.pose_cov,
                   {**(meta or {}), "marker_kind": m.kind, "extract": info},
                   None if joints is None else np.asarray(joints, dtype=float))
