"""Maximum-likelihood refinement and covariance of a hand-eye calibration.

Both setups are written as one measurement model. The camera measures the
marker ``B_i = C^-1 M_i K`` (paper eq. 1, ``A_i X = Y B_i``, rearranged), with

- eye-to-hand: ``C = Y = T_base_cam``, ``K = X = T_flange_marker``, ``M_i = A_i``;
- eye-in-hand: ``C = X = T_flange_cam``, ``K = Y = T_base_marker``,
  ``M_i = A_i^-1`` (from ``A_i X B_i = Y``).

Point data (``B`` of shape (N, 3), the marker center in the camera frame)
constrain ``C`` (6 dof) and the translation ``t_K`` (3); the residual is the
equation of translation (paper eq. 5) in the camera frame,
``r_i = p_i - R_C^T (R_Mi t_K + t_Mi - t_C)``, weighted by the inverse point
covariance (Mahalanobis). Pose data (``B`` of shape (N, 4, 4)) add the
rotation residual ``e_i = Log(R_Bi^T R_C^T R_Mi R_K)`` (marker frame), so
``C`` and ``K`` (6 + 6 dof) are estimated; the rotation noise level and the
scale of the translation covariance are estimated from the residuals.

Perturbations follow `calib.result`: ``R = Exp(d) R_est``, ``t = t_est + dt``
for both ``C`` and ``K``. `covariance` returns the 6x6 block of ``C`` of the
inverse Fisher information, i.e. with the marker-side unknowns marginalised:
the covariance of the ML estimate. A closed-form estimate is less efficient;
`kron_t_prime_covariance` (YKronT', analytic) and `delta_method_covariance`
(any closed form from poses, numerical) give the first-order covariance of
the closed-form estimator itself.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from calib import transforms as tf
from calib.errors import CalibrationError, DegenerateMotionError, InsufficientDataError
from calib.noise import default_point_cov
from calib.result import CalibrationResult, Residuals
from calib.setup import Setup, check_setup
from calib.solvers import check_measurements

#: A given ``point_cov`` is trusted unless the residuals reject it at this level;
#: then the covariance is inflated by the a posteriori variance factor.
CHI2_REJECT = 0.999
#: Smallest eigenvalue ratio of the Fisher information before we call the motions degenerate.
MIN_INFORMATION_RATIO = 1e-14

_I3 = np.eye(3)


# --------------------------------------------------------------------------- checks


def check_point_cov(point_cov, n: int) -> np.ndarray | None:
    """Validate a point covariance (3, 3) or (N, 3, 3) and broadcast it to (N, 3, 3); None passes."""
    if point_cov is None:
        return None
    cov = np.asarray(point_cov, dtype=float)
    if cov.shape == (3, 3):
        cov = np.broadcast_to(cov, (n, 3, 3))
    if cov.shape != (n, 3, 3):
        raise CalibrationError(f"point_cov must have shape (3, 3) or ({n}, 3, 3), got {cov.shape}")
    if not np.isfinite(cov).all():
        raise CalibrationError("point_cov contains NaN or inf")
    if np.abs(cov - np.swapaxes(cov, 1, 2)).max() > 1e-9 * max(np.abs(cov).max(), 1e-30):
        raise CalibrationError("point_cov is not symmetric")
    return cov


# --------------------------------------------------------------------------- model


def _split(X, Y, A, setup):
    """Camera transform C, marker-side transform K and per-sample M_i (see module docstring)."""
    if setup == Setup.EYE_TO_HAND:
        return Y, X, A
    return X, Y, tf.invert(A)


def _join(C, K, setup):
    """(X, Y) from camera transform C and marker-side transform K."""
    return (K, C) if setup == Setup.EYE_TO_HAND else (C, K)


def _skew(v):
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def _so3_log(R):
    return Rotation.from_matrix(R).as_rotvec()


def _so3_exp(v):
    return Rotation.from_rotvec(v).as_matrix()


def _inv_right_jacobian(e):
    """Inverse right Jacobian of SO(3), ``Log(Exp(e) Exp(d)) = e + Jr^-1(e) d + O(d^2)``; e (N, 3)."""
    th = np.linalg.norm(e, axis=1)
    S = _skew(e)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    c = np.where(small, 1.0 / 12.0, 1.0 / ths**2 - (1.0 + np.cos(ths)) / (2.0 * ths * np.sin(ths)))
    return np.eye(3) + 0.5 * S + c[:, None, None] * (S @ S)


def _point_residuals(C, t_K, M, p):
    """Translation residuals r (N, 3) = p - predicted, and their Jacobians (N, 3, 3) each.

    Returns ``r, J_dC, J_tC, J_tK``: derivatives of ``r`` w.r.t. the left rotation
    perturbation of C, the translation of C and the translation of K.
    """
    R_C, t_C = C[:3, :3], C[:3, 3]
    w = M[:, :3, :3] @ t_K + M[:, :3, 3] - t_C          # marker center minus camera origin, C's parent frame
    r = p - w @ R_C                                      # w @ R_C == (R_C^T w_i)_i
    J_dC = -(R_C.T @ _skew(w))
    J_tC = np.broadcast_to(R_C.T, J_dC.shape)
    J_tK = -(R_C.T @ M[:, :3, :3])
    return r, J_dC, J_tC, J_tK


def _rotation_residuals(C, K, M, R_B):
    """Rotation residuals e (N, 3) = Log(R_B^T R_C^T R_M R_K) and Jacobians w.r.t. dC, dK (N, 3, 3)."""
    R_C, R_K, R_M = C[:3, :3], K[:3, :3], M[:, :3, :3]
    E = np.swapaxes(R_B, 1, 2) @ R_C.T @ R_M @ R_K
    e = _so3_log(E)
    Jinv = _inv_right_jacobian(e)
    J_dK = Jinv @ R_K.T
    J_dC = -(J_dK @ np.swapaxes(R_M, 1, 2))
    return e, J_dC, J_dK


def _whitener(cov):
    """Inverse Cholesky factors (N, 3, 3) so that ``L^-1 r`` has unit covariance."""
    try:
        L = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        raise CalibrationError("point_cov is not positive definite") from None
    return np.linalg.inv(L)


class _Problem:
    """Whitened residual vector and Jacobian of one data set for the LM loop.

    Parameters are ``[dC, tC, tK]`` (points) or ``[dC, tC, dK, tK]`` (poses).
    """

    def __init__(self, M, B, W_t, sigma_rot=None):
        self.M = M
        self.points = B.ndim == 2
        self.p = B if self.points else B[:, :3, 3]
        self.R_B = None if self.points else B[:, :3, :3]
        self.W_t = W_t
        self.sigma_rot = sigma_rot
        self.n_params = 9 if self.points else 12

    def raw(self, C, K):
        r, J_dC, J_tC, J_tK = _point_residuals(C, K[:3, 3], self.M, self.p)
        if self.points:
            return r, None, np.concatenate([J_dC, J_tC, J_tK], axis=2), None
        e, JeC, JeK = _rotation_residuals(C, K, self.M, self.R_B)
        zeros = np.zeros_like(J_dC)
        J_t = np.concatenate([J_dC, J_tC, zeros, J_tK], axis=2)
        J_e = np.concatenate([JeC, zeros, JeK, zeros], axis=2)
        return r, e, J_t, J_e

    def whitened(self, C, K):
        r, e, J_t, J_e = self.raw(C, K)
        rw = np.einsum("nij,nj->ni", self.W_t, r).reshape(-1)
        Jw = (self.W_t @ J_t).reshape(-1, self.n_params)
        if not self.points:
            rw = np.concatenate([rw, (e / self.sigma_rot).reshape(-1)])
            Jw = np.concatenate([Jw, (J_e / self.sigma_rot).reshape(-1, self.n_params)])
        return rw, Jw

    def whitened_residual_only(self, C, K):
        R_C, t_C = C[:3, :3], C[:3, 3]
        w = self.M[:, :3, :3] @ K[:3, 3] + self.M[:, :3, 3] - t_C
        r = np.einsum("nij,nj->ni", self.W_t, self.p - w @ R_C)
        cost = float(np.sum(r**2))
        if not self.points:
            E = np.swapaxes(self.R_B, 1, 2) @ R_C.T @ self.M[:, :3, :3] @ K[:3, :3]
            cost += float(np.sum(_so3_log(E) ** 2)) / self.sigma_rot**2
        return cost, r


def _apply(C, K, delta, points):
    """Retract a parameter step onto (C, K) with left perturbations."""
    C2 = tf.make_transform(_so3_exp(delta[:3]) @ C[:3, :3], C[:3, 3] + delta[3:6])
    if points:
        K2 = tf.make_transform(K[:3, :3], K[:3, 3] + delta[6:9])
    else:
        K2 = tf.make_transform(_so3_exp(delta[6:9]) @ K[:3, :3], K[:3, 3] + delta[9:12])
    return C2, K2


def _levenberg_marquardt(problem, C, K, *, max_iterations, tol=1e-10):
    """Minimise the whitened cost over (C, K). Returns C, K, cost, iterations, converged."""
    cost = problem.whitened_residual_only(C, K)[0]
    lam = 1e-6
    for it in range(1, max_iterations + 1):
        r, J = problem.whitened(C, K)
        H = J.T @ J
        g = J.T @ r
        while True:
            try:
                delta = -np.linalg.solve(H + lam * np.diag(np.diag(H)), g)
            except np.linalg.LinAlgError:
                raise DegenerateMotionError("the motions do not constrain every unknown (singular normal equations)") from None
            C2, K2 = _apply(C, K, delta, problem.points)
            cost2 = problem.whitened_residual_only(C2, K2)[0]
            if cost2 <= cost:
                break
            lam *= 10.0
            if lam > 1e10:
                # No descent direction left: we sit at the minimum to numerical precision.
                return C, K, cost, it, True
        lam = max(lam / 10.0, 1e-12)
        step = np.abs(delta).max()
        rel = (cost - cost2) / max(cost, 1e-300)
        C, K, cost = C2, K2, cost2
        if step < tol or rel < 1e-14:
            return C, K, cost, it, True
    return C, K, cost, max_iterations, False


def _marker_rotation(C, M, R_B):
    """Best R_K given C for pose data: chordal mean of R_M^T R_C R_B (the nuisance rotation)."""
    S = (np.swapaxes(M[:, :3, :3], 1, 2) @ C[:3, :3] @ R_B).sum(axis=0)
    return tf.project_to_so3(S)


def _point_weights(B, point_cov):
    """Whitening matrices for the translation residual and whether ``point_cov`` was given."""
    p = B if B.ndim == 2 else B[:, :3, 3]
    cov = check_point_cov(point_cov, len(p))
    given = cov is not None
    if not given:
        cov = default_point_cov(p)
    return _whitener(cov), given


def _pose_noise(problem, C, K, W0):
    """Rotation sigma (rad) and scale of the ``W0``-whitened translation covariance, from the residuals (pose data)."""
    r, e, _, _ = problem.raw(C, K)
    n = len(r)
    dof = max(3 * n - 6, 1)                                # each residual block carries half of the 12 unknowns
    rw = np.einsum("nij,nj->ni", W0, r)
    sigma_rot = max(float(np.sqrt(np.sum(e**2) / dof)), 1e-9)
    scale_t = max(float(np.sum(rw**2) / dof), 1e-18)
    return sigma_rot, scale_t


def _information(problem, C, K):
    _, J = problem.whitened(C, K)
    return J.T @ J


def _camera_block(info):
    """6x6 camera block of the inverse information, after a degeneracy check."""
    ev = np.linalg.eigvalsh(info)
    if ev[0] <= MIN_INFORMATION_RATIO * ev[-1]:
        raise DegenerateMotionError(
            "the motions do not constrain every unknown "
            f"(Fisher information eigenvalue ratio {ev[0] / ev[-1]:.1e}); vary the flange rotation"
        )
    cov = np.linalg.inv(info)[:6, :6]
    return 0.5 * (cov + cov.T)


def _min_samples(points: bool) -> int:
    return 3 if points else 2


def _prepare(X, Y, A, B, setup, point_cov):
    """Validated problem at (X, Y): returns problem, C, K, whether the point covariance was given, A, B."""
    setup = check_setup(setup)
    A, B = check_measurements(A, B)
    X = tf.check_transform(X, "X")
    Y = tf.check_transform(Y, "Y")
    points = B.ndim == 2
    if len(A) < _min_samples(points):
        raise InsufficientDataError(f"need at least {_min_samples(points)} samples, got {len(A)}")
    C, K, M = _split(X, Y, A, setup)
    W_t, given = _point_weights(B, point_cov)
    problem = _Problem(M, B, W_t)
    if not points:
        K = tf.make_transform(_marker_rotation(C, M, B[:, :3, :3]), K[:3, 3])
    return problem, C, K, given, A, B


def _variance_factor(cost: float, dof: int, given: bool) -> float:
    """A posteriori variance factor for point data (see `covariance`)."""
    if dof <= 0:
        return 1.0
    s2 = cost / dof
    if given and cost <= chi2.ppf(CHI2_REJECT, dof):
        return 1.0
    return s2


# --------------------------------------------------------------------------- public API


def covariance(X, Y, A, B, *, setup: str, point_cov=None) -> np.ndarray:
    """Covariance (6, 6) of the camera transform of a calibration.

    The camera transform is ``Y = T_base_cam`` (eye-to-hand) or
    ``X = T_flange_cam`` (eye-in-hand); the 6-vector is
    ``[delta_rotvec (rad), delta_t (m)]`` with ``R_true = Exp(delta) R_est``,
    ``t_true = t_est + delta_t`` (`calib.result`). Computed as the camera block
    of the inverse Fisher information ``(J^T W J)^-1`` of the measurement model
    (module docstring; the equation of translation, paper eq. 5, plus eq. 4 for
    pose data) linearised at the estimate, which marginalises the marker-side
    unknowns.

    Parameters
    ----------
    X, Y : array_like, shape (4, 4)
        The estimate (paper eq. 1). For pose data the rotation of the
        marker-side transform is a nuisance and is re-estimated from the data,
        so a point-only estimate (identity placeholder) is fine.
    A : array_like, shape (N, 4, 4)
        ``T_base_flange``.
    B : array_like, shape (N, 3) or (N, 4, 4)
        Marker center in the camera frame, or ``T_cam_marker``.
    setup : {"eye_to_hand", "eye_in_hand"}
    point_cov : array_like, shape (3, 3) or (N, 3, 3), optional
        Covariance of the marker center, m^2. Trusted as given unless the
        residuals reject it (chi-square test at `CHI2_REJECT`), in which case
        it is inflated by the a posteriori variance factor. Without it the
        depth model of `calib.noise` gives the shape and the residuals the
        scale. For pose data the rotation noise is always estimated from the
        residuals.

    Returns
    -------
    cov : ndarray, shape (6, 6)

    Raises
    ------
    CalibrationError, InsufficientDataError, DegenerateMotionError
    """
    problem, C, K, given, _, _ = _prepare(X, Y, A, B, setup, point_cov)
    if problem.points:
        cost = problem.whitened_residual_only(C, K)[0]
        factor = _variance_factor(cost, 3 * len(problem.p) - 9, given)
        return factor * _camera_block(_information(problem, C, K))
    sigma_rot, scale_t = _pose_noise(problem, C, K, problem.W_t)
    problem.sigma_rot = sigma_rot
    problem.W_t = problem.W_t / np.sqrt(scale_t)
    return _camera_block(_information(problem, C, K))


def kron_t_prime_covariance(X, Y, A, B, *, setup: str, point_cov=None) -> np.ndarray:
    """First-order covariance (6, 6) of the closed-form YKronT' estimate of the camera transform.

    The covariance of the estimator itself (delta method / sandwich), not of
    the ML estimate: YKronT' is unweighted least squares and so less efficient,
    and `covariance` (inverse Fisher information) would be over-confident for
    it. Each marker point ``p_i`` is perturbed by ``dp_i`` (covariance
    ``Sigma_i``) and the perturbation is propagated analytically through the
    three steps of `calib.solvers.y_kron_t_prime`:

    1. the 3N x 15 least squares of eq. 20, ``M x = b`` with
       ``x = [vec(Q); t_1; t_2]``:
       ``dx = (M^T M)^-1 sum_i (dM_i^T e_i - M_i^T E_i dp_i)``, ``e = b - M x``,
       ``E_i = Q`` (eye-to-hand) or ``R_Ai Q`` (eye-in-hand) (the residual
       term is second order in the noise but keeps the Jacobian exact);
    2. the projection ``R = polar(Q)`` onto SO(3): with ``Q = R P``,
       ``delta = R (tr(P) I - P)^-1 vex(R^T dQ - dQ^T R)`` (left perturbation);
    3. the re-solve of the two translations with ``R`` fixed (the 3N x 6
       system ``T2 t = c``): ``dt = (T2^T T2)^-1 sum_i T2_i^T dc_i``, with
       ``dc_i = -R dp_i + [R p_i]x delta`` (eye-to-hand) or
       ``-R_Ai R dp_i + R_Ai [R p_i]x delta`` (eye-in-hand).

    Then ``cov = sum_i J_i Sigma_i J_i^T``. ``Sigma_i`` is ``point_cov``
    (trusted unless the chi-square test at `CHI2_REJECT` rejects it at the
    estimate, then scaled by the a posteriori variance factor) or the depth
    model of `calib.noise` scaled from the residuals, as in `covariance`.
    Robot poses are taken as exact.

    Parameters
    ----------
    X, Y : array_like, shape (4, 4)
        The YKronT' estimate. Eye-to-hand: ``X = T_flange_marker``,
        ``Y = T_base_cam`` (camera); eye-in-hand: ``X = T_flange_cam``
        (camera), ``Y = T_base_marker``.
    A : array_like, shape (N, 4, 4)
        ``T_base_flange``.
    B : array_like, shape (N, 3) or (N, 4, 4)
        Marker center in the camera frame (m); of a pose only the translation is used.
    setup : {"eye_to_hand", "eye_in_hand"}
    point_cov : array_like, shape (3, 3) or (N, 3, 3), optional
        Marker center covariance, m^2.

    Returns
    -------
    cov : ndarray, shape (6, 6)
        ``[delta_rotvec (rad), delta_t (m)]`` of the camera transform (`calib.result`).

    Raises
    ------
    CalibrationError, InsufficientDataError, DegenerateMotionError
    """
    p = np.asarray(B, dtype=float)
    p = p[:, :3, 3] if p.ndim == 3 else p
    problem, C, K, given, A, _ = _prepare(X, Y, A, p, setup, point_cov)
    n = len(A)
    cov_p = check_point_cov(point_cov, n)
    if cov_p is None:
        cov_p = default_point_cov(p)
    factor = _variance_factor(problem.whitened_residual_only(C, K)[0], 3 * n - 9, given)

    R_A, t_A = A[:, :3, :3], A[:, :3, 3]
    # Step 1: the system of eq. 20 exactly as `calib.solvers._y_kron_t_prime` builds it.
    M = np.empty((n, 3, 15))
    T2 = np.empty((n, 3, 6))
    if setup == Setup.EYE_TO_HAND:
        M[:, :, :9] = (p[:, None, :, None] * _I3[None, :, None, :]).reshape(n, 3, 9)
        M[:, :, 9:12] = _I3
        M[:, :, 12:] = -R_A
        rhs = t_A
        T2[:, :, :3] = _I3
        T2[:, :, 3:] = -R_A
    else:
        M[:, :, :9] = (R_A[:, :, None, :] * p[:, None, :, None]).reshape(n, 3, 9)
        M[:, :, 9:12] = R_A
        M[:, :, 12:] = -_I3
        rhs = -t_A
        T2[:, :, :3] = R_A
        T2[:, :, 3:] = -_I3
    Mf = M.reshape(3 * n, 15)
    H_inv = np.linalg.inv(Mf.T @ Mf)
    x = H_inv @ (Mf.T @ rhs.reshape(-1))
    Q = x[:9].reshape(3, 3).T                                         # unvec, column-major
    e = rhs - M @ x                                                   # (N, 3) residuals of eq. 20
    if setup == Setup.EYE_TO_HAND:
        E, u = Q, e
    else:
        E, u = R_A @ Q, np.einsum("nji,nj->ni", R_A, e)
    # d(M_i^T e_i) through M_i: (dp^T kron R)^T e = vec(R^T e dp^T), entry 3c + r = u_r dp_c.
    N_res = np.zeros((n, 15, 3))
    for c in range(3):
        N_res[:, 3 * c:3 * c + 3, c] = u
    L = np.swapaxes(M, 1, 2) @ E - N_res                              # (N, 15, 3)
    # Step 2: derivative of the polar factor, one column per entry of vec(Q).
    R = tf.project_to_so3(Q)
    P = R.T @ Q
    P = 0.5 * (P + P.T)
    dQ = np.zeros((9, 3, 3))
    dQ[np.arange(9), np.arange(9) % 3, np.arange(9) // 3] = 1.0       # vec is column-major
    K_skew = R.T @ dQ - np.swapaxes(dQ, 1, 2) @ R
    k = np.stack([K_skew[:, 2, 1], K_skew[:, 0, 2], K_skew[:, 1, 0]], axis=1)   # (9, 3)
    D = R @ np.linalg.solve(np.trace(P) * _I3 - P, k.T)                # (3, 9): d delta / d vec(Q)
    J_rot = -(D @ H_inv[:9]) @ L                                      # (N, 3, 3): d delta / d p_i
    # Step 3: translations re-solved with R fixed.
    Rp = p @ R.T
    if setup == Setup.EYE_TO_HAND:
        F, G = -R, _skew(Rp)
    else:
        F, G = -R_A @ R, R_A @ _skew(Rp)
    T2t = np.swapaxes(T2, 1, 2)
    T2f = T2.reshape(3 * n, 6)
    H2_inv = np.linalg.inv(T2f.T @ T2f)[:3]                           # the camera translation is t[:3]
    S = T2f.T @ G.reshape(3 * n, 3)                                   # sum_i T2_i^T G_i, (6, 3)
    J_t = H2_inv @ (T2t @ F + S @ J_rot)                              # (N, 3, 3)
    J = np.concatenate([J_rot, J_t], axis=1)                          # (N, 6, 3)
    # sum_i J_i Sigma_i J_i^T as one (6 x 3N) (3N x 6) product.
    JS = np.swapaxes(J @ cov_p, 0, 1).reshape(6, 3 * n)
    cov = factor * (JS @ np.swapaxes(J, 0, 1).reshape(6, 3 * n).T)
    return 0.5 * (cov + cov.T)


def delta_method_covariance(estimator, X, Y, A, B, *, setup: str, point_cov=None, step: float = 1e-3) -> np.ndarray:
    """Numerical first-order covariance (6, 6) of any closed-form estimator from marker poses.

    The sandwich ``sum_i J_i Sigma_i J_i^T`` of the estimator ``(A, B) ->
    camera transform`` itself (delta method), with ``J_i`` by forward
    differences: each sample's marker pose ``B_i`` (``T_cam_marker``) is moved
    along the 6 principal directions of its noise, ``step`` standard
    deviations at a time, and the closed form is re-run (6N runs). The noise
    model is the one of `refine` for pose data: rotation noise
    ``R_B Exp(e)``, ``e ~ N(0, sigma_rot^2 I)``, and translation noise of
    covariance ``s * Sigma_i`` (``point_cov`` or the depth model of
    `calib.noise`), with ``sigma_rot`` and ``s`` estimated from the residuals
    of the ML fit started at ``(X, Y)`` (the closed form's own residuals would
    count its estimation error as noise). Robot poses are taken as exact.

    Setups: eye-to-hand ``X = T_flange_marker``, ``Y = T_base_cam``
    (camera); eye-in-hand ``X = T_flange_cam`` (camera), ``Y = T_base_marker``.

    Parameters
    ----------
    estimator : callable
        ``estimator(A, B) -> (X, Y)``, the closed form (e.g. YQuatT', paper eq. 19).
    X, Y : array_like, shape (4, 4)
        Its estimate on the unperturbed data.
    A : array_like, shape (N, 4, 4)
        ``T_base_flange``.
    B : array_like, shape (N, 4, 4)
        ``T_cam_marker``.
    setup : {"eye_to_hand", "eye_in_hand"}
    point_cov : array_like, shape (3, 3) or (N, 3, 3), optional
        Covariance of the marker translation, m^2 (its scale is re-estimated).
    step : float
        Finite-difference step in noise standard deviations.

    Returns
    -------
    cov : ndarray, shape (6, 6)
        ``[delta_rotvec (rad), delta_t (m)]`` of the camera transform (`calib.result`).

    Raises
    ------
    CalibrationError, InsufficientDataError, DegenerateMotionError
    """
    problem, C, K, _, A, B = _prepare(X, Y, A, B, setup, point_cov)
    if problem.points:
        raise CalibrationError("delta_method_covariance needs marker poses B of shape (N, 4, 4)")
    W0 = problem.W_t
    for _ in range(2):
        sigma_rot, scale_t = _pose_noise(problem, C, K, W0)
        problem.sigma_rot, problem.W_t = sigma_rot, W0 / np.sqrt(scale_t)
        C, K = _levenberg_marquardt(problem, C, K, max_iterations=50)[:2]
    sigma_rot, scale_t = _pose_noise(problem, C, K, W0)
    cov_t = check_point_cov(point_cov, len(B))
    if cov_t is None:
        cov_t = default_point_cov(B[:, :3, 3])
    L_t = np.linalg.cholesky(scale_t * cov_t)                          # (N, 3, 3) noise directions
    rot_steps = _so3_exp(np.eye(3) * (step * sigma_rot))               # (3, 3, 3)

    base = _split(*estimator(A, B), A, setup)[0]
    base_inv_R, base_t = base[:3, :3].T, base[:3, 3]
    J = np.empty((len(B), 6, 6))
    B_pert = B.copy()
    for i in range(len(B)):
        for k in range(6):
            if k < 3:
                B_pert[i, :3, :3] = B[i, :3, :3] @ rot_steps[k]
            else:
                B_pert[i, :3, 3] = B[i, :3, 3] + step * L_t[i, :, k - 3]
            cam = _split(*estimator(A, B_pert), A, setup)[0]
            J[i, :3, k] = _so3_log((cam[:3, :3] @ base_inv_R)[None])[0]
            J[i, 3:, k] = cam[:3, 3] - base_t
            B_pert[i] = B[i]
    J /= step
    cov = np.einsum("nij,nkj->ik", J, J)
    return 0.5 * (cov + cov.T)


def cramer_rao_bound(X, Y, A, point_cov, *, setup: str) -> tuple[float, float, np.ndarray]:
    """Cramér-Rao lower bound of the camera transform from point data, at the truth.

    Parameters
    ----------
    X, Y : array_like, shape (4, 4)
        The true transforms (paper eq. 1).
    A : array_like, shape (N, 4, 4)
        True ``T_base_flange`` of the samples.
    point_cov : array_like, shape (3, 3) or (N, 3, 3)
        True covariance of the measured marker centers, m^2.
    setup : {"eye_to_hand", "eye_in_hand"}

    Returns
    -------
    rot_rms : float
        ``sqrt(trace)`` of the rotation block of the inverse Fisher information
        (rad): the smallest RMS rotation error any unbiased estimator reaches.
    trans_rms : float
        The same for the translation block (m).
    cov : ndarray, shape (6, 6)
        The camera block of the inverse Fisher information.
    """
    setup = check_setup(setup)
    A = tf.check_transforms(A, "A")
    X = tf.check_transform(X, "X")
    Y = tf.check_transform(Y, "Y")
    C, K, M = _split(X, Y, A, setup)
    p_true = tf.transform_points(tf.invert(C) @ M, K[:3, 3])
    cov_p = check_point_cov(point_cov, len(A))
    if cov_p is None:
        raise CalibrationError("point_cov is required for the Cramér-Rao bound")
    problem = _Problem(M, p_true, _whitener(cov_p))
    cov = _camera_block(_information(problem, C, K))
    return float(np.sqrt(np.trace(cov[:3, :3]))), float(np.sqrt(np.trace(cov[3:, 3:]))), cov


def error_vector(T_est, T_true) -> np.ndarray:
    """Error ``[delta_rotvec, delta_t]`` (6,) of an estimate in the `calib.result` convention.

    ``R_true = Exp(delta_rotvec) R_est``, ``t_true = t_est + delta_t``; rad and m.
    """
    T_est = tf.check_transform(T_est, "T_est")
    T_true = tf.check_transform(T_true, "T_true")
    d = _so3_log((T_true[:3, :3] @ T_est[:3, :3].T)[None])[0]
    return np.concatenate([d, T_true[:3, 3] - T_est[:3, 3]])


def nees(T_est, T_true, cov) -> float:
    """Normalised estimation error squared ``e^T cov^-1 e`` of a 6-dof estimate (mean 6 if ``cov`` is honest)."""
    cov = np.asarray(cov, dtype=float)
    if cov.shape != (6, 6):
        raise CalibrationError(f"cov must have shape (6, 6), got {cov.shape}")
    e = error_vector(T_est, T_true)
    return float(e @ np.linalg.solve(cov, e))


def residuals(X, Y, A, B, *, setup: str) -> Residuals:
    """Per-sample residuals of ``A_i X = Y B_i`` (paper eq. 1) in the camera frame.

    Translation: distance between the measured and the predicted marker center
    (m). Rotation (pose data only): angle of ``R_B^T R_C^T R_M R_K`` (rad).
    """
    setup = check_setup(setup)
    A, B = check_measurements(A, B)
    return _residuals(tf.check_transform(X, "X"), tf.check_transform(Y, "Y"), A, B, setup)


def _residuals(X, Y, A, B, setup) -> Residuals:
    C, K, M = _split(X, Y, A, setup)
    p = B if B.ndim == 2 else B[:, :3, 3]
    r = _point_residuals(C, K[:3, 3], M, p)[0]
    rot = None
    if B.ndim == 3:
        E = np.swapaxes(B[:, :3, :3], 1, 2) @ C[:3, :3].T @ M[:, :3, :3] @ K[:3, :3]
        rot = tf.rotation_angle(E)
    return Residuals(translation=np.linalg.norm(r, axis=1), rotation=rot)


def refine(initial: CalibrationResult, A, B, *, point_cov=None, max_iterations: int = 50) -> CalibrationResult:
    """Maximum-likelihood refinement of a calibration from any closed-form start.

    Point data (``B`` (N, 3)): minimises ``sum_i r_i^T Sigma_i^-1 r_i`` with the
    equation of translation (paper eq. 5) in the camera frame,
    ``r_i = p_i - (C^-1 M_i K)`` translation (module docstring), over the camera
    transform (6 dof) and the marker translation (3). ``Sigma_i`` is
    ``point_cov`` or the depth model of `calib.noise`. Pose data
    (``B`` (N, 4, 4) ``T_cam_marker``): adds the rotation residual and
    estimates both transforms (6 + 6 dof); the rotation and translation noise
    levels are re-estimated from the residuals between two LM passes.

    Setups: eye-to-hand ``X = T_flange_marker``, ``Y = T_base_cam``;
    eye-in-hand ``X = T_flange_cam``, ``Y = T_base_marker`` (``initial.setup``).

    Parameters
    ----------
    initial : CalibrationResult
        Start (e.g. YKronT'). Its method name is kept with ``"+ML"`` appended.
    A : array_like, shape (N, 4, 4)
        ``T_base_flange``.
    B : array_like, shape (N, 3) or (N, 4, 4)
    point_cov : array_like, shape (3, 3) or (N, 3, 3), optional
        Marker center covariance, m^2.
    max_iterations : int
        Per LM pass.

    Returns
    -------
    CalibrationResult
        With ``cov`` (see `covariance`), ``converged``, ``iterations`` and
        ``info["cost"]`` (final chi-square), ``info["initial_cost"]``,
        ``info["variance_factor"]`` (point data).

    Raises
    ------
    CalibrationError, InsufficientDataError, DegenerateMotionError
    """
    if not isinstance(initial, CalibrationResult):
        raise CalibrationError(f"initial must be a CalibrationResult, got {type(initial).__name__}")
    setup = initial.setup
    problem, C, K, given, A, B = _prepare(initial.X, initial.Y, A, B, setup, point_cov)
    if problem.points:
        initial_cost = problem.whitened_residual_only(C, K)[0]
        C, K, cost, iters, converged = _levenberg_marquardt(problem, C, K, max_iterations=max_iterations)
        factor = _variance_factor(cost, 3 * len(problem.p) - 9, given)
        cov = factor * _camera_block(_information(problem, C, K))
        info = {"cost": cost, "initial_cost": initial_cost, "variance_factor": factor}
        rotation_known = initial.marker_rotation_known
    else:
        W0 = problem.W_t
        iters, initial_cost = 0, None
        # Pass 1 weights come from the start's residuals, pass 2 from pass 1's.
        for _ in range(2):
            sigma_rot, scale_t = _pose_noise(problem, C, K, W0)
            problem.sigma_rot, problem.W_t = sigma_rot, W0 / np.sqrt(scale_t)
            if initial_cost is None:
                initial_cost = problem.whitened_residual_only(C, K)[0]
            C, K, cost, it, converged = _levenberg_marquardt(problem, C, K, max_iterations=max_iterations)
            iters += it
        sigma_rot, scale_t = _pose_noise(problem, C, K, W0)
        problem.sigma_rot, problem.W_t = sigma_rot, W0 / np.sqrt(scale_t)
        cov = _camera_block(_information(problem, C, K))
        info = {"cost": cost, "initial_cost": initial_cost, "sigma_rotation": sigma_rot, "translation_scale": scale_t}
        rotation_known = True
    X, Y = _join(C, K, setup)
    return dataclasses.replace(
        initial,
        method=f"{initial.method}+ML",
        X=X,
        Y=Y,
        n_samples=len(A),
        residuals=_residuals(X, Y, A, B, setup),
        cov=cov,
        marker_rotation_known=rotation_known,
        converged=converged,
        iterations=iters,
        info={**initial.info, **info},
    )


def point_jacobian(X, Y, A, *, setup: str) -> tuple[np.ndarray, np.ndarray]:
    """Predicted marker points and their Jacobian w.r.t. the point model's unknowns.

    The point model of the module docstring (paper eq. 5), for flange poses
    that have not been measured yet: what the camera would see, and how that
    depends on the unknowns ``[dC, tC, tK]`` (left rotation perturbation and
    translation of the camera transform C, translation of the marker-side K).

    Parameters
    ----------
    X, Y : array_like, shape (4, 4)
        Eye-to-hand: ``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand:
        ``X = T_flange_cam``, ``Y = T_base_marker``.
    A : array_like, shape (N, 4, 4)
        ``T_base_flange``.
    setup : {"eye_to_hand", "eye_in_hand"}

    Returns
    -------
    points : ndarray, shape (N, 3)
        Marker center in the camera frame, m.
    J : ndarray, shape (N, 3, 9)
        ``d points / d [dC, tC, tK]``.
    """
    check_setup(setup)
    C, K, M = _split(tf.check_transform(X, "X"), tf.check_transform(Y, "Y"), tf.check_transforms(A, "A"), setup)
    r, J_dC, J_tC, J_tK = _point_residuals(C, K[:3, 3], M, np.zeros((len(M), 3)))
    return -r, -np.concatenate([J_dC, J_tC, J_tK], axis=2)
