"""The measurement model of a hand-eye sample: residual, Jacobian, whitening, information.

One model shared by `calib.refine` (ML refinement), `calib.robust` (inlier
test), `calib.monitor` (the monitoring engine), `calib.auto` (``solve("auto")``)
and the pose planner (information matrix).

Unknowns
--------
Both setups are one model. The camera measures the marker ``B_i = C^-1 M_i K``
(paper eq. 1 ``A_i X = Y B_i`` rearranged), with

- eye-to-hand: ``C = Y = T_base_cam``, ``K = X = T_flange_marker``, ``M_i = A_i``;
- eye-in-hand: ``C = X = T_flange_cam``, ``K = Y = T_base_marker``,
  ``M_i = A_i^-1`` (from ``A_i X B_i = Y``).

Parameter vector (left perturbations as in `calib.result`, ``R = Exp(d) R_est``,
``t = t_est + dt``): ``[dC, tC, tK]`` for points, ``[dC, tC, dK, tK]`` for
poses, followed by the free camera nuisance parameters (`CAMERA_PARAMS`).

Measurements
------------
- Marker point (always): ``r_i = p_i - h(R_C^T (R_Mi t_K + t_Mi - t_C); theta)``,
  the equation of translation (paper eq. 5) in the camera frame. ``h`` is the
  camera's systematic error (`CameraCorrection`): measured depth
  ``z_m = (1 + s) z + d`` with the point moved along its pixel ray, and a
  lateral scale ``1 + f`` from a focal length error::

      h(p) = diag(1 + f, 1 + f, 1) p (1 + s + d / z)

  With ``theta = 0``, ``h`` is the identity and the model is the paper's.
- Marker orientation (pose data): ``e_i = Log(R_Bi^T R_C^T R_Mi R_K)`` (eq. 4,
  marker frame), noise ``sigma_rot^2 I``.

Noise (errors in variables)
---------------------------
The point residual's covariance is ``Sigma_i = s_p S_i + sigma_R^2 T_i``:

- ``S_i`` the camera's point covariance shape (given ``point_cov``, else the
  depth model of `calib.noise`), ``s_p`` its scale;
- ``T_i`` the robot pose error propagated through the lever arm of the
  marker (`robot_cofactor`): the flange pose is ``A_i Exp(xi)`` with
  ``xi = [a, b]`` in the flange frame, ``b ~ N(0, sigma_R^2 I)`` (m),
  ``a ~ N(0, (ROBOT_ROTATION_PER_M sigma_R)^2 I)`` (rad).

`variance_components` estimates ``s_p``, ``sigma_R^2`` and ``sigma_rot^2``
from the residuals (Förstner's iterated variance-component estimate, the
Helmert/REML kind: each component's weighted residual square sum divided by
its share of the redundancy).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from calib import transforms as tf
from calib.errors import CalibrationError, DegenerateMotionError, InsufficientDataError
from calib.noise import default_point_cov
from calib.setup import Setup

#: Names of the camera nuisance parameters, in parameter-vector order.
CAMERA_PARAMS = ("depth_scale", "depth_offset", "focal_scale")
#: Flange rotation error per unit of flange translation error of the robot
#: (rad per m). A UR10's joint zero offsets of 0.01-0.05 deg move the flange
#: by ~0.2-1 mm at 1.2 m reach and turn it by the same order in mrad, so 1.
ROBOT_ROTATION_PER_M = 1.0
#: Smallest eigenvalue ratio of the information before the motions are called degenerate.
MIN_INFORMATION_RATIO = 1e-14
#: Leave-one-out: a sample whose residual block has an eigenvalue of ``I - H_ii`` at or below this is one
#: the others cannot do without (leverage 1).
LEVERAGE_MARGIN = 1e-9

_I3 = np.eye(3)
#: ``[e_k]x`` for the unit vectors (3, 3, 3): ``[v]x = sum_k v_k [e_k]x``.
_GENERATORS = tf.skew(np.eye(3))
#: Row and column of each entry of a 3x3 matrix in row-major order: ``(a b^T).flat == a[_ROW] * b[_COL]``.
_ROW, _COL = np.divmod(np.arange(9), 3)
_EYE_ROW = np.eye(3).reshape(9)


# --------------------------------------------------------------------------- frames


def split(X, Y, A, setup: str):
    """Camera transform ``C``, marker-side transform ``K`` and per-sample ``M_i`` (module docstring)."""
    if setup == Setup.EYE_TO_HAND:
        return Y, X, A
    return X, Y, tf.invert(A)


def join(C, K, setup: str):
    """``(X, Y)`` from the camera transform ``C`` and the marker-side transform ``K``."""
    return (K, C) if setup == Setup.EYE_TO_HAND else (C, K)


# --------------------------------------------------------------------------- camera correction


@dataclass(frozen=True)
class CameraCorrection:
    """Systematic error of the RGB-D camera: what it measures for a true point.

    ``depth_scale`` s and ``depth_offset`` d (m): measured depth
    ``(1 + s) z + d``, along the pixel ray; ``focal_scale`` f: lateral
    coordinates scaled by ``1 + f`` (the focal length used to back-project is
    ``1 / (1 + f)`` of the true one). All zero = a perfect camera.
    """

    depth_scale: float = 0.0
    depth_offset: float = 0.0
    focal_scale: float = 0.0

    def as_array(self) -> np.ndarray:
        return np.array([self.depth_scale, self.depth_offset, self.focal_scale])

    def measure(self, points) -> np.ndarray:
        """What the camera reports (N, 3) for true camera-frame points (N, 3), m."""
        return measure(points, self.as_array())[0]

    def correct(self, measured) -> np.ndarray:
        """True camera-frame points (N, 3) from measured ones (N, 3): the inverse of `measure`."""
        m = np.asarray(measured, dtype=float)
        s, d, f = self.as_array()
        z = (m[:, 2] - d) / (1.0 + s)
        out = m * (z / m[:, 2])[:, None]
        out[:, :2] /= 1.0 + f
        return out

    def rigid_stand_in(self, measured) -> tuple[np.ndarray, float]:
        """Rigid transform ``G`` (4, 4) of the camera frame closest to `correct` on ``measured`` (N, 3), and its misfit.

        ``G p ~ correct(p)`` in least squares over the points (Kabsch, via
        scipy's ``Rotation.align_vectors``). A camera transform ``T`` that
        pairs with this correction becomes ``T @ G`` for consumers that take
        the camera's points uncorrected and only a rigid transform (a URDF, a
        tf): exact where the correction is rigid, and over the points'
        region otherwise. Returns ``G`` and the RMS misfit (m) of
        ``G p - correct(p)`` over the points.
        """
        m = tf.check_points(measured, "measured")
        target = self.correct(m)
        mc, tc = m.mean(axis=0), target.mean(axis=0)
        m0, t0 = m - mc, target - tc
        R = Rotation.align_vectors(t0, m0)[0].as_matrix() if len(m) >= 3 else np.eye(3)
        misfit = float(np.sqrt(np.mean(np.square(m0 @ R.T - t0)) * 3))
        return tf.make_transform(R, tc - R @ mc), misfit


def measure(p, theta):
    """``h(p; theta)`` (N, 3) and its Jacobians w.r.t. ``p`` (N, 3, 3) and ``theta`` (N, 3, 3).

    See the module docstring: ``h(p) = diag(1 + f, 1 + f, 1) p (1 + s + d / z)``.
    """
    s, d, f = theta
    z = p[:, 2]
    g = 1.0 + s + d / z
    D = np.array([1.0 + f, 1.0 + f, 1.0])
    h = p * g[:, None] * D
    J_p = g[:, None, None] * np.diag(D)[None].repeat(len(p), axis=0)
    J_p[:, :, 2] += -(D * p) * (d / z**2)[:, None]
    J_theta = np.empty((len(p), 3, 3))
    J_theta[:, :, 0] = D * p
    J_theta[:, :, 1] = D * p / z[:, None]
    J_theta[:, :, 2] = p * g[:, None] * np.array([1.0, 1.0, 0.0])
    return h, J_p, J_theta


def _measured(p, theta) -> np.ndarray:
    """``h(p; theta)`` (N, 3) alone (`measure` without its Jacobians, for cost evaluations)."""
    s, d, f = theta
    return p * ((1.0 + s + d / p[:, 2])[:, None] * np.array([1.0 + f, 1.0 + f, 1.0]))


# --------------------------------------------------------------------------- residuals


def point_residuals(C, t_K, M, p):
    """Translation residuals ``r`` (N, 3) = p - predicted (no camera error), and Jacobians (N, 3, 3) each.

    Returns ``r, J_dC, J_tC, J_tK``: derivatives of ``r`` w.r.t. the left
    rotation perturbation of C, the translation of C and the translation of K.
    """
    R_C, t_C = C[:3, :3], C[:3, 3]
    w = M[:, :3, :3] @ t_K + M[:, :3, 3] - t_C          # marker center minus camera origin, C's parent frame
    r = p - w @ R_C                                      # w @ R_C == (R_C^T w_i)_i
    J_dC = -(R_C.T @ tf.skew(w))
    J_tC = np.broadcast_to(R_C.T, J_dC.shape)
    J_tK = -(R_C.T @ M[:, :3, :3])
    return r, J_dC, J_tC, J_tK


def predict_points(C, t_K, M, theta=None) -> np.ndarray:
    """Predicted measured marker points (N, 3) in the camera frame, camera error ``theta`` applied."""
    R_C, t_C = C[:3, :3], C[:3, 3]
    p = (M[:, :3, :3] @ t_K + M[:, :3, 3] - t_C) @ R_C
    if theta is None or not np.any(theta):
        return p
    return _measured(p, np.asarray(theta, dtype=float))


def point_jacobians(C, K, M, theta, setup: str):
    """Predicted measured point and its Jacobians, per sample, for the recursive filter of `calib.monitor`.

    Returns ``h (N, 3), H_C (N, 3, 6), H_tK (N, 3, 3), H_theta (N, 3, 3), H_xi (N, 3, 6)``:
    the point the camera reports, ``h(R_C^T (R_Mi t_K + t_Mi - t_C); theta)``, and
    its derivatives w.r.t. the camera transform (left perturbation ``[dC, tC]``),
    the marker-side translation, the camera parameters (all of `CAMERA_PARAMS`)
    and a flange-frame twist ``xi = [a, b]`` (rad, m) of the robot pose
    (``A_i Exp(xi)``, as ``robot_shared_error`` of `calib.auto`). Eye-to-hand
    the twist moves the marker by ``R_A (a x t_K + b)``; eye-in-hand it moves the
    camera, so the base marker seen from the flange moves by ``-(a x y + b)``,
    ``y`` its flange-frame position.
    """
    R_C, t_C = C[:3, :3], C[:3, 3]
    R_M = M[:, :3, :3]
    y = R_M @ K[:3, 3] + M[:, :3, 3]                   # marker center in C's parent frame
    q = (y - t_C) @ R_C                                # == R_C^T (y - t_C): the point without camera error
    h, J_p, J_theta = measure(q, np.zeros(3) if theta is None else np.asarray(theta, dtype=float))
    Rt = R_C.T
    dq = np.empty((len(q), 3, 6))
    dq[:, :, :3] = Rt @ tf.skew(y - t_C)
    dq[:, :, 3:] = -Rt
    dq_tK = Rt @ R_M
    dq_xi = np.empty((len(q), 3, 6))
    if setup == Setup.EYE_TO_HAND:
        dq_xi[:, :, :3] = -(dq_tK @ tf.skew(K[:3, 3]))
        dq_xi[:, :, 3:] = dq_tK
    else:
        dq_xi[:, :, :3] = Rt @ tf.skew(y)
        dq_xi[:, :, 3:] = -Rt
    return h, J_p @ dq, J_p @ dq_tK, J_theta, J_p @ dq_xi


def inv_right_jacobian(e):
    """Inverse right Jacobian of SO(3), ``Log(Exp(e) Exp(d)) = e + Jr^-1(e) d + O(d^2)``; e (N, 3)."""
    th = np.linalg.norm(e, axis=1)
    S = tf.skew(e)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    c = np.where(small, 1.0 / 12.0, 1.0 / ths**2 - (1.0 + np.cos(ths)) / (2.0 * ths * np.sin(ths)))
    return np.eye(3) + 0.5 * S + c[:, None, None] * (S @ S)


def rotation_residuals(C, K, M, R_B):
    """Rotation residuals ``e`` (N, 3) = Log(R_B^T R_C^T R_M R_K) and Jacobians w.r.t. dC, dK (N, 3, 3)."""
    R_C, R_K, R_M = C[:3, :3], K[:3, :3], M[:, :3, :3]
    E = np.swapaxes(R_B, 1, 2) @ R_C.T @ R_M @ R_K
    e = tf.so3_log(E)
    Jinv = inv_right_jacobian(e)
    J_dK = Jinv @ R_K.T
    J_dC = -(J_dK @ np.swapaxes(R_M, 1, 2))
    return e, J_dC, J_dK


def robot_cofactor(C, K, M, setup: str) -> np.ndarray:
    """Camera-frame covariance (N, 3, 3) of the predicted marker point per unit robot variance ``sigma_R^2``.

    The flange pose is ``A_i Exp([a, b])`` (flange frame), ``b ~ N(0, I)``,
    ``a ~ N(0, ROBOT_ROTATION_PER_M^2 I)``. The marker point (eye-to-hand) or
    the inverse flange motion seen from the flange-mounted camera
    (eye-in-hand) moves by ``b + a x l`` (rotated into C's parent frame), with
    ``l`` the lever arm from the flange to the marker, so the covariance is
    ``R_C^T (I + rho^2 [l]x [l]x^T) R_C``.
    """
    R_C = C[:3, :3]
    lever = np.einsum("nij,j->ni", M[:, :3, :3], K[:3, 3])
    if setup != Setup.EYE_TO_HAND:
        lever = lever + M[:, :3, 3]
    # [l]x [l]x^T = |l|^2 I - l l^T, and R^T (a I - l l^T) R = a I - (R^T l)(R^T l)^T.
    rho2 = ROBOT_ROTATION_PER_M**2
    lc = lever @ R_C
    out = lc[:, _ROW] * (-rho2 * lc)[:, _COL]         # entries of -rho^2 l l^T as rows (N, 9)
    out[:, ::4] += (1.0 + rho2 * np.sum(lc * lc, axis=1))[:, None]
    return out.reshape(-1, 3, 3)


# --------------------------------------------------------------------------- weights


def check_point_cov(point_cov, n: int) -> np.ndarray | None:
    """Validate a point covariance (3, 3) or (N, 3, 3) and broadcast it to (N, 3, 3); None passes."""
    if point_cov is None:
        return None
    # Variances in m^2: the same bound as coordinates keeps their products finite.
    cov = tf.as_real_array(point_cov, "point_cov")
    if cov.shape == (3, 3):
        cov = np.broadcast_to(cov, (n, 3, 3))
    if cov.shape != (n, 3, 3):
        raise CalibrationError(f"point_cov must have shape (3, 3) or ({n}, 3, 3), got {cov.shape}")
    if not np.isfinite(cov).all():
        raise CalibrationError("point_cov contains NaN or inf")
    if np.abs(cov - np.swapaxes(cov, 1, 2)).max() > 1e-9 * max(np.abs(cov).max(), 1e-30):
        raise CalibrationError("point_cov is not symmetric")
    return cov


def whitener(cov) -> np.ndarray:
    """Inverse Cholesky factors ``W`` (N, 3, 3) so that ``W r`` has unit covariance (``W^T W = cov^-1``).

    Written out for 3x3 (a batched LAPACK call costs ~100x more per sample), on
    the entries as contiguous rows (9, N): strided columns of (N, 3, 3) cost 2-3x.
    """
    a = np.asarray(cov, dtype=float)
    n = len(a)
    a00, _, _, a10, a11, _, a20, a21, a22 = np.ascontiguousarray(a.reshape(n, 9).T)
    with np.errstate(invalid="ignore", divide="ignore"):
        l00 = np.sqrt(a00)
        l10, l20 = a10 / l00, a20 / l00
        l11 = np.sqrt(a11 - l10**2)
        l21 = (a21 - l20 * l10) / l11
        l22 = np.sqrt(a22 - l20**2 - l21**2)
        ok = bool(np.all((l00 > 0) & (l11 > 0) & (l22 > 0) & (l22 < np.inf)))     # NaN fails every comparison
    if not ok:
        raise CalibrationError("point_cov is not positive definite")
    W = np.zeros((9, n))
    W[0], W[4], W[8] = 1.0 / l00, 1.0 / l11, 1.0 / l22
    W[3] = -l10 * W[0] / l11
    W[7] = -l21 * W[4] / l22
    W[6] = -(l20 * W[0] + l21 * W[3]) / l22
    return np.ascontiguousarray(W.T).reshape(n, 3, 3)


def point_shape(B, point_cov) -> tuple[np.ndarray, bool]:
    """Camera point covariance shape ``S_i`` (N, 3, 3) and whether ``point_cov`` was given."""
    p = B if B.ndim == 2 else B[:, :3, 3]
    cov = check_point_cov(point_cov, len(p))
    if cov is None:
        return default_point_cov(p), False
    return np.array(cov), True


def point_weights(B, point_cov) -> tuple[np.ndarray, bool]:
    """Whitening matrices (N, 3, 3) of the point residual and whether ``point_cov`` was given."""
    cov, given = point_shape(B, point_cov)
    return whitener(cov), given


# --------------------------------------------------------------------------- problem


def _same_point(a, b) -> bool:
    """Whether two ``(C, K, theta)`` are the same estimate (theta None and zeros differ: different Jacobians)."""
    if (a[2] is None) != (b[2] is None):
        return False
    for x, y in zip(a, b):
        if x is not y and not np.array_equal(x, y):
            return False
    return True


class Problem:
    """Whitened residual vector and Jacobian of one data set (see the module docstring).

    Parameters
    ----------
    M : ndarray, shape (N, 4, 4)
        Per-sample robot transform of the model (`split`).
    B : ndarray, shape (N, 3) or (N, 4, 4)
        Measured marker points or poses (camera frame).
    W_t : ndarray, shape (N, 3, 3)
        Whitening matrices of the point residual (`whitener` of ``Sigma_i``).
    sigma_rot : float, optional
        Rotation noise (rad) of pose data.
    free : sequence of bool, length 3
        Which of `CAMERA_PARAMS` are estimated; the others stay at ``theta``.
    use_rotation : bool
        Whether pose data contribute their orientation residual (else only
        the translation of ``B`` is used and ``K``'s rotation is not estimated).
    memo : dict, optional
        Shared by problems of the same ``M``, ``B`` and ``use_rotation``
        that differ only in their weights and free camera parameters: `raw`
        keeps its last evaluation there, so re-weighting at a fixed estimate
        (variance components, then the next fit) or freeing another camera
        parameter does not evaluate it twice, and the contiguous copies of
        ``M``'s blocks are made once. The arrays `raw` returns are then
        shared and must not be modified.
    """

    def __init__(self, M, B, W_t, sigma_rot=None, free=(False, False, False), use_rotation=True, memo=None):
        self.M = M
        self._memo = memo
        self._store = memo if memo is not None else {}     # where `_system` keeps its last result
        # Contiguous copies: products with them are single BLAS calls (views of M are strided). Shared through
        # the memo by the re-weighted problems of a fit.
        geometry = None if memo is None else memo.get("geometry")
        if geometry is None:
            geometry = (np.ascontiguousarray(M[:, :3, :3]), np.ascontiguousarray(M[:, :3, 3]),
                        np.ascontiguousarray(np.swapaxes(M[:, :3, :3], 1, 2)))
            if memo is not None:
                memo["geometry"] = geometry
        self._R_M, self._t_M, self._R_Mt = geometry
        self.rotations = B.ndim == 3 and use_rotation
        self.p = B if B.ndim == 2 else B[:, :3, 3]
        self.R_B = B[:, :3, :3] if self.rotations else None
        self.W_t = W_t
        self.sigma_rot = sigma_rot
        self.free = np.asarray(free, dtype=bool)
        self._key = tuple(bool(f) for f in self.free)      # memo key of this free set
        self.n_pose = 12 if self.rotations else 9
        self.n_params = self.n_pose + int(self.free.sum())

    @property
    def points(self) -> bool:
        """True when only marker points are used (no orientation residual)."""
        return not self.rotations

    def raw(self, C, K, theta=None):
        """Unwhitened residuals and Jacobians: ``r (N,3), e (N,3)|None, J_t (N,3,P), J_e (N,3,P)|None``."""
        if self._memo is None:
            return self._raw(C, K, theta, self.free)[0]
        # Kept per free set at the last estimate; another free set there takes the residuals and the pose
        # columns (they do not depend on which camera parameters are free) and adds its camera columns.
        last = self._memo.get("raw")
        if last is None or not _same_point(last[0], (C, K, theta)):
            out, q = self._raw(C, K, theta, self.free)
            last = ((C, K, theta), {}, q)
            self._memo["raw"] = last
        else:
            out = last[1].get(self._key)
            if out is None:
                r, e, J_t, J_e = next(iter(last[1].values()))
                n, n_pose = len(r), self.n_pose
                J_t2 = np.empty((n, 3, self.n_params))
                J_t2[:, :, :n_pose] = J_t[:, :, :n_pose]
                self._camera_columns(last[2], theta, self.free, J_t2[:, :, n_pose:])
                J_e2 = None
                if J_e is not None:
                    J_e2 = np.zeros((n, 3, self.n_params))
                    J_e2[:, :, :n_pose] = J_e[:, :, :n_pose]
                out = (r, e, J_t2, J_e2)
        last[1][self._key] = out
        return out

    @staticmethod
    def _camera_columns(q, theta, free, out) -> None:
        """Jacobian columns ``out`` (N, 3, k) of the point residual w.r.t. the ``free`` camera parameters at the
        uncorrected points ``q`` (N, 3) (zero without ``theta``): minus ``dh/dtheta`` of `measure`."""
        if theta is None:
            out[...] = 0.0
            return
        s, d, f = theta
        z = q[:, 2]
        Dq = q * np.array([1.0 + f, 1.0 + f, 1.0])
        for k, j in enumerate(np.flatnonzero(free)):
            if j == 0:
                np.negative(Dq, out=out[:, :, k])
            elif j == 1:
                np.divide(Dq, -z[:, None], out=out[:, :, k])
            else:
                out[:, :, k] = -(q * (1.0 + s + d / z)[:, None] * np.array([1.0, 1.0, 0.0]))

    def _columns(self, J) -> np.ndarray:
        """The columns of this problem's parameters from a Jacobian with every camera parameter, contiguous
        (an index array on the last axis leaves it outermost in memory: products with it are 2x slower)."""
        out = np.empty(J.shape[:2] + (self.n_params,))
        out[:, :, :self.n_pose] = J[:, :, :self.n_pose]
        out[:, :, self.n_pose:] = J[:, :, self.n_pose + np.flatnonzero(self.free)]
        return out

    def _raw(self, C, K, theta, free):
        """`raw` for the camera parameters ``free``, and the points without camera error ``q`` (N, 3)."""
        R_C, t_C = C[:3, :3], C[:3, 3]
        n, n_pose = len(self._R_M), self.n_pose
        n_params = n_pose + int(free.sum())
        # Marker center minus camera origin, C's parent frame, as one matrix-vector product over all samples.
        w = (self._R_M.reshape(-1, 3) @ K[:3, 3]).reshape(n, 3) + (self._t_M - t_C)
        q = w @ R_C                                       # == (R_C^T w_i)_i, the point without camera error
        tK = 9 if self.rotations else 6
        # Filled in place (no concatenation): [dC, tC, (dK), tK, nuisances]. Blocks as single matrix
        # products instead of batched 3x3 ones: -R_C^T [w]x = -[q]x R_C^T = -sum_k q_k [e_k]x R_C^T, and
        # (R_C^T R_M)^T = R_M^T R_C.
        Jp = np.empty((n, 3, n_pose))
        Jp[:, :, 0:3] = (q @ -(_GENERATORS @ R_C.T).reshape(3, 9)).reshape(n, 3, 3)
        Jp[:, :, 3:6] = R_C.T
        if self.rotations:
            Jp[:, :, 6:9] = 0.0
        Jp[:, :, tK:tK + 3] = np.swapaxes((self._R_Mt.reshape(-1, 3) @ -R_C).reshape(n, 3, 3), 1, 2)
        if not (theta is not None and (np.any(theta) or free.any())):
            r = self.p - q
            if not free.any():
                return ((r, None, Jp, None) if not self.rotations else (r, *self._rotation_part(C, K, Jp))), q
            J_t = np.zeros((n, 3, n_params))
            J_t[:, :, :n_pose] = Jp
        else:
            s, d, f = theta
            z = q[:, 2]
            g = 1.0 + s + d / z
            D = np.array([1.0 + f, 1.0 + f, 1.0])
            Dq = D * q
            r = self.p - Dq * g[:, None]
            # J_p = g diag(D) + c e_z^T with c = -(D q) d / z^2 (`measure`), built as rows (N, 9); one batched
            # product into place (broadcasting over the 3-long axis costs 3x more).
            J_p = np.zeros((n, 9))
            J_p[:, ::4] = g[:, None] * D
            J_p[:, 2::3] += Dq * (-d / z**2)[:, None]
            J_t = np.empty((n, 3, n_params))
            np.matmul(J_p.reshape(n, 3, 3), Jp, out=J_t[:, :, :n_pose])
            self._camera_columns(q, theta, free, J_t[:, :, n_pose:])
        if not self.rotations:
            return (r, None, J_t, None), q
        return (r, *self._rotation_part(C, K, J_t)), q

    def _rotation_part(self, C, K, J_t):
        """``e, J_t, J_e`` of `raw`: the orientation residuals and their Jacobian (`rotation_residuals`)."""
        e, JeC, JeK = rotation_residuals(C, K, self.M, self.R_B)
        J_e = np.zeros_like(J_t)
        J_e[:, :, 0:3] = JeC
        J_e[:, :, 6:9] = JeK
        return e, J_t, J_e

    def _system(self, C, K, theta):
        """``raw``, the whitened point residuals ``v`` (N, 3) and Jacobian ``G`` (N, 3, P), ``G^T G`` and the
        normal matrix (with the orientation rows).

        The last one is kept (in the memo when there is one): a fit's last step, the variance components
        and the information at one estimate with one whitening share it.
        """
        raw = self.raw(C, K, theta)
        key = self._key
        last = self._store.get("system")
        if last is None or not (last[0] is self.W_t and _same_point(last[1], (C, K, theta))
                                and last[2] == self.sigma_rot):
            last = (self.W_t, (C, K, theta), self.sigma_rot, {})
            self._store["system"] = last
        systems = last[3]
        if key in systems:
            return systems[key]
        full = systems.get((True, True, True))
        if full is not None:
            # Fewer camera parameters free at the same estimate and whitening: their rows and columns.
            cols = np.concatenate([np.arange(self.n_pose), self.n_pose + np.flatnonzero(self.free)])
            out = (raw, full[1], self._columns(full[2]), full[3][cols][:, cols], full[4][cols][:, cols])
        else:
            r, e, J_t, J_e = raw
            v = np.einsum("nij,nj->ni", self.W_t, r)
            G = self.W_t @ J_t
            G_flat = G.reshape(-1, self.n_params)
            N_points = G_flat.T @ G_flat
            N = N_points
            if self.rotations:
                Je_flat = J_e.reshape(-1, self.n_params)
                N = N + Je_flat.T @ Je_flat / self.sigma_rot**2
            out = (raw, v, G, N_points, N)
        systems[key] = out
        return out

    def _normal(self, C, K, theta):
        """Normal matrix ``J^T J``, gradient ``J^T r`` and cost ``r^T r`` of the whitened problem."""
        (r, e, _, J_e), v, G, _, N = self._system(C, K, theta)
        v_flat = v.reshape(-1)
        g = G.reshape(-1, self.n_params).T @ v_flat
        cost = float(v_flat @ v_flat)
        if self.rotations:
            s2 = self.sigma_rot**2
            g = g + J_e.reshape(-1, self.n_params).T @ e.reshape(-1) / s2
            cost += float(np.sum(e * e)) / s2
        return N, g, cost

    def whitened(self, C, K, theta=None):
        """Whitened residual vector (3N or 6N,) and Jacobian (3N or 6N, n_params)."""
        (_, e, _, J_e), v, G, _, _ = self._system(C, K, theta)
        rw = v.reshape(-1)
        Jw = G.reshape(-1, self.n_params)
        if self.rotations:
            rw = np.concatenate([rw, (e / self.sigma_rot).reshape(-1)])
            Jw = np.concatenate([Jw, (J_e / self.sigma_rot).reshape(-1, self.n_params)])
        return rw, Jw

    def cost(self, C, K, theta=None) -> float:
        """Whitened residual square sum (chi-square statistic)."""
        last = self._store.get("system")
        if (last is not None and self._key in last[3] and last[0] is self.W_t and last[2] == self.sigma_rot
                and _same_point(last[1], (C, K, theta))):
            return self._normal(C, K, theta)[2]      # evaluated at this estimate already
        q = ((self._R_M.reshape(-1, 3) @ K[:3, 3]).reshape(-1, 3) + (self._t_M - C[:3, 3])) @ C[:3, :3]
        p = q if theta is None or not np.any(theta) else _measured(q, np.asarray(theta, dtype=float))
        r = np.einsum("nij,nj->ni", self.W_t, self.p - p)
        cost = float(np.sum(r * r))
        if self.rotations:
            E = np.swapaxes(self.R_B, 1, 2) @ C[:3, :3].T @ self.M[:, :3, :3] @ K[:3, :3]
            cost += float(np.sum(tf.so3_log(E) ** 2)) / self.sigma_rot**2
        return cost

    def retract(self, C, K, theta, delta):
        """Apply a parameter step with left perturbations: new ``(C, K, theta)``."""
        C2 = tf.make_transform(tf.so3_exp(delta[:3]) @ C[:3, :3], C[:3, 3] + delta[3:6])
        if self.rotations:
            K2 = tf.make_transform(tf.so3_exp(delta[6:9]) @ K[:3, :3], K[:3, 3] + delta[9:12])
        else:
            K2 = tf.make_transform(K[:3, :3], K[:3, 3] + delta[6:9])
        if theta is not None and self.free.any():
            theta = np.array(theta, dtype=float)
            theta[self.free] += delta[self.n_pose:]
        return C2, K2, theta


class WeightedData:
    """One data set under the extended model, with the weights of its current noise levels kept.

    ``M`` (`split`), the camera's point covariance shape ``S_i``, whether
    orientations are used, and caches: the robot cofactor at the last estimate
    and the whitener of the last noise levels, so that re-weighting at a fixed
    estimate (variance components, then the next fit) computes neither again.
    Used by `calib.auto` and `calib.diagnostics`.

    Parameters
    ----------
    A : ndarray, shape (N, 4, 4)
        ``T_base_flange``.
    B : ndarray, shape (N, 3) or (N, 4, 4)
        Marker points or ``T_cam_marker``.
    setup : {"eye_to_hand", "eye_in_hand"}
    shape : ndarray, shape (N, 3, 3)
        The camera's point covariance shape (`point_shape`).
    use_rotation : bool
        Whether orientation residuals are used (pose data).
    shape_whitener : ndarray, shape (N, 3, 3), optional
        `whitener` of ``shape`` when the caller has it.
    """

    def __init__(self, A, B, setup, shape, use_rotation, shape_whitener=None):
        self.setup = setup
        self.A, self.B = A, B
        self.shape = shape
        self.use_rotation = use_rotation
        self.M = split(np.eye(4), np.eye(4), A, setup)[2]
        self._cof_at = None
        self._memo: dict = {}      # the last raw evaluation, shared by the problems of this data set (`Problem`)
        self._whitener_at = None   # the last point whitener, with its noise levels and robot cofactor
        self._shape_whitener = shape_whitener

    @property
    def points(self) -> np.ndarray:
        """Marker points (N, 3), m."""
        return self.B if self.B.ndim == 2 else self.B[:, :3, 3]

    def cofactor(self, C, K):
        """`robot_cofactor` at ``(C, K)``; the last one is kept (rounds re-weight at a fixed estimate)."""
        if self._cof_at is None or not ((self._cof_at[0] is C or np.array_equal(self._cof_at[0], C))
                                        and (self._cof_at[1] is K or np.array_equal(self._cof_at[1], K))):
            self._cof_at = (C, K, robot_cofactor(C, K, self.M, self.setup))
        return self._cof_at[2]

    @property
    def shape_whitener(self) -> np.ndarray:
        """`whitener` of the camera's point covariance shape alone (no robot error)."""
        if self._shape_whitener is None:
            self._shape_whitener = whitener(self.shape)
        return self._shape_whitener

    def problem(self, C, K, noise: "NoiseLevels", free):
        """The whitened `Problem` at ``(C, K)`` with the noise levels ``noise`` and the camera parameters
        ``free``, and the robot cofactor used."""
        cof = self.cofactor(C, K)
        # The same levels at the same estimate (a fit's final problem, its information, its held-out step).
        if self._whitener_at is None or self._whitener_at[0] != noise or self._whitener_at[1] is not cof:
            self._whitener_at = (noise, cof, whitener(noise.point_cov(self.shape, cof)))
        W = self._whitener_at[2]
        return Problem(self.M, self.B, W, sigma_rot=noise.rotation, free=free, use_rotation=self.use_rotation,
                       memo=self._memo), cof



def point_d2(C, K, M, p, W_shape) -> np.ndarray:
    """Squared point residuals (N,) at ``(C, K)`` (no camera error) whitened by the camera's shape ``W_shape``."""
    return whitened_squares(W_shape, p - predict_points(C, K[:3, 3], M))


def whitened_squares(W, r) -> np.ndarray:
    """``|W_i r_i|^2`` (N,) for whitening matrices (N, 3, 3) and residuals (N, 3)."""
    wr = np.einsum("nij,nj->ni", W, r)
    return np.sum(wr * wr, axis=1)


def information(problem: Problem, C, K, theta=None) -> np.ndarray:
    """Fisher information ``J^T W J`` (n_params, n_params) of ``problem`` at ``(C, K, theta)``."""
    return problem._system(C, K, theta)[4]


def camera_block(info) -> np.ndarray:
    """6x6 camera block of the inverse information, after a degeneracy check."""
    ev = np.linalg.eigvalsh(info)
    if ev[0] <= MIN_INFORMATION_RATIO * ev[-1]:
        raise DegenerateMotionError(
            "the motions do not constrain every unknown "
            f"(Fisher information eigenvalue ratio {ev[0] / ev[-1]:.1e}); vary the flange rotation"
        )
    cov = np.linalg.inv(info)[:6, :6]
    return 0.5 * (cov + cov.T)


def minimize(problem: Problem, C, K, theta=None, *, max_iterations: int = 50, tol: float = 1e-10):
    """Levenberg-Marquardt on the whitened cost over ``(C, K, theta)``.

    Returns ``C, K, theta, cost, iterations, converged``.
    """
    if max_iterations < 1:
        return C, K, theta, problem.cost(C, K, theta), 0, False
    cost = None
    lam = 1e-6
    for it in range(1, max_iterations + 1):
        H, g, cost_here = problem._normal(C, K, theta)
        if cost is None:
            cost = cost_here          # the starting cost; later ones come from the accepted steps
        while True:
            try:
                delta = -np.linalg.solve(H + lam * np.diag(np.diag(H)), g)
            except np.linalg.LinAlgError:
                raise DegenerateMotionError("the motions do not constrain every unknown (singular normal equations)") from None
            if np.abs(delta).max() < tol:
                # At the minimum to the tolerance: a step this small need not lower the cost (rounding), and
                # raising the damping until it does cost up to 16 more evaluations.
                return C, K, theta, cost, it, True
            C2, K2, theta2 = problem.retract(C, K, theta, delta)
            # The whole system at the trial estimate: a step is usually taken, and the next iteration (or the
            # variance components after it, `calib.auto`) needs it there; a rejected one costs the Jacobian.
            cost2 = problem._normal(C2, K2, theta2)[2]
            if cost2 <= cost:
                break
            lam *= 10.0
            if lam > 1e10:
                # No descent direction left: we sit at the minimum to numerical precision.
                return C, K, theta, cost, it, True
        lam = max(lam / 10.0, 1e-12)
        step = np.abs(delta).max()
        rel = (cost - cost2) / max(cost, 1e-300)
        C, K, theta, cost = C2, K2, theta2, cost2
        if step < tol or rel < 1e-14:
            return C, K, theta, cost, it, True
    return C, K, theta, cost, max_iterations, False


def marker_rotation(C, M, R_B) -> np.ndarray:
    """Best ``R_K`` given ``C`` for pose data: chordal mean of ``R_M^T R_C R_B``."""
    S = (np.swapaxes(M[:, :3, :3], 1, 2) @ C[:3, :3] @ R_B).sum(axis=0)
    return tf.project_to_so3(S)


# --------------------------------------------------------------------------- noise levels


@dataclass(frozen=True)
class NoiseLevels:
    """Variance components of the model (module docstring).

    Attributes
    ----------
    point_scale : float
        ``s_p``: factor on the camera point covariance shape (1 = as given / as the depth model says).
    robot : float
        ``sigma_R``: flange translation error, m (rotation ``ROBOT_ROTATION_PER_M`` times it, rad).
    rotation : float or None
        ``sigma_rot``: marker orientation noise, rad (pose data).
    """

    point_scale: float = 1.0
    robot: float = 0.0
    rotation: float | None = None

    def point_cov(self, shape, robot_cof) -> np.ndarray:
        """``Sigma_i`` (N, 3, 3) = ``s_p S_i + sigma_R^2 T_i``."""
        return self.point_scale * shape + self.robot**2 * robot_cof


#: Floors of the variance components: they keep the weights finite when a component vanishes.
MIN_POINT_SCALE = 1e-4
MIN_ROBOT_SIGMA = 1e-6
MIN_ROTATION_SIGMA = 1e-6


def variance_components(problem: Problem, C, K, theta, shape, robot_cof, noise: NoiseLevels,
                        *, estimate=(True, True, True)) -> tuple[NoiseLevels, np.ndarray]:
    """One update of the variance components at ``(C, K, theta)`` (Helmert / REML scoring).

    The point covariance is ``Sigma_i = s_p S_i + sigma_R^2 T_i`` (module
    docstring), ``P_i = Sigma_i^-1``, ``v_i`` the point residuals. The
    Helmert equations ``sum_l H_kl sigma_l^2 = q_k`` with
    ``q_k = sum_i v_i^T P_i Q_ki P_i v_i`` and
    ``H_kl = c_k sum_i tr(Q_ki P_i Q_li P_i)`` are solved for
    ``(s_p, sigma_R^2)``; ``c_k = r_k / tr(Q_k P)`` is the share of
    component ``k`` in the redundancy, ``r_k = tr(Q_k P) - tr(N^-1 J^T P Q_k P J)``,
    ``N = J^T P J``, which removes the bias of the fitted parameters (REML).
    Iterated with the fit, this is Fisher scoring of the restricted likelihood.
    The orientation noise (own block) is ``sum e^2 / r_rot``.

    ``problem.W_t`` and ``problem.sigma_rot`` must hold the whitening of
    ``noise``: ``W_t`` that of ``noise.point_cov(shape, robot_cof)`` (the
    camera share ``S`` enters through it, `whitener`; only the robot's is
    multiplied out). ``estimate`` says which of (point, robot, rotation) to update;
    a component whose solution is negative (not supported by the data) is
    set to its floor and the other re-solved alone.

    Returns
    -------
    noise : NoiseLevels
        Updated.
    redundancy : ndarray, shape (3,)
        Degrees of freedom of the redundancy taken by (point, robot, rotation).
    """
    (r, e, J_t, J_e), v, G, NG, Nmat = problem._system(C, K, theta)
    u = J_t.shape[2]
    # In whitened terms (W^T W = P): v^T P Q P v = v~^T Q~ v~, tr(Q P) = tr(Q~), tr(Q_k P Q_l P) = tr(Q~_k Q~_l),
    # tr(Q P J N^-1 J^T P) = tr(Q~ G N^-1 G^T), with v~ = W v, G = W J, Q~ = W Q W^T: fewer 3x3 products.
    W = problem.W_t
    n = len(r)
    G_flat = G.reshape(-1, u)
    if e is not None:
        s2 = problem.sigma_rot**2
        Je_flat = J_e.reshape(-1, u)
    Ninv = np.linalg.inv(Nmat)
    # W (s_p S + sigma_R^2 T) W^T = I: the camera share Q~_0 follows from the robot's, Q~_0 = (I - sigma_R^2 Q~_1) / s_p,
    # exact to rounding relative to I (the robot share is the one computed, its subtraction does not cancel
    # when it is small, and s_p >= MIN_POINT_SCALE). Rows (N, 9).
    s_p, s_r = noise.point_scale, noise.robot**2
    Q = np.empty((2, n, 9))
    Q[1] = (W @ robot_cof @ np.ascontiguousarray(np.swapaxes(W, 1, 2))).reshape(n, 9)
    np.multiply(Q[1], -s_r / s_p, out=Q[0])
    Q[0, :, ::4] += 1.0 / s_p
    Q_flat = Q.reshape(2, -1)
    # tr(Q~_k Q~_l) summed (Q~ symmetric), v~^T Q~ v~ (the sum of Q~ * v~ v~^T) and tr(Q~), in one product.
    V = np.empty((4, 9 * n))
    V[:2] = Q_flat
    V[2] = (v[:, _ROW] * v[:, _COL]).reshape(-1)
    V[3] = np.tile(_EYE_ROW, n)
    (h00, h01, q0, t0), (h10, h11, q1, t1) = (Q_flat @ V.T).tolist()
    # tr(Q~ G N^-1 G^T) = tr(N^-1 G^T Q~ G), for the robot share; the camera's follows from
    # s_p tr(Q~_0 .) + sigma_R^2 tr(Q~_1 .) = tr(.) (no cancellation when it is the larger share).
    tr_rob = float(np.sum(Ninv * (G_flat.T @ (Q[1].reshape(n, 3, 3) @ G).reshape(-1, u))))
    tr_all = float(np.sum(Ninv * NG))
    red = [t0 - (tr_all - s_r * tr_rob) / s_p, t1 - tr_rob]
    c0, c1 = red[0] / max(t0, 1e-300), red[1] / max(t1, 1e-300)
    value = _solve_components([[h00 * c0, h01 * c0], [h10 * c1, h11 * c1]], [q0, q1], [s_p, s_r], list(estimate[:2]))
    shares = [s_p * red[0], s_r * red[1]]
    rot = noise.rotation
    if e is not None:
        tr_rot = 3.0 * len(e) - float(np.sum(Ninv * (Je_flat.T @ Je_flat))) / s2
        shares.append(tr_rot)
        if estimate[2] and tr_rot > 0.5:
            rot = max(float(np.sqrt(np.sum(e**2) / tr_rot)), MIN_ROTATION_SIGMA)
    else:
        shares.append(0.0)
    new = NoiseLevels(
        point_scale=max(float(value[0]), MIN_POINT_SCALE),
        robot=max(float(np.sqrt(max(value[1], 0.0))), MIN_ROBOT_SIGMA),
        rotation=rot,
    )
    return new, np.array(shares)


def _solve_components(H, q, value, active) -> list:
    """The Helmert equations ``H x = q`` (2x2, lists) for the ``active`` components, the others held at ``value``.

    A component whose solution is negative (not supported by the data) is held at its floor and the other
    re-solved alone; a singular system leaves the values as they are. Scalar arithmetic (Cramer's rule):
    numpy's solve and index bookkeeping cost ~50 us here, 4-5 times per fit.
    """
    value, active = list(value), list(active)
    while any(active):
        if all(active):
            det = H[0][0] * H[1][1] - H[0][1] * H[1][0]
            if det == 0.0:
                break
            idx = [0, 1]
            sol = [(q[0] * H[1][1] - H[0][1] * q[1]) / det, (H[0][0] * q[1] - H[1][0] * q[0]) / det]
        else:
            k = 0 if active[0] else 1
            if H[k][k] == 0.0:
                break
            idx = [k]
            sol = [(q[k] - H[k][1 - k] * value[1 - k]) / H[k][k]]
        if all(s > 0 for s in sol):
            for k, s in zip(idx, sol):
                value[k] = s
            break
        drop = idx[sol.index(min(sol))]
        value[drop] = (MIN_POINT_SCALE, MIN_ROBOT_SIGMA**2)[drop]
        active[drop] = False
    return value


def _hat_blocks(G, Ninv) -> np.ndarray:
    """Diagonal blocks ``G_i N^-1 G_i^T`` (N, k*k, row-major) of the hat matrix for whitened Jacobian blocks G (N, k, u)."""
    n, k, u = G.shape
    try:
        F = (G.reshape(-1, u) @ np.linalg.cholesky(Ninv)).reshape(n, k, u)
    except np.linalg.LinAlgError:
        return ((G.reshape(-1, u) @ Ninv).reshape(n, k, u) @ np.swapaxes(G, 1, 2)).reshape(n, k * k)
    out = np.empty((n, k, k))
    for a in range(k):
        for b in range(a + 1):
            out[:, a, b] = out[:, b, a] = np.einsum("nu,nu->n", F[:, a], F[:, b])
    return out.reshape(n, k * k)


def _hat_rows(G, Ninv):
    """The entries ``00, 01, 02, 11, 12, 22`` (each (N,)) of the hat blocks `_hat_blocks` of point blocks G (N, 3, u)."""
    try:
        F = G.reshape(-1, G.shape[2]) @ np.linalg.cholesky(Ninv)
    except np.linalg.LinAlgError:
        h = _hat_blocks(G, Ninv)
        return h[:, 0], h[:, 1], h[:, 2], h[:, 4], h[:, 5], h[:, 8]
    F0, F1, F2 = np.swapaxes(F.reshape(len(G), 3, -1), 0, 1)
    return (np.einsum("nu,nu->n", F0, F0), np.einsum("nu,nu->n", F0, F1), np.einsum("nu,nu->n", F0, F2),
            np.einsum("nu,nu->n", F1, F1), np.einsum("nu,nu->n", F1, F2), np.einsum("nu,nu->n", F2, F2))


def leave_one_out(problem: Problem, C, K, theta=None, point_cov=None) -> tuple[np.ndarray, np.ndarray]:
    """Linearised leave-one-out prediction errors of the marker points.

    For a least-squares fit the whitened residual block of sample ``i`` left
    out is, to first order, ``(I - H_ii)^-1 r_i`` with the hat-matrix block
    ``H_ii = G_i N^-1 G_i^T`` (``G_i`` its whitened Jacobian rows, ``N`` the
    normal matrix; exact for a linear model), and the parameter covariance
    without it ``(N - G_i^T G_i)^-1 = N^-1 + N^-1 G_i^T (I - H_ii)^-1 G_i N^-1``
    (Woodbury). The held-out point's predicted covariance is
    ``Sigma_i + J_i (N - G_i^T G_i)^-1 J_i^T``.

    Parameters
    ----------
    point_cov : ndarray, shape (N, 3, 3), optional
        ``Sigma_i`` of the points (m^2); default the inverse of ``W^T W``.

    Returns
    -------
    errors : ndarray, shape (N,)
        Held-out point prediction error norms, m.
    predicted : ndarray, shape (N,)
        Predicted RMS of each (``sqrt(trace)`` of its covariance), m.

    Raises
    ------
    InsufficientDataError
        When some sample left out leaves the others short of determining the unknowns.
    """
    return _leave_one_out(problem, C, K, theta, point_cov, step=False)[:2]


def leave_one_out_after_step(problem: Problem, C, K, theta=None, point_cov=None):
    """`leave_one_out` of the Gauss-Newton step from ``(C, K, theta)``, without taking it.

    The model linearised at the given estimate: the residuals after the step
    are ``r + J delta`` with ``delta = -N^-1 J^T W r``, the Jacobian is kept.
    For a model variant fitted from a nearby estimate (one more free
    parameter), this is its held-out error to first order, at the cost of one
    Jacobian instead of a refit.

    Returns
    -------
    errors, predicted : ndarray, shape (N,)
        As `leave_one_out`, m.
    delta : ndarray, shape (n_params,)
        The step (`Problem.retract` order).
    """
    return _leave_one_out(problem, C, K, theta, point_cov, step=True)


def _leave_one_out(problem, C, K, theta, point_cov, *, step):
    (r, e, J_t, J_e), rw, G, _, Nmat = problem._system(C, K, theta)
    n, u = len(r), J_t.shape[2]
    W = problem.W_t
    if e is not None:
        G = np.concatenate([G, J_e / problem.sigma_rot], axis=1)
        rw = np.concatenate([rw, e / problem.sigma_rot], axis=1)
    k = G.shape[1]
    G_flat = G.reshape(-1, u)
    Ninv = np.linalg.inv(Nmat)
    delta = None
    if step:
        delta = -Ninv @ (G_flat.T @ rw.reshape(-1))
        rw = rw + (G_flat @ delta).reshape(n, k)
    # Leverage 1 (an eigenvalue of S at 0): without sample i the others do not determine the unknowns.
    # Only the point rows of S^-1 are needed: r_loo = S^-1 r and A = H + H S^-1 H = S^-1 - I (S + H = I),
    # both from 3x3 closed forms (a batched LAPACK call costs ~1 us per sample), on entry rows (9, N).
    if k == 3:
        h00, h01, h02, h11, h12, h22 = _hat_rows(G, Ninv)
        s00, s11, s22 = 1.0 - h00, 1.0 - h11, 1.0 - h22
        singular = not _sym3_positive_rows(s00, -h01, -h02, s11, -h12, s22, LEVERAGE_MARGIN).all()
        if not singular:
            # Adjugate of the symmetric S (off-diagonal entries -h).
            c00, c11, c22 = s11 * s22 - h12 * h12, s00 * s22 - h02 * h02, s00 * s11 - h01 * h01
            c01, c02, c12 = h02 * h12 + h01 * s22, h01 * h12 + h02 * s11, h01 * h02 + s00 * h12
            det = s00 * c00 - h01 * c01 - h02 * c02
            S_inv = np.stack([c00, c01, c02, c01, c11, c12, c02, c12, c22]) / det
            rp = rw.T
    else:
        S = -_hat_blocks(G, Ninv).reshape(n, k, k)
        S.reshape(n, k * k)[:, ::k + 1] += 1.0
        # Points and orientations: the point rows of S^-1 = [T^-1, -T^-1 X] with X = S12 S22^-1 and the
        # Schur complement T = S11 - X S21; S - margin I is positive definite iff its orientation block
        # and that block's Schur complement are.
        S11, S12, S21, S22 = S[:, :3, :3], S[:, :3, 3:], S[:, 3:, :3], S[:, 3:, 3:]
        shift = LEVERAGE_MARGIN * np.eye(3)
        X_m = S12 @ _inv3(S22 - shift)
        singular = not (_sym3_positive(S22, LEVERAGE_MARGIN).all()
                        and _sym3_positive(S11 - X_m @ S21, LEVERAGE_MARGIN).all())
        if not singular:
            X = S12 @ _inv3(S22)
            S_inv = _rows(_inv3(S11 - X @ S21))
            rp = (rw[:, :3] - (X @ rw[:, 3:, None])[:, :, 0]).T
    if singular:
        raise InsufficientDataError(f"leave-one-out needs more than {n} samples: without one of them the "
                                    "others do not determine every unknown")
    # Point rows of S^-1 r, back in unwhitened units through L = W^-1 (lower triangular).
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = S_inv
    r0 = a00 * rp[0] + a01 * rp[1] + a02 * rp[2]
    r1 = a10 * rp[0] + a11 * rp[1] + a12 * rp[2]
    r2 = a20 * rp[0] + a21 * rp[1] + a22 * rp[2]
    w00, _, _, w10, w11, _, w20, w21, w22 = _rows(W)
    l00, l11, l22 = 1.0 / w00, 1.0 / w11, 1.0 / w22
    l10 = -w10 * l00 * l11
    l21 = -w21 * l11 * l22
    l20 = -(w20 * l00 + w21 * l10) * l22
    e1, e2 = l10 * r0 + l11 * r1, l20 * r0 + l21 * r1 + l22 * r2
    errors = np.sqrt((l00 * r0) ** 2 + e1 * e1 + e2 * e2)
    # trace(Sigma + L A L^T) with A = S^-1 - I, the second term as sum(A * L^T L).
    m00, m11, m22 = l00**2 + l10**2 + l20**2, l11**2 + l21**2, l22**2
    m01, m02, m12 = l10 * l11 + l20 * l21, l20 * l22, l21 * l22
    tr_fit = ((a00 - 1.0) * m00 + (a11 - 1.0) * m11 + (a22 - 1.0) * m22
              + (a01 + a10) * m01 + (a02 + a20) * m02 + (a12 + a21) * m12)
    tr_sigma = m00 + m11 + m22 if point_cov is None else np.reshape(point_cov, (n, 9))[:, ::4].sum(axis=1)
    return errors, np.sqrt(tr_sigma + tr_fit), delta


def _rows(a) -> np.ndarray:
    """Entries of 3x3 matrices (N, 3, 3) as contiguous rows (9, N), row-major order (strided columns cost 2-3x)."""
    return np.ascontiguousarray(np.reshape(a, (-1, 9)).T)


def _inv3(a) -> np.ndarray:
    """Inverses (N, 3, 3) of 3x3 matrices by the adjugate (a batched LAPACK call costs ~100x more per matrix)."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = _rows(a)
    c = np.empty((9, len(a00)))
    c[0] = a11 * a22 - a12 * a21
    c[1] = a02 * a21 - a01 * a22
    c[2] = a01 * a12 - a02 * a11
    c[3] = a12 * a20 - a10 * a22
    c[4] = a00 * a22 - a02 * a20
    c[5] = a02 * a10 - a00 * a12
    c[6] = a10 * a21 - a11 * a20
    c[7] = a01 * a20 - a00 * a21
    c[8] = a00 * a11 - a01 * a10
    c /= a00 * c[0] + a01 * c[3] + a02 * c[6]
    return np.ascontiguousarray(c.T).reshape(-1, 3, 3)


def _sym3_positive(a, margin: float) -> np.ndarray:
    """Whether each symmetric 3x3 matrix (N, 3, 3) minus ``margin I`` is positive definite (N,), i.e. its smallest
    eigenvalue exceeds ``margin`` (Sylvester's criterion: the leading minors; the upper triangle is read)."""
    a00, a01, a02, _, a11, a12, _, _, a22 = _rows(a)
    return _sym3_positive_rows(a00, a01, a02, a11, a12, a22, margin)


def _sym3_positive_rows(a00, a01, a02, a11, a12, a22, margin: float) -> np.ndarray:
    """`_sym3_positive` of the upper-triangle entries, each (N,)."""
    b00, b11, b22 = a00 - margin, a11 - margin, a22 - margin
    m2 = b00 * b11 - a01 * a01
    det = b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
    return (b00 > 0) & (m2 > 0) & (det > 0)
