"""What the engine is armed from (`Reference`), the calibration in use (`InUse`), the state covariance, and the
workspace figures (1-sigma, distance between two camera transforms) over the arming samples' points."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from handeye.calib import model
from handeye.calib import transforms as tf
from handeye.calib.auto import CONSIDER_SIGMA
from handeye.calib.errors import CalibrationError
from handeye.calib.problem import CalibrationProblem
from handeye.calib.result import CalibrationResult
from handeye.calib.setup import Setup
from handeye.calib.monitor.kernels import I3


#: Workspace points kept from the arming samples (the drift and accuracy figures are RMS over them).
WORKSPACE_POINTS = 200
#: A marker offset given with no uncertainty is taken as known to this (1-sigma per axis, m).
MARKER_OFFSET_FLOOR_M = 1e-6


@dataclass(frozen=True)
class Reference:
    """What the engine is armed from (fixed until it is armed again).

    Attributes
    ----------
    setup : Setup
    C : ndarray (4, 4)
        The arming calibration's camera transform (``T_base_cam`` / ``T_flange_cam``).
    K : ndarray (4, 4)
        Marker-side transform (``T_flange_marker`` / ``T_base_marker``) of the arming result.
    theta : ndarray (3,)
        Its camera correction (`handeye.calib.model.CAMERA_PARAMS`).
    noise : NoiseLevels
        Noise levels of the arming result.
    workspace : ndarray (W, 3)
        True camera-frame marker points of the arming samples: where the drift and accuracy are measured.
    sigma_mm : float
        The arming calibration's 1-sigma over the workspace, mm.
    result : CalibrationResult
        The arming result.
    shared_var : float
        Variance (m^2 per axis) of the error of a predicted point that samples at nearby poses share
        (`shared_error_var`): the *moved* test marginalises it.
    """

    setup: Setup
    C: np.ndarray
    K: np.ndarray
    theta: np.ndarray
    noise: model.NoiseLevels
    workspace: np.ndarray
    sigma_mm: float
    result: CalibrationResult
    shared_var: float = 0.0


@dataclass(frozen=True)
class InUse:
    """The calibration in use: the arming one, then each re-learnt one (replaced, never changed).

    Attributes
    ----------
    C : ndarray (4, 4)
        Its camera transform.
    theta : ndarray (3,)
        Its camera correction.
    sigma_mm : float
        Its 1-sigma over the workspace, mm.
    """

    C: np.ndarray
    theta: np.ndarray
    sigma_mm: float


def shared_error_var(result: CalibrationResult) -> float:
    """Variance (m^2 per axis) of the calibration's prediction error that contiguous samples share.

    ``auto``'s blocked folds (from 100 samples) predict contiguous
    stretches of the recording held out in turn; its self-check predicts
    single samples held out. What the first adds to the second is error that
    a stretch shares, beyond the independent noise of each sample: the
    model's own systematic error at those poses (an unmodelled distortion,
    a robot error that varies smoothly with the pose). Samples at new poses
    near each other share it too, and a window of them must not read it as
    a move: ``(stretch^2 - single^2) / 3``, 0 without blocked folds.
    """
    blocked = result.auto.blocked_folds if result.auto is not None else None
    if blocked is None or blocked.reported_m is None or result.self_check is None:
        return 0.0
    return max(0.0, blocked.reported_m ** 2 - result.self_check.loo_observed_m ** 2) / 3.0


def arm_reference(result: CalibrationResult, problem: CalibrationProblem, *,
                  consider_theta=None) -> tuple[Reference, np.ndarray]:
    """The calibration in use and the covariance of the engine's state, from a result and its samples.

    The state is ``[dC, tC, t_K, theta, z]``: the camera transform (left
    perturbation, `handeye.calib.result`), the marker-side translation, the camera
    parameters (`handeye.calib.model.CAMERA_PARAMS`) and, with the problem's
    ``robot_shared_error``, the P kinematic-error parameters all samples share (unit variance). Its
    covariance is the inverse information of ``auto``'s extended model at the
    result (`handeye.calib.model.point_jacobians`, the result's noise levels), camera
    parameters that ``auto`` left at nominal held to their typical error
    (``consider_theta``, default `handeye.calib.auto.CONSIDER_SIGMA`), and the
    estimate's sensitivity to ``z`` as their cross covariance.

    Parameters
    ----------
    result : CalibrationResult
        Of either setup; its camera correction and noise levels (``auto``) are
        used when present (``solve("auto")``), else none and unit scale; the
        levels are widened by the square of its self-check's held-out ratio
        (observed / predicted) when that exceeds 1.
    problem : CalibrationProblem
        The samples it was solved from: flange poses, marker centres in the
        camera frame as measured, their covariance shapes (default:
        `handeye.calib.noise`'s depth model) and, when set, the kinematic-error factor
        at their joints (``robot_shared_error``, (N, 6, P)).

    Returns
    -------
    reference : Reference
    cov : ndarray (12 + P, 12 + P)

    Raises
    ------
    CalibrationError
        Malformed samples, or samples that do not determine the camera.
    """
    setup = Setup(result.setup)
    if problem.setup != setup:
        raise CalibrationError(f"the result is {setup}, its samples {problem.setup}")
    A, p, point_cov, robot_factor = problem.A, problem.points, problem.point_cov, problem.robot_shared_error
    C, K, M = model.split(result.X, result.Y, A, setup)
    theta = result.camera_correction.as_array()
    levels = result.auto.noise if result.auto is not None else model.NoiseLevels()
    # Held-out samples predicted worse than the model expects (auto's self-check): the noise levels were
    # fitted too closely, so they are widened by that ratio (never narrowed).
    ratio = result.self_check.loo_ratio if result.self_check is not None else 1.0
    widen = max(1.0, float(ratio or 1.0)) ** 2
    noise = model.NoiseLevels(levels.point_scale * widen, levels.robot * math.sqrt(widen))
    correction = result.auto.camera_correction if result.auto is not None else {}
    consider = CONSIDER_SIGMA if consider_theta is None else consider_theta
    held = np.array([0.0 if name in correction and correction[name].estimated else consider[name] ** -2
                     for name in model.CAMERA_PARAMS])
    shape, _ = model.point_shape(p, point_cov)
    # A known marker offset (`CalibrationProblem.marker_offset`) is information on the marker-side translation:
    # held as given (sigma 0) is held to a micrometre.
    offset_info = None if problem.marker_offset is None else max(problem.marker_offset_sigma, MARKER_OFFSET_FLOOR_M) ** -2
    cov = state_covariance(C, K, M, theta, setup, noise, shape, held, robot_factor, offset_info)
    cov = 0.5 * (cov + cov.T)
    q = model.CameraCorrection(*theta).correct(p)
    workspace = q[::max(1, len(q) // WORKSPACE_POINTS)]
    ref = Reference(setup, C.copy(), K.copy(), theta, noise, workspace, workspace_sigma(C, theta, workspace, cov) * 1e3,
                    result, shared_error_var(result))
    return ref, cov


def state_covariance(C, K, M, theta, setup, noise, shape, held, robot_factor, offset_info=None) -> np.ndarray:
    """`arm_reference`'s state covariance: the inverse information of the samples (``M`` (N, 4, 4), point
    covariance shapes ``shape`` (N, 3, 3), ``noise``) about ``[dC, tC, t_K, theta]``, ``held`` (3,) added to
    the camera parameters' information and ``offset_info`` (1/m^2, None: none) to the marker-side
    translation's, then the kinematic error's block from ``robot_factor`` (N, 6, P)."""
    _, H_C, H_tK, H_th, H_xi = model.point_jacobians(C, K, M, theta, setup)
    W = np.linalg.inv(noise.point_cov(shape, model.robot_cofactor(C, K, M, setup)))
    J = np.concatenate([H_C, H_tK, H_th], axis=2)                     # (N, 3, 12)
    N = np.einsum("nki,nkl,nlj->ij", J, W, J)
    N[9:12, 9:12] += np.diag(held)
    if offset_info is not None:
        N[6:9, 6:9] += offset_info * I3
    try:
        cov = np.linalg.inv(N)
    except np.linalg.LinAlgError:
        raise CalibrationError("the reference samples do not determine the camera transform") from None
    if robot_factor is not None:
        F = robot_factor                     # validated with the problem it came in
        # The estimate's error from a shared error z ~ N(0, I): -N^-1 J^T W H_z z.
        G = -cov @ np.einsum("nki,nkl,nlj->ij", J, W, H_xi @ F)
        cov = np.block([[cov + G @ G.T, G], [G.T, np.eye(F.shape[2])]])
    return cov


def workspace_sigma(C, theta, points, cov) -> float:
    """RMS 1-sigma (m) over camera-frame ``points`` (W, 3) of where ``C`` and ``theta`` put them.

    A measured point ``m`` goes to ``C correct_theta(m)``; ``cov`` is the
    state covariance of `arm_reference` (its first 12 rows and columns are used).
    """
    J = np.zeros((len(points), 3, 12))
    J[:, :, :3] = -tf.skew(points @ C[:3, :3].T)
    J[:, :, 3:6] = I3
    J[:, :, 9:12] = -C[:3, :3] @ model.measure(points, np.asarray(theta, dtype=float))[2]
    var = np.einsum("wij,jk,wik->w", J, cov[:12, :12], J)
    return float(np.sqrt(max(np.mean(var), 0.0)))


def workspace_distance(C1, C2, points) -> float:
    """RMS distance (m) between where two camera transforms put camera-frame ``points`` (W, 3)."""
    d = points @ (C1[:3, :3] - C2[:3, :3]).T + (C1[:3, 3] - C2[:3, 3])
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


class WorkspaceMoments:
    """`workspace_sigma` over fixed camera-frame points (W, 3), and the drift of a calibration over them, at a
    cost independent of W.

    Both are RMS figures over the points of the Jacobian of where ``C`` and
    ``theta`` put a point, which is ``R_C G(p; theta) B`` with ``B =
    diag(R_C^T, R_C^T, I, I)`` and ``G`` linear in ``[1, focal_scale,
    depth_scale, depth_offset]`` with per-point terms. So the second moments
    of those terms give them exactly, with a few small products per sample.
    """

    def __init__(self, points):
        points = np.asarray(points, dtype=float)
        n = len(points)
        xy, xy_z = points[:, :2], points[:, :2] / points[:, 2:]
        G = np.zeros((n, 4, 3, 12))                     # per point, the terms of G for 1, f, s, d
        G[:, 0, :, :3] = -tf.skew(points)
        G[:, 0, :, 3:6] = I3
        G[:, 0, :, 9] = -points
        G[:, 0, :, 10] = -points / points[:, 2:]
        G[:, 0, :2, 11] = -xy
        G[:, 1, :2, 9] = -xy                            # focal_scale
        G[:, 1, :2, 10] = -xy_z
        G[:, 2, :2, 11] = -xy                           # depth_scale
        G[:, 3, :2, 11] = -xy_z                         # depth_offset
        Q = np.einsum("wmai,wnaj->mnji", G, G) / n        # Q_mn^T = mean G_n^T G_m
        m, k = np.triu_indices(4)
        self.terms = (Q[m, k] + np.where((m < k)[:, None, None], Q[k, m], 0.0)).reshape(10, 144)
        self._B = np.eye(12)

    def drift_factor(self, C, theta) -> np.ndarray:
        """``F`` (12, 12) such that ``|F d|`` is the RMS displacement over the points of where ``C`` and ``theta``
        put them when the state moves by ``d`` (12,): rotation vector and translation of the camera
        transform, marker-side translation, camera correction (first order: `sigma` of ``d d^T``), m.
        Linear in ``d``: the slope of ``F d`` over time is the drift rate."""
        s, d, f = np.asarray(theta, dtype=float).tolist()
        K = np.array([1.0, f, s, d, f * f, f * s, f * d, s * s, s * d, d * d]).dot(self.terms).reshape(12, 12)
        B = np.eye(12)
        B[:3, :3] = B[3:6, 3:6] = C[:3, :3]
        metric = B.dot(0.5 * (K + K.T)).dot(B.T)
        w, V = np.linalg.eigh(metric)
        return (V * np.sqrt(np.clip(w, 0.0, None))).T

    def sigma(self, C, theta, cov) -> float:
        """`workspace_sigma` of ``C``, ``theta`` (3,) and the state covariance ``cov`` over the points, m."""
        B = self._B
        B[:3, :3] = B[3:6, 3:6] = C[:3, :3]
        # sum over m <= n of c_m c_n <B^T cov B, Q_mn^T + Q_nm^T (m < n)>, c = [1, f, s, d]
        M = B.T.dot(cov[:12, :12]).dot(B)              # ndarray.dot: @'s product, less call overhead
        t00, t01, t02, t03, t11, t12, t13, t22, t23, t33 = self.terms.dot(M.ravel()).tolist()
        s, d, f = theta.tolist()
        var = (t00 + f * (t01 + f * t11) + s * (t02 + f * t12 + s * t22)
               + d * (t03 + f * t13 + s * t23 + d * t33))
        return math.sqrt(max(var, 0.0))
