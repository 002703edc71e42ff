"""Information-optimal flange poses for an active calibration.

Greedy D-optimal design with a travel cost. Given the current estimate of
``A_i X = Y B_i`` (paper eq. 1) and the Fisher information of the samples
taken so far, the planner draws candidate flange poses around the start pose,
screens out those the camera could not measure, scores the rest by the
expected information gain on the camera transform and moves to the best one
the robot can reach:

    gain_j  = log det Sigma_C(I) - log det Sigma_C(I + J_j^T S_j^-1 J_j)
    score_j = gain_j - travel_weight * t_travel(j)

``Sigma_C(I)`` is the camera block of ``I^-1`` (the other unknowns
marginalised), ``J_j`` the Jacobian of the predicted marker point (paper eq. 5)
at candidate ``j`` and ``S_j`` its covariance from the depth model of
`handeye.calib.noise`. Maximising ``gain`` maximises the volume shrink of the camera's
confidence ellipsoid (D-optimality; invariant to the choice of units, so mm
and deg need no weighting). ``t_travel`` is a trapezoidal-profile estimate of
the motion time, so between two equally informative poses the nearer one wins.

Setups: eye-to-hand (``X = T_flange_marker``, ``Y = T_base_cam``; the camera
transform is ``Y``) and eye-in-hand (``X = T_flange_cam``, ``Y =
T_base_marker``; the camera transform is ``X``). Poses are ``T_base_flange``.

Validity is split by who knows what. This module checks what the camera model
decides (marker center and corners inside the image with a margin widened by
the predicted pixel uncertainty, depth range, marker facing the camera within
a maximum angle) and optional keep-out boxes along the straight path; the
robot's own checks (IK within joint limits continuous from the current joints,
workspace box, tilt cone, path) come in as a callback, so this module imports
no driver.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated

import numpy as np
from pydantic import BeforeValidator, ConfigDict, Field, model_validator

from handeye.calib import model
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError
from handeye.calib.noise import default_point_cov
from handeye.calib.params import Fraction, NonNegativeFloat, Params, PinholeParams, PositiveFloat, PositiveInt, Vector3
from handeye.calib.setup import Setup, check_setup

#: ``reachable(T_base_flange (4, 4), q_from (6,) or None) -> q (6,) or None``.
Reachable = Callable[[np.ndarray, "np.ndarray | None"], "np.ndarray | None"]

#: Number of unknowns of the point model: camera transform (6) + marker-side translation (3).
N_PARAMS = 9
#: Prior standard deviation of a free camera correction (depth scale, depth offset in m, focal scale): weak.
CORRECTION_PRIOR_SIGMA = 1.0


class CameraView(PinholeParams):
    """What the camera can measure (pinhole, no distortion needed at this accuracy).

    Attributes
    ----------
    width, height : int
        Image size, px.
    fx, fy, cx, cy : float
        Intrinsics, px.
    margin_px : float
        Every marker corner must stay this far inside the image border.
    depth_min_m, depth_max_m : float
        Range of the marker center's depth (camera z), m.
    max_view_angle_deg : float
        Largest angle between the marker normal and the ray to the camera.
    marker_size_m : float
        Side of the marker's black square, m (its corners are checked).
    """

    model_config = ConfigDict(frozen=True)

    margin_px: NonNegativeFloat = 40.0
    depth_min_m: NonNegativeFloat = 0.4
    depth_max_m: PositiveFloat = 2.0
    max_view_angle_deg: Annotated[PositiveFloat, Field(lt=90)] = 60.0
    marker_size_m: PositiveFloat = 0.05

    @model_validator(mode="after")
    def _consistent(self):
        if not self.depth_min_m < self.depth_max_m:
            raise ValueError(f"need depth_min_m < depth_max_m, got {self.depth_min_m}, {self.depth_max_m}")
        if not self.margin_px < min(self.width, self.height) / 2:
            raise ValueError(f"margin_px must be below half the image ({min(self.width, self.height) / 2} px), "
                             f"got {self.margin_px}")
        return self

    def project(self, p: np.ndarray) -> np.ndarray:
        """Pixels (..., 2) of camera-frame points (..., 3) (z must be positive)."""
        return np.stack([self.fx * p[..., 0] / p[..., 2] + self.cx, self.fy * p[..., 1] / p[..., 2] + self.cy], -1)


class KeepOut(Params):
    """An axis-aligned box in the base frame (m) that the flange and the marker/camera must not enter."""

    model_config = ConfigDict(frozen=True)

    min: Vector3
    max: Vector3

    @model_validator(mode="after")
    def _ordered(self):
        if not all(lo < hi for lo, hi in zip(self.min, self.max)):
            raise ValueError(f"min {self.min} must be below max {self.max} on every axis")
        return self


def _boxes(value):
    """``keep_out`` entries may be given as ``(min, max)`` pairs."""
    if isinstance(value, (list, tuple)):
        return tuple({"min": k[0], "max": k[1]} if isinstance(k, (list, tuple)) and len(k) == 2 else k for k in value)
    return value


class PlannerConfig(Params):
    """Candidate generation, scoring and the travel model.

    Attributes
    ----------
    n_candidates : int
        Candidate poses drawn per planned pose.
    translation_range_m : float
        Candidates lie within +- this per axis around the start pose ...
    tilt_deg : float
        ... turned about a random axis through the flange by up to this.
    local_fraction : float
        This share of the candidates is drawn at a third of both ranges, so
        that a cautious step is available while the estimate is still rough.
    workspace_min, workspace_max : 3 floats or None
        Candidate positions are clipped into this box (the robot's own limit
        check still decides).
    keep_out : sequence of KeepOut
        Boxes that the flange origin and the marker (eye-to-hand) / camera
        (eye-in-hand) origin must keep ``clearance_m`` from, along the
        straight path from the current pose.
    clearance_m : float
    travel_weight : float
        Score cost per second of estimated motion, in nats of information.
    speed_m_s, acceleration_m_s2 : float
        Linear motion profile for the travel-time estimate.
    rotation_radius_m : float
        A rotation by ``a`` rad counts as ``a * rotation_radius_m`` of travel.
    prior_sigma_rad, prior_sigma_m : float
        Weak prior on every unknown before any sample (keeps the information invertible).
    uncertainty_k : float
        The image margin grows by this many predicted pixel standard
        deviations of the marker center (0: trust the estimate fully).
    max_checks : int
        Reachability callbacks per planned pose at most (best scores first).
    """

    model_config = ConfigDict(frozen=True)

    n_candidates: PositiveInt = 300
    translation_range_m: PositiveFloat = 0.15
    tilt_deg: PositiveFloat = 40.0
    local_fraction: Fraction = 0.3
    workspace_min: Vector3 | None = None
    workspace_max: Vector3 | None = None
    keep_out: Annotated[tuple[KeepOut, ...], BeforeValidator(_boxes)] = ()
    clearance_m: NonNegativeFloat = 0.05
    travel_weight: NonNegativeFloat = 0.05
    speed_m_s: PositiveFloat = 0.25
    acceleration_m_s2: PositiveFloat = 1.0
    rotation_radius_m: PositiveFloat = 0.1
    prior_sigma_rad: PositiveFloat = 1.0
    prior_sigma_m: PositiveFloat = 1.0
    uncertainty_k: NonNegativeFloat = 3.0
    max_checks: PositiveInt = 40

    @model_validator(mode="after")
    def _workspace(self):
        if (self.workspace_min is None) != (self.workspace_max is None):
            raise ValueError("workspace_min and workspace_max go together")
        return self


#: A camera model for uses that never screen poses (`least_informative`).
_NO_VIEW = CameraView(width=1, height=1, fx=1.0, fy=1.0, cx=0.0, cy=0.0, margin_px=0.0)


@dataclass(frozen=True)
class PlannedPose:
    """One planned pose and what the planner expects from it.

    Attributes
    ----------
    T_base_flange : ndarray, shape (4, 4)
    q : ndarray, shape (6,), or None
        Joint target from the reachability callback.
    gain : float
        Expected information gain on the camera transform, nats.
    travel_s : float
        Estimated motion time from the previous pose, s.
    pixel : ndarray, shape (2,)
        Predicted marker center in the image, px.
    point_cam : ndarray, shape (3,)
        Predicted marker center in the camera frame, m.
    cov : ndarray, shape (6, 6)
        Predicted covariance of the camera transform once this pose is
        sampled (`handeye.calib.result` convention).
    """

    T_base_flange: np.ndarray
    q: np.ndarray | None
    gain: float
    travel_s: float
    pixel: np.ndarray
    point_cam: np.ndarray
    cov: np.ndarray


@dataclass
class ScreenStats:
    """Why candidates were rejected (counts by reason), for logs and the benchmark."""

    reasons: Counter = field(default_factory=Counter)
    checks: int = 0


def marker_rotation(setup: str, X, Y, A, T_cam_marker) -> tuple[np.ndarray, np.ndarray]:
    """Fill in the marker-side rotation that point-only solvers (YKronT') leave at identity.

    From measured marker orientations ``R_B`` (e.g. ArUco), the chordal mean
    of ``R_A^T R_Y R_B`` (eye-to-hand, ``R_X``) or ``R_A R_X R_B``
    (eye-in-hand, ``R_Y``); the planner needs it to know which way the marker faces.

    Parameters
    ----------
    setup : {"eye_to_hand", "eye_in_hand"}
    X, Y : array_like, shape (4, 4)
    A : array_like, shape (N, 4, 4)
    T_cam_marker : array_like, shape (N, 4, 4)

    Returns
    -------
    X, Y : ndarray, shape (4, 4)
        With the marker-side rotation replaced.
    """
    check_setup(setup)
    X, Y = tf.check_transform(X, "X"), tf.check_transform(Y, "Y")
    A, B = tf.check_transforms(A, "A"), tf.check_transforms(T_cam_marker, "T_cam_marker")
    if len(A) != len(B) or len(A) == 0:
        raise CalibrationError(f"A and T_cam_marker must be equally long and non-empty, got {len(A)}, {len(B)}")
    C, K, M = model.split(X, Y, A, setup)
    return model.join(C, tf.make_transform(model.marker_rotation(C, M, B[:, :3, :3]), K[:3, 3]), setup)


def candidate_poses(T_start, config: PlannerConfig, rng: np.random.Generator) -> np.ndarray:
    """``config.n_candidates`` flange poses (N, 4, 4) around ``T_start``.

    Offsets uniform in ``+-translation_range_m`` per axis, rotations about
    uniform random axes through the flange origin by up to ``tilt_deg``; a
    ``local_fraction`` share at a third of both ranges. Positions are clipped
    into the workspace box when one is configured.
    """
    T_start = tf.check_transform(T_start, "T_start")
    n = config.n_candidates
    scale = np.where(np.arange(n) < round(config.local_fraction * n), 1.0 / 3.0, 1.0)
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = rng.uniform(0.0, np.deg2rad(config.tilt_deg), size=n) * scale
    R = tf.so3_exp(axes * angles[:, None])
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    T[:, :3, :3] = R @ T_start[:3, :3]
    T[:, :3, 3] = T_start[:3, 3] + rng.uniform(-1, 1, size=(n, 3)) * config.translation_range_m * scale[:, None]
    if config.workspace_min is not None:
        T[:, :3, 3] = np.clip(T[:, :3, 3], config.workspace_min, config.workspace_max)
    return T


def travel_time(T_from, T_to, config: PlannerConfig) -> np.ndarray:
    """Trapezoidal-profile motion time (s) from ``T_from`` (4, 4) to each of ``T_to`` (N, 4, 4).

    The path length is the larger of the translation and ``rotation_radius_m``
    times the rotation angle.
    """
    rot, dist = tf.pose_error(np.asarray(T_to), np.asarray(T_from)[None])
    length = np.maximum(dist, config.rotation_radius_m * rot)
    v, a = config.speed_m_s, config.acceleration_m_s2
    return np.where(length > v * v / a, length / v + v / a, 2.0 * np.sqrt(length / a))


class PosePlanner:
    """Greedy D-optimal pose selection for one calibration (see the module docstring).

    Parameters
    ----------
    setup : {"eye_to_hand", "eye_in_hand"}
    X, Y : array_like, shape (4, 4)
        Current estimate (paper eq. 1), with the marker-side rotation filled
        in (`marker_rotation`) so the marker's facing is known.
    view : CameraView
    config : PlannerConfig
    point_cov : callable, optional
        ``point_cov(points (N, 3)) -> (N, 3, 3)`` m^2; default the depth model
        `handeye.calib.noise.default_point_cov`.
    correction : (theta, free) or (theta, free, sigma), optional
        Camera correction of the measurement model (`handeye.calib.model.CAMERA_PARAMS`:
        depth scale, depth offset, focal scale): current values ``theta`` (3,)
        and which are unknowns ``free`` (3 bools), with a prior standard
        deviation ``sigma`` (3,) each (default `CORRECTION_PRIOR_SIGMA`). The
        free ones are unknowns of the information matrix and count in the
        D-optimal criterion with the camera transform. A parameter a solver
        keeps at nominal but whose typical error widens its covariance
        (`handeye.calib.auto`'s "consider" covariance) is free with that error as
        its prior: the predicted covariance then matches it to first order.
    """

    def __init__(self, setup: str, X, Y, view: CameraView, config: PlannerConfig | None = None,
                 point_cov: Callable[[np.ndarray], np.ndarray] = default_point_cov, correction=None):
        self.setup = check_setup(setup)
        self.view = view
        self.config = config or PlannerConfig()
        self._point_cov = point_cov
        self.X, self.Y = tf.check_transform(X, "X"), tf.check_transform(Y, "Y")
        correction = (np.zeros(3), (False, False, False)) if correction is None else tuple(correction)
        theta, free = correction[:2]
        sigma = np.asarray(correction[2] if len(correction) == 3 else [CORRECTION_PRIOR_SIGMA] * 3, dtype=float)
        self.theta = np.asarray(theta, dtype=float)
        self.free = tuple(bool(f) for f in free)
        if self.theta.shape != (3,) or len(self.free) != 3 or not np.isfinite(self.theta).all() \
                or len(correction) not in (2, 3) or sigma.shape != (3,) or not np.all(sigma > 0):
            raise CalibrationError(f"correction must be (theta (3,), free (3 bools)[, sigma (3,) > 0]), "
                                   f"got {correction!r}")
        n_free = sum(self.free)
        c = self.config
        self._prior = np.diag(np.r_[[c.prior_sigma_rad ** -2] * 3, [c.prior_sigma_m ** -2] * 6,
                                    sigma[list(self.free)] ** -2])
        #: Unknowns the criterion is about: the camera transform (6) and the free camera corrections.
        self._interest = np.r_[np.arange(6), N_PARAMS + np.arange(n_free)].astype(int)
        self.information = self._prior.copy()
        self.stats = ScreenStats()

    # ------------------------------------------------------------ information
    def predict(self, A) -> tuple[np.ndarray, np.ndarray]:
        """Predicted marker points (N, 3) at flange poses A (N, 4, 4) and their Jacobians (N, 3, P)
        w.r.t. the unknowns ``[dC, tC, tK, free corrections]`` (`handeye.calib.model`)."""
        C, K, M = model.split(self.X, self.Y, tf.check_transforms(A, "A"), self.setup)
        p = model.predict_points(C, K[:3, 3], M, self.theta)
        problem = model.Linearization(M, p, np.broadcast_to(np.eye(3), (len(p), 3, 3)), free=self.free)
        J = problem.raw(C, K, self.theta)[2]
        return p, -J  # the residual is measured minus predicted

    def _information(self, p: np.ndarray, J: np.ndarray) -> np.ndarray:
        S_inv = np.linalg.inv(self._point_cov(np.where(p[:, 2:] > 0.1, p, [0.0, 0.0, 0.1])))
        return np.swapaxes(J, 1, 2) @ S_inv @ J

    def sample_information(self, A) -> np.ndarray:
        """Fisher information (N, P, P) of a sample at each flange pose of A (N, 4, 4)."""
        return self._information(*self.predict(A))

    def add(self, T_base_flange) -> None:
        """Account for a sample taken at ``T_base_flange`` (4, 4), or for one at each of (N, 4, 4)."""
        T = np.asarray(T_base_flange, dtype=float)
        A = tf.check_transform(T, "T_base_flange")[None] if T.ndim == 2 else tf.check_transforms(T, "T_base_flange")
        self.information = self.information + self.sample_information(A).sum(axis=0)

    def camera_cov(self, information=None) -> np.ndarray:
        """Predicted covariance (6, 6) of the camera transform (`handeye.calib.result` convention)."""
        cov = np.linalg.inv(self.information if information is None else information)[..., :6, :6]
        return 0.5 * (cov + np.swapaxes(cov, -1, -2))

    def consider_cov(self) -> np.ndarray:
        """Predicted covariance (6, 6) of the camera transform if the free camera corrections are kept at
        nominal, their prior standard deviations taken as typical errors: ``N_xx^-1 + S diag(sigma^2) S^T``,
        ``S = N_xx^-1 N_xc`` (`handeye.calib.auto`'s "consider" covariance, which ``auto`` reports before it has enough
        samples to estimate camera parameters). Equal to `camera_cov` without free corrections."""
        n = self.information.shape[0]
        if n == N_PARAMS:
            return self.camera_cov()
        c = np.arange(N_PARAMS, n)
        prior_c = np.diag(self._prior)[c]
        N_xx = self.information[:N_PARAMS, :N_PARAMS]
        S = np.linalg.solve(N_xx, self.information[:N_PARAMS, c])
        cov = (np.linalg.inv(N_xx) + (S / prior_c) @ S.T)[:6, :6]
        return 0.5 * (cov + cov.T)

    def gains(self, A) -> np.ndarray:
        """Expected D-optimal gain (nats) of sampling at each flange pose of A (N, 4, 4)."""
        return self._gains(self.sample_information(A))

    def log_det_covariance(self, information) -> np.ndarray:
        """log det of the covariance of the unknowns of interest (camera + free corrections)."""
        cov = np.linalg.inv(information)[..., self._interest[:, None], self._interest]
        return np.linalg.slogdet(cov)[1]

    def _gains(self, U: np.ndarray) -> np.ndarray:
        return self.log_det_covariance(self.information) - self.log_det_covariance(self.information + U)

    # --------------------------------------------------------------- validity
    def marker_in_camera(self, A) -> np.ndarray:
        """``T_cam_marker`` (N, 4, 4) predicted at flange poses A (N, 4, 4)."""
        A = np.asarray(A, dtype=float)
        if self.setup == Setup.EYE_TO_HAND:
            return tf.invert(self.Y) @ A @ self.X
        return _invert_stack(A @ self.X) @ self.Y

    def screen(self, A, T_from=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Which flange poses the camera could measure (and that clear the keep-out boxes).

        Parameters
        ----------
        A : ndarray, shape (N, 4, 4)
        T_from : ndarray, shape (4, 4), optional
            Start of the straight path checked against the keep-out boxes
            (default: only the targets).

        Returns
        -------
        ok : ndarray of bool, shape (N,)
        points : ndarray, shape (N, 3)
            Predicted marker centers, camera frame, m.
        J : ndarray, shape (N, 3, P)
            Their Jacobians (reused for the scores).
        """
        v = self.view
        A = np.asarray(A, dtype=float)
        T_cm = self.marker_in_camera(A)
        p, J = self.predict(A)
        reasons = self.stats.reasons
        P = self._point_uncertainty(J)
        z, k = p[:, 2], self.config.uncertainty_k
        # The depth limits, too, keep k predicted standard deviations of the marker's depth.
        sz = k * np.sqrt(np.maximum(P[:, 2, 2], 0.0))
        ok = (z - sz >= v.depth_min_m) & (z + sz <= v.depth_max_m)
        reasons["depth range"] += int((~ok).sum())
        # Marker normal (its z axis) must point back at the camera: angle to the ray from the marker to the camera.
        n = T_cm[:, :3, 2]
        cos_view = -np.einsum("ni,ni->n", n, p) / np.maximum(np.linalg.norm(p, axis=1), 1e-9)
        # ... by k predicted standard deviations of the camera rotation less than the limit.
        s_rot = math.sqrt(max(np.linalg.eigvalsh(self.camera_cov()[:3, :3])[-1], 0.0)) if k > 0 else 0.0
        facing = np.arccos(np.clip(cos_view, -1, 1)) <= math.radians(v.max_view_angle_deg) - k * s_rot
        reasons["view angle"] += int((ok & ~facing).sum())
        ok &= facing
        # Corners inside the image, the margin widened by k predicted pixel sigmas of the center.
        h = v.marker_size_m / 2
        corners = np.array([[-h, -h, 0, 1], [h, -h, 0, 1], [h, h, 0, 1], [-h, h, 0, 1]])
        pc = np.einsum("nij,kj->nki", T_cm, corners)[..., :3]
        zc = np.where(pc[..., 2] > 1e-3, pc[..., 2], np.nan)
        px = v.project(np.concatenate([pc[..., :2], zc[..., None]], -1))
        margin = v.margin_px + k * self._pixel_sigma(p, P)
        inside = np.all((px[..., 0] >= margin[:, None]) & (px[..., 0] <= v.width - margin[:, None])
                        & (px[..., 1] >= margin[:, None]) & (px[..., 1] <= v.height - margin[:, None]), axis=1)
        reasons["marker outside the image margin"] += int((ok & ~inside).sum())
        ok &= inside
        if self.config.keep_out:
            clear = self._clear(A, T_from)
            reasons["keep-out box"] += int((ok & ~clear).sum())
            ok &= clear
        return ok, p, J

    def _point_uncertainty(self, J: np.ndarray) -> np.ndarray:
        """Covariance (N, 3, 3) of the predicted marker centers from the parameter uncertainty (zero if k = 0)."""
        if self.config.uncertainty_k == 0:
            return np.zeros((len(J), 3, 3))
        return J @ np.linalg.inv(self.information) @ np.swapaxes(J, 1, 2)

    def _pixel_sigma(self, p: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Largest predicted pixel standard deviation (N,) of the marker center, given its covariance P (N, 3, 3)."""
        z = np.maximum(p[:, 2], 1e-3)
        # Pixel Jacobian of the projection, f/z [I2 | -xy/z].
        Jp = np.zeros((len(p), 2, 3))
        Jp[:, 0, 0] = self.view.fx / z
        Jp[:, 1, 1] = self.view.fy / z
        Jp[:, 0, 2] = -self.view.fx * p[:, 0] / z**2
        Jp[:, 1, 2] = -self.view.fy * p[:, 1] / z**2
        Q = Jp @ P @ np.swapaxes(Jp, 1, 2)
        return np.sqrt(np.maximum(np.linalg.eigvalsh(Q)[:, -1], 0.0))

    def _clear(self, A: np.ndarray, T_from) -> np.ndarray:
        c = self.config
        if T_from is not None:
            T_from = np.asarray(T_from, float)
            # Straight-line samples of the carried points (every ~1 cm of the longest path, at most 50).
            carried_from = np.stack([T_from[:3, 3], (T_from @ self.X)[:3, 3]])
            carried_to = np.stack([A[:, :3, 3], (A @ self.X)[:, :3, 3]], axis=1)  # (N, 2, 3)
            n = int(min(50, max(2, np.ceil(np.abs(carried_to - carried_from).max() / 0.01))))
            s = np.linspace(0, 1, n)[:, None, None, None]
            pts = carried_from[None, None] + s * (carried_to[None] - carried_from[None, None])  # (n, N, 2, 3)
            pts = np.moveaxis(pts, 0, 1).reshape(len(A), -1, 3)
        else:
            pts = np.stack([A[:, :3, 3], (A @ self.X)[:, :3, 3]], axis=1)
        clear = np.ones(len(A), bool)
        for box in c.keep_out:
            lo = np.asarray(box.min) - c.clearance_m
            hi = np.asarray(box.max) + c.clearance_m
            clear &= ~np.any(np.all((pts >= lo) & (pts <= hi), axis=2), axis=1)
        return clear

    # ----------------------------------------------------------------- choice
    def next_pose(self, T_start, T_current, q_current, rng: np.random.Generator,
                  reachable: Reachable | None = None) -> PlannedPose | None:
        """The best valid pose to sample next (does not add it; call `add` once sampled).

        Parameters
        ----------
        T_start : (4, 4)
            Center of the candidate region (the run's start pose).
        T_current : (4, 4)
            Where the flange is now (start of the next motion).
        q_current : (6,) or None
            Current joints, handed to ``reachable``.
        rng : numpy.random.Generator
        reachable : callable, optional
            The robot's own check (`Reachable`); None accepts every pose.

        Returns
        -------
        PlannedPose or None
            None when no candidate is valid.
        """
        T_current = tf.check_transform(T_current, "T_current")
        A = candidate_poses(T_start, self.config, rng)
        ok, p, J = self.screen(A, T_current)
        idx = np.flatnonzero(ok)
        if len(idx) == 0:
            return None
        A, p, J = A[idx], p[idx], J[idx]
        U = self._information(p, J)
        gain = self._gains(U)
        travel = travel_time(T_current, A, self.config)
        order = np.argsort(-(gain - self.config.travel_weight * travel))
        for k in order[: self.config.max_checks]:
            self.stats.checks += 1
            q = None
            if reachable is not None:
                q = reachable(A[k], q_current)
                if q is None:
                    self.stats.reasons["robot limits"] += 1
                    continue
            pixel = self.view.project(p[k])
            return PlannedPose(A[k], None if q is None else np.asarray(q, float), float(gain[k]), float(travel[k]),
                               pixel, p[k].copy(), self.camera_cov(self.information + U[k]))
        return None

    def plan(self, T_start, q_start, n: int, rng: np.random.Generator,
             reachable: Reachable | None = None) -> list[PlannedPose]:
        """``n`` poses in a row, each assumed sampled before the next is chosen (a dry run).

        The estimate is not updated between poses (nothing is measured), so
        the expected covariance after each pose is that of the current
        linearisation. Stops early when no candidate is valid.
        """
        T_cur, q_cur = tf.check_transform(T_start, "T_start"), q_start
        out: list[PlannedPose] = []
        for _ in range(n):
            pose = self.next_pose(T_start, T_cur, q_cur, rng, reachable)
            if pose is None:
                break
            out.append(pose)
            self.add(pose.T_base_flange)
            T_cur, q_cur = pose.T_base_flange, pose.q
        return out


def least_informative(setup: str, X, Y, A, *, keep_recent: int = 0, correction=None,
                      point_cov: Callable[[np.ndarray], np.ndarray] = default_point_cov) -> int:
    """Which sample to drop from a bounded set so that the estimate loses the least: the D-optimal exchange rule.

    For every sample ``i`` but the ``keep_recent`` newest, the loss of
    removing it is ``log det Sigma_C(I - U_i) - log det Sigma_C(I)`` (the
    growth of the camera's confidence ellipsoid, `PosePlanner`); the sample
    with the smallest loss goes. Samples at poses the others already cover
    carry little information of their own and go first; a lone pose that
    pins down a direction stays however old it is.

    Parameters
    ----------
    setup : {"eye_to_hand", "eye_in_hand"}
    X, Y : array_like, shape (4, 4)
        Current estimate (eye-to-hand ``X = T_flange_marker``, ``Y = T_base_cam``;
        eye-in-hand ``X = T_flange_cam``, ``Y = T_base_marker``).
    A : array_like, shape (N, 4, 4)
        ``T_base_flange`` of the samples held, oldest first.
    keep_recent : int
        The newest this many are never dropped (they follow the present).
    correction : (theta, free), optional
        See `PosePlanner`.

    Returns
    -------
    int
        Index into ``A``.
    """
    A = tf.check_transforms(A, "A")
    if not 0 <= keep_recent < len(A):
        raise CalibrationError(f"keep_recent must be in [0, {len(A)}), got {keep_recent}")
    planner = PosePlanner(setup, X, Y, _NO_VIEW, PlannerConfig(uncertainty_k=0), point_cov, correction)
    U = planner.sample_information(A)
    info = planner.information + U.sum(axis=0)
    candidates = U[: len(A) - keep_recent]
    loss = planner.log_det_covariance(info - candidates) - planner.log_det_covariance(info)
    return int(np.argmin(loss))


def _invert_stack(T: np.ndarray) -> np.ndarray:
    R = np.swapaxes(T[:, :3, :3], 1, 2)
    out = np.broadcast_to(np.eye(4), T.shape).copy()
    out[:, :3, :3] = R
    out[:, :3, 3] = -np.einsum("nij,nj->ni", R, T[:, :3, 3])
    return out


#: Directions of the bootstrap pattern: (rotation axis in the flange frame, base-frame offset direction).
_BOOTSTRAP = [((1, 0, 0), (1, 0, 0)), ((0, 1, 0), (0, 1, 0)), ((-1, 0, 0), (0, 0, 1)), ((0, -1, 0), (-1, 0, 0)),
              ((0.7071, 0.7071, 0), (0, -1, 0)), ((0, 0, 1), (0, 0, -1))]


def bootstrap_poses(T_start, setup: str, view: CameraView, point_cam, config: PlannerConfig, *,
                    lever_max_m: float = 0.1, view_angle_deg: float = 0.0, n: int = 5) -> np.ndarray:
    """A model-free pattern (n, 4, 4) to take the first samples with, while nothing is known.

    Turns about the flange's own x, y, -x, -y, x+y, z axes, each with an offset
    along a different base axis. The amplitude is the largest fraction ``a <= 1``
    of ``(translation_range_m, tilt_deg)`` for which the marker provably stays
    in view whatever the unknown transforms are, given only the first
    measurement (marker center ``point_cam`` at distance ``r0`` and depth
    ``z0``, and a bound ``view_angle_deg`` on its view angle) and a bound ``L``
    on the lever arm (flange to marker, eye-to-hand; flange to camera,
    eye-in-hand). A turn by ``theta`` with an offset ``d`` moves

    - the marker relative to the camera by at most
      ``delta = |d| + theta (L + r0 [eye-in-hand])``: every marker corner (at
      ``s = marker_size_m / sqrt 2`` from the center) then lies within
      ``delta + s`` of the first center, whose pixel moves by at most
      ``f (delta + s) sqrt(1 + (x0/z0)^2) / (z0 - delta - s)`` along u (y0 for
      v), which must fit in the room to the image margin; the center's depth
      stays within ``z0 +- delta``;
    - the viewing ray by at most ``asin(delta_p / r0)``, with ``delta_p`` the
      displacement of the marker (eye-to-hand: ``delta``) or of the camera
      (eye-in-hand: ``|d| + theta L``), and eye-to-hand the marker's normal by
      ``theta``: the view angle stays below ``view_angle_deg`` plus these.

    Returns
    -------
    ndarray, shape (n, 4, 4)
        Empty (0, 4, 4) when even a tiny pattern would not be safe.
    """
    T_start = tf.check_transform(T_start, "T_start")
    check_setup(setup)
    p0 = np.asarray(point_cam, dtype=float)
    if p0.shape != (3,) or not np.isfinite(p0).all() or p0[2] <= 0:
        raise CalibrationError(f"point_cam must be a finite 3-vector in front of the camera, got {point_cam!r}")
    if not 1 <= n <= len(_BOOTSTRAP):
        raise CalibrationError(f"n must be in 1..{len(_BOOTSTRAP)}, got {n}")
    z0, r0 = float(p0[2]), float(np.linalg.norm(p0))
    u, v = view.project(p0)
    m = view.margin_px
    room_u, room_v = min(u - m, view.width - m - u), min(v - m, view.height - m - v)
    # Pixel shift per metre of 3-D displacement near the first center (the projection's slope, bounded).
    gain_u = view.fx * math.hypot(1.0, p0[0] / z0)
    gain_v = view.fy * math.hypot(1.0, p0[1] / z0)
    s = view.marker_size_m / math.sqrt(2)
    theta_max = math.radians(config.tilt_deg)
    eye_in_hand = setup == Setup.EYE_IN_HAND
    room_px = min(room_u, room_v)

    def safe(a: float) -> bool:
        theta = a * theta_max
        moved = a * config.translation_range_m + theta * lever_max_m  # the carried marker / camera origin
        delta = moved + (theta * r0 if eye_in_hand else 0.0)
        if delta >= z0 - view.depth_min_m or z0 + delta > view.depth_max_m or moved >= r0:
            return False
        ray = math.degrees(math.asin(moved / r0))
        if view_angle_deg + ray + (0.0 if eye_in_hand else math.degrees(theta)) > view.max_view_angle_deg:
            return False
        e = delta + s
        return e < z0 and gain_u * e / (z0 - e) <= room_u and gain_v * e / (z0 - e) <= room_v

    if room_px <= 0 or not safe(0.02):
        return np.zeros((0, 4, 4))
    lo, hi = 0.02, 1.0
    if safe(hi):
        lo = hi
    for _ in range(30):
        if lo == hi:
            break
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if safe(mid) else (lo, mid)
    a = lo
    out = []
    for axis, offset in _BOOTSTRAP[:n]:
        ax = np.asarray(axis, float) / np.linalg.norm(axis)
        R = T_start[:3, :3] @ tf.so3_exp(ax * a * theta_max)
        dt = np.asarray(offset, float) * a * config.translation_range_m
        out.append(tf.make_transform(R, T_start[:3, 3] + dt))
    return np.stack(out)
