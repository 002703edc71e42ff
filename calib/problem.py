"""A calibration problem: the validated samples every solver, `auto`, robust, refine, crossval and the monitor take.

Built once (`CalibrationProblem.from_arrays`, `CalibrationProblem.from_observations`)
and checked once there; everything downstream trusts it. Frames (paper eq. 1,
``A_i X = Y B_i``): ``A_i = T_base_flange``, ``B_i = T_cam_marker`` (or the
marker centre in the camera frame). Eye-to-hand ``X = T_flange_marker``,
``Y = T_base_cam``; eye-in-hand ``X = T_flange_cam``, ``Y = T_base_marker``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError, InsufficientDataError
from handeye.calib.model import check_point_cov
from handeye.calib.observation import Observation
from handeye.calib.setup import Setup, check_setup
from handeye.calib.solvers import check_measurements

#: Which measurements a problem built from observations takes: every one the samples carry
#: (``"all"``: the marker centres, and the orientations when every sample has a pose), the
#: centres alone (``"points"``), or the poses as measured (``"poses"``, for the pose-based methods).
MEASUREMENTS = ("all", "points", "poses")


@dataclass(frozen=True, eq=False)
class CalibrationProblem:
    """Samples of one hand-eye calibration, validated.

    Attributes
    ----------
    setup : Setup
        ``eye_to_hand`` or ``eye_in_hand`` (`handeye.calib.setup`).
    A : ndarray, shape (N, 4, 4)
        ``T_base_flange``, m.
    B : ndarray, shape (N, 3) or (N, 4, 4)
        Marker centres in the camera frame (m), or ``T_cam_marker`` poses
        (their translation is the point, their rotation the marker rotation).
    point_cov : ndarray, shape (N, 3, 3), or None
        Covariance of the marker points, m^2; None: the depth model of `handeye.calib.noise`.
    robot_shared_error : ndarray, shape (N, 6, P), or None
        The robot error all samples share, as a factor of the flange-pose error
        (flange-frame twist, rad then m; `handeye.calib.robot_error.ur_dh_error_factor`).
        Only ``auto`` uses it (a "consider" covariance).
    kept : ndarray of int, shape (N,)
        Position of each sample in the observations it was built from (``arange(N)`` from arrays).
    marker_offset : ndarray, shape (3,), or None
        The marker-side translation, known (m): eye-to-hand the marker's
        offset on the flange (``t_flange_marker``), eye-in-hand the static
        marker's position in the base frame (``t_base_marker``). Only ``auto``
        uses it: held at it (to ``marker_offset_sigma``), it completes what
        motions that never turn the tool about two axes leave open.
    marker_offset_sigma : float
        Its 1-sigma per axis, m (0: held as given).
    """

    setup: Setup
    A: np.ndarray
    B: np.ndarray
    point_cov: np.ndarray | None = None
    robot_shared_error: np.ndarray | None = None
    kept: np.ndarray | None = None
    marker_offset: np.ndarray | None = None
    marker_offset_sigma: float = 0.0

    @classmethod
    def from_arrays(cls, A, B, *, setup: Setup = Setup.EYE_TO_HAND, point_cov=None,
                    robot_shared_error=None, marker_offset=None, marker_offset_sigma=0.0) -> "CalibrationProblem":
        """Validate arrays into a problem.

        Parameters
        ----------
        A : array_like, shape (N, 4, 4)
            ``T_base_flange``.
        B : array_like, shape (N, 3) or (N, 4, 4)
            Marker centres in the camera frame, or ``T_cam_marker``.
        setup : {"eye_to_hand", "eye_in_hand"}
        point_cov : array_like, shape (3, 3) or (N, 3, 3), optional
        robot_shared_error : array_like, shape (N, 6, P), optional
        marker_offset : array_like, shape (3,), optional
            The known marker-side translation, m (see the class attributes).
        marker_offset_sigma : float
            Its 1-sigma, m (0: held as given).

        Raises
        ------
        CalibrationError
            Unknown setup, bad shapes, NaN/inf, non-rigid transforms, mismatched N,
            a point at the camera origin; the message names the field.
        """
        setup = check_setup(setup)
        A, B = check_measurements(A, B)
        n = len(A)
        offset, sigma = check_marker_offset(marker_offset, marker_offset_sigma)
        return cls(setup, A, B, check_point_cov(point_cov, n), check_shared_error(robot_shared_error, n),
                   np.arange(n), offset, sigma)

    @classmethod
    def from_observations(cls, observations: Sequence[Observation], setup: Setup, *, measurements: str = "all",
                          robot_shared_error=None, marker_offset=None,
                          marker_offset_sigma=0.0) -> "CalibrationProblem":
        """The problem of a list of samples; samples lacking the measurement asked for are left out.

        ``measurements="all"``: the depth-lifted marker centres ``point_cam``
        with ``point_cov`` and, when every sample has a pose, its orientation
        (the centre takes the place of the pose's origin: both are fixed on
        the marker, so the marker frame just moves to the centre).
        ``"points"``: the centres alone. ``"poses"``: ``T_cam_marker`` as
        measured, with the translation block of ``pose_cov`` as point
        covariance. ``robot_shared_error``: (N, 6, P), one row per observation.
        ``marker_offset``, ``marker_offset_sigma``: as `from_arrays`.
        """
        if measurements not in MEASUREMENTS:
            raise CalibrationError(f"measurements must be one of {', '.join(MEASUREMENTS)}, got {measurements!r}")
        if measurements == "all":
            has_pose = all(o.T_cam_marker is not None for o in observations)
            has_point = all(o.point_cam is not None for o in observations)
            A, B, point_cov, kept = observations_to_arrays(observations, "poses" if has_pose else "points")
            if has_pose and has_point:
                _, centres, point_cov, _ = observations_to_arrays(observations, "points")
                B = B.copy()
                B[:, :3, 3] = centres
        else:
            A, B, point_cov, kept = observations_to_arrays(observations, measurements)
        if robot_shared_error is not None:
            factor = tf.as_real_array(robot_shared_error, "robot_shared_error")
            if factor.ndim == 0 or len(factor) != len(observations):
                raise CalibrationError(f"robot_shared_error must have one row per observation ({len(observations)}), "
                                       f"got shape {factor.shape}")
            robot_shared_error = factor[kept]
        problem = cls.from_arrays(A, B, setup=setup, point_cov=point_cov, robot_shared_error=robot_shared_error,
                                  marker_offset=marker_offset, marker_offset_sigma=marker_offset_sigma)
        return problem.with_kept(kept)

    def with_kept(self, kept) -> "CalibrationProblem":
        """The same samples, numbered by their positions ``kept`` in the source observations."""
        return dataclasses.replace(self, kept=np.asarray(kept, dtype=int))

    @property
    def n(self) -> int:
        """Number of samples."""
        return len(self.A)

    @property
    def has_poses(self) -> bool:
        """Whether ``B`` holds marker poses (orientations measured), not only points."""
        return self.B.ndim == 3

    @property
    def points(self) -> np.ndarray:
        """Marker centres in the camera frame (N, 3), m."""
        return self.B if self.B.ndim == 2 else self.B[:, :3, 3]

    @property
    def marker_rotations(self) -> np.ndarray | None:
        """Measured marker rotations ``R_cam_marker`` (N, 3, 3), or None for point data."""
        return self.B[:, :3, :3] if self.has_poses else None

    def subset(self, index) -> "CalibrationProblem":
        """The samples ``index`` (a boolean mask or indices), without re-validation."""
        idx = np.asarray(index)
        return dataclasses.replace(
            self, A=self.A[idx], B=self.B[idx], point_cov=None if self.point_cov is None else self.point_cov[idx],
            robot_shared_error=None if self.robot_shared_error is None else self.robot_shared_error[idx],
            kept=None if self.kept is None else self.kept[idx])

    def with_measurements(self, B) -> "CalibrationProblem":
        """The same robot poses with other measurements of the same samples (e.g. flips resolved), trusted."""
        return dataclasses.replace(self, B=B)


def check_shared_error(robot_shared_error, n: int) -> np.ndarray | None:
    """Validate a shared robot-error factor (N, 6, P); None passes."""
    if robot_shared_error is None:
        return None
    factor = tf.as_real_array(robot_shared_error, "robot_shared_error")
    if factor.ndim != 3 or factor.shape[:2] != (n, 6) or factor.shape[2] < 1:
        raise CalibrationError(f"robot_shared_error must have shape ({n}, 6, P), got {factor.shape}")
    return factor


def check_marker_offset(marker_offset, sigma) -> tuple[np.ndarray | None, float]:
    """Validate a known marker-side translation (3,), m, and its 1-sigma (m, >= 0); None passes."""
    s = tf.as_real_array(sigma, "marker_offset_sigma")
    if s.shape != () or s < 0.0:
        raise CalibrationError(f"marker_offset_sigma must be one 1-sigma >= 0 (m), got {s.tolist()}")
    if marker_offset is None:
        return None, float(s)
    offset = tf.as_real_array(marker_offset, "marker_offset")
    if offset.shape != (3,):
        raise CalibrationError(f"marker_offset must be 3 numbers (x, y, z in m), got shape {offset.shape}")
    return offset.copy(), float(s)


def observations_to_arrays(observations: Sequence[Observation], kind: str):
    """``(A, B, point_cov, kept)`` of the observations that carry ``kind`` ("points" or "poses").

    For poses the point covariance is the translation block of ``pose_cov``
    mapped through the left-multiplied perturbation: ``J pose_cov J^T``, ``J = [-[t]x, I]``.
    """
    if kind not in ("points", "poses"):
        raise CalibrationError(f"kind must be 'points' or 'poses', got {kind!r}")
    attr = "point_cam" if kind == "points" else "T_cam_marker"
    kept = [i for i, o in enumerate(observations) if getattr(o, attr) is not None]
    if not kept:
        raise InsufficientDataError(f"no observation has a {attr} measurement")
    A = np.stack([np.asarray(observations[i].T_base_flange, dtype=float) for i in kept])
    B = np.stack([np.asarray(getattr(observations[i], attr), dtype=float) for i in kept])
    covs = []
    for i in kept:
        o = observations[i]
        if kind == "points":
            covs.append(None if o.point_cov is None else np.asarray(o.point_cov, dtype=float))
        elif o.pose_cov is not None:
            J = np.hstack([-tf.skew(np.asarray(o.T_cam_marker, dtype=float)[:3, 3]), np.eye(3)])
            covs.append(J @ np.asarray(o.pose_cov, dtype=float) @ J.T)
        else:
            covs.append(None)
    point_cov = None if any(c is None for c in covs) else np.stack(covs)
    return A, B, point_cov, np.asarray(kept, dtype=int)


def as_problem(problem_or_A, B=None, **arrays) -> CalibrationProblem:
    """``problem_or_A`` if it is a `CalibrationProblem`, else the array form ``(A, B, **arrays)`` validated
    (`CalibrationProblem.from_arrays`: ``setup``, ``point_cov``, ``robot_shared_error``, ``marker_offset``,
    ``marker_offset_sigma``)."""
    if isinstance(problem_or_A, CalibrationProblem):
        extra = [k for k, v in arrays.items() if v is not None] + (["B"] if B is not None else [])
        if extra:
            raise CalibrationError(f"{', '.join(extra)} given beside a CalibrationProblem, which carries them")
        return problem_or_A
    if B is None:
        raise CalibrationError("B is missing: pass a CalibrationProblem, or A and B")
    return CalibrationProblem.from_arrays(problem_or_A, B, **{k: v for k, v in arrays.items() if v is not None})
