"""Maximum-likelihood refinement and covariance of a hand-eye calibration (the paper's model).

The measurement model (residuals, Jacobians, whitening, information) is
`handeye.calib.model`, with the camera ``C`` and marker-side ``K`` transforms of
both setups: eye-to-hand ``C = Y = T_base_cam``, ``K = X = T_flange_marker``;
eye-in-hand ``C = X = T_flange_cam``, ``K = Y = T_base_marker``. Here it is
used without camera nuisance parameters or robot error (see `handeye.calib.auto` for
the extended model).

Point data (``B`` of shape (N, 3), the marker center in the camera frame)
constrain ``C`` (6 dof) and the translation ``t_K`` (3); the residual is the
equation of translation (paper eq. 5) in the camera frame,
``r_i = p_i - R_C^T (R_Mi t_K + t_Mi - t_C)``, weighted by the inverse point
covariance (Mahalanobis). Pose data (``B`` of shape (N, 4, 4)) add the
rotation residual ``e_i = Log(R_Bi^T R_C^T R_Mi R_K)`` (marker frame), so
``C`` and ``K`` (6 + 6 dof) are estimated; the rotation noise level and the
scale of the translation covariance are estimated from the residuals.

Perturbations follow `handeye.calib.result`: ``R = Exp(d) R_est``, ``t = t_est + dt``
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
from scipy.stats import chi2

from handeye.calib import model
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError, InsufficientDataError
from handeye.calib.model import check_point_cov
from handeye.calib.noise import default_point_cov
from handeye.calib.problem import CalibrationProblem
from handeye.calib.result import CalibrationResult, RefineDetails, Residuals
from handeye.calib.setup import Setup, check_setup

#: A given ``point_cov`` is trusted unless the residuals reject it at this level;
#: then the covariance is inflated by the a posteriori variance factor.
CHI2_REJECT = 0.999
_I3 = np.eye(3)


def _pose_noise(problem, C, K, W0):
    """Rotation sigma (rad) and scale of the ``W0``-whitened translation covariance, from the residuals (pose data)."""
    r, e, _, _ = problem.raw(C, K)
    n = len(r)
    dof = max(3 * n - 6, 1)                                # each residual block carries half of the 12 unknowns
    rw = np.einsum("nij,nj->ni", W0, r)
    sigma_rot = max(float(np.sqrt(np.sum(e**2) / dof)), 1e-9)
    scale_t = max(float(np.sum(rw**2) / dof), 1e-18)
    return sigma_rot, scale_t


def _min_samples(points: bool) -> int:
    return 3 if points else 2


def _prepare(X, Y, problem: CalibrationProblem, B=None):
    """The model at (X, Y) of the problem's samples (or of their measurements ``B``): the linearisation,
    C, K and whether the point covariance was given."""
    X = tf.check_transform(X, "X")
    Y = tf.check_transform(Y, "Y")
    B = problem.B if B is None else B
    points = B.ndim == 2
    if problem.n < _min_samples(points):
        raise InsufficientDataError(f"need at least {_min_samples(points)} samples, got {problem.n}")
    C, K, M = model.split(X, Y, problem.A, problem.setup)
    W_t, given = model.point_weights(B, problem.point_cov)
    lin = model.Linearization(M, B, W_t)
    if not points:
        K = tf.make_transform(model.marker_rotation(C, M, B[:, :3, :3]), K[:3, 3])
    return lin, C, K, given


def _variance_factor(cost: float, dof: int, given: bool) -> float:
    """A posteriori variance factor for point data (see `covariance`)."""
    if dof <= 0:
        return 1.0
    s2 = cost / dof
    if given and cost <= chi2.ppf(CHI2_REJECT, dof):
        return 1.0
    return s2


# --------------------------------------------------------------------------- public API


def covariance(X, Y, problem: CalibrationProblem) -> np.ndarray:
    """Covariance (6, 6) of the camera transform of a calibration.

    The camera transform is ``Y = T_base_cam`` (eye-to-hand) or
    ``X = T_flange_cam`` (eye-in-hand); the 6-vector is
    ``[delta_rotvec (rad), delta_t (m)]`` with ``R_true = Exp(delta) R_est``,
    ``t_true = t_est + delta_t`` (`handeye.calib.result`). Computed as the camera block
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
    problem : CalibrationProblem
        The samples. A point covariance is trusted as given unless the
        residuals reject it (chi-square test at `CHI2_REJECT`), in which case
        it is inflated by the a posteriori variance factor. Without it the
        depth model of `handeye.calib.noise` gives the shape and the residuals the
        scale. For pose data the rotation noise is always estimated from the
        residuals.

    Returns
    -------
    cov : ndarray, shape (6, 6)

    Raises
    ------
    CalibrationError, InsufficientDataError, DegenerateMotionError
    """
    lin, C, K, given = _prepare(X, Y, problem)
    if lin.points:
        cost = lin.cost(C, K)
        factor = _variance_factor(cost, 3 * len(lin.p) - 9, given)
        return factor * model.camera_block(model.information(lin, C, K))
    sigma_rot, scale_t = _pose_noise(lin, C, K, lin.W_t)
    lin.sigma_rot = sigma_rot
    lin.W_t = lin.W_t / np.sqrt(scale_t)
    return model.camera_block(model.information(lin, C, K))


def kron_t_prime_covariance(X, Y, problem: CalibrationProblem) -> np.ndarray:
    """First-order covariance (6, 6) of the closed-form YKronT' estimate of the camera transform.

    The covariance of the estimator itself (delta method / sandwich), not of
    the ML estimate: YKronT' is unweighted least squares and so less efficient,
    and `covariance` (inverse Fisher information) would be over-confident for
    it. Each marker point ``p_i`` is perturbed by ``dp_i`` (covariance
    ``Sigma_i``) and the perturbation is propagated analytically through the
    three steps of `handeye.calib.solvers.y_kron_t_prime`:

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
    model of `handeye.calib.noise` scaled from the residuals, as in `covariance`.
    Robot poses are taken as exact.

    Parameters
    ----------
    X, Y : array_like, shape (4, 4)
        The YKronT' estimate. Eye-to-hand: ``X = T_flange_marker``,
        ``Y = T_base_cam`` (camera); eye-in-hand: ``X = T_flange_cam``
        (camera), ``Y = T_base_marker``.
    problem : CalibrationProblem
        The samples; of a pose only the translation (the marker centre) is used.

    Returns
    -------
    cov : ndarray, shape (6, 6)
        ``[delta_rotvec (rad), delta_t (m)]`` of the camera transform (`handeye.calib.result`).

    Raises
    ------
    CalibrationError, InsufficientDataError, DegenerateMotionError
    """
    p, A, setup = problem.points, problem.A, problem.setup
    lin, C, K, given = _prepare(X, Y, problem, p)
    n = len(A)
    cov_p = problem.point_cov
    if cov_p is None:
        cov_p = default_point_cov(p)
    factor = _variance_factor(lin.cost(C, K), 3 * n - 9, given)

    J = _kron_t_prime_jacobian(A, p, setup)
    # sum_i J_i Sigma_i J_i^T as one (6 x 3N) (3N x 6) product.
    JS = np.swapaxes(J @ cov_p, 0, 1).reshape(6, 3 * n)
    cov = factor * (JS @ np.swapaxes(J, 0, 1).reshape(6, 3 * n).T)
    return 0.5 * (cov + cov.T)


def _kron_t_prime_jacobian(A, p, setup) -> np.ndarray:
    """Derivatives (N, 6, 3) of the YKronT' camera transform ``[delta, t]`` w.r.t. each marker point, through
    the three steps of `kron_t_prime_covariance`'s docstring."""
    n = len(A)
    R_A, t_A = A[:, :3, :3], A[:, :3, 3]
    # Step 1: the system of eq. 20 exactly as `handeye.calib.solvers.y_kron_t_prime_unchecked` builds it.
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
        F, G = -R, tf.skew(Rp)
    else:
        F, G = -R_A @ R, R_A @ tf.skew(Rp)
    T2t = np.swapaxes(T2, 1, 2)
    T2f = T2.reshape(3 * n, 6)
    H2_inv = np.linalg.inv(T2f.T @ T2f)[:3]                           # the camera translation is t[:3]
    S = T2f.T @ G.reshape(3 * n, 3)                                   # sum_i T2_i^T G_i, (6, 3)
    J_t = H2_inv @ (T2t @ F + S @ J_rot)                              # (N, 3, 3)
    J = np.concatenate([J_rot, J_t], axis=1)                          # (N, 6, 3)
    return J


def delta_method_covariance(estimator, X, Y, problem: CalibrationProblem, *, step: float = 1e-3) -> np.ndarray:
    """Numerical first-order covariance (6, 6) of any closed-form estimator from marker poses.

    The sandwich ``sum_i J_i Sigma_i J_i^T`` of the estimator ``(A, B) ->
    camera transform`` itself (delta method), with ``J_i`` by forward
    differences: each sample's marker pose ``B_i`` (``T_cam_marker``) is moved
    along the 6 principal directions of its noise, ``step`` standard
    deviations at a time, and the closed form is re-run (6N runs). The noise
    model is the one of `refine` for pose data: rotation noise
    ``R_B Exp(e)``, ``e ~ N(0, sigma_rot^2 I)``, and translation noise of
    covariance ``s * Sigma_i`` (``point_cov`` or the depth model of
    `handeye.calib.noise`), with ``sigma_rot`` and ``s`` estimated from the residuals
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
    problem : CalibrationProblem
        The samples, with marker poses ``T_cam_marker``; the scale of a point
        covariance is re-estimated.
    step : float
        Finite-difference step in noise standard deviations.

    Returns
    -------
    cov : ndarray, shape (6, 6)
        ``[delta_rotvec (rad), delta_t (m)]`` of the camera transform (`handeye.calib.result`).

    Raises
    ------
    CalibrationError, InsufficientDataError, DegenerateMotionError
    """
    A, B, setup = problem.A, problem.B, problem.setup
    if not problem.has_poses:
        raise CalibrationError("delta_method_covariance needs marker poses B of shape (N, 4, 4)")
    lin, C, K, _ = _prepare(X, Y, problem)
    W0 = lin.W_t
    for _ in range(2):
        sigma_rot, scale_t = _pose_noise(lin, C, K, W0)
        lin.sigma_rot, lin.W_t = sigma_rot, W0 / np.sqrt(scale_t)
        C, K = model.minimize(lin, C, K, max_iterations=50)[:2]
    sigma_rot, scale_t = _pose_noise(lin, C, K, W0)
    cov_t = problem.point_cov
    if cov_t is None:
        cov_t = default_point_cov(B[:, :3, 3])
    L_t = np.linalg.cholesky(scale_t * cov_t)                          # (N, 3, 3) noise directions
    rot_steps = tf.so3_exp(np.eye(3) * (step * sigma_rot))               # (3, 3, 3)

    base = model.split(*estimator(A, B), A, setup)[0]
    base_inv_R, base_t = base[:3, :3].T, base[:3, 3]
    J = np.empty((len(B), 6, 6))
    B_pert = B.copy()
    for i in range(len(B)):
        for k in range(6):
            if k < 3:
                B_pert[i, :3, :3] = B[i, :3, :3] @ rot_steps[k]
            else:
                B_pert[i, :3, 3] = B[i, :3, 3] + step * L_t[i, :, k - 3]
            cam = model.split(*estimator(A, B_pert), A, setup)[0]
            J[i, :3, k] = tf.so3_log((cam[:3, :3] @ base_inv_R)[None])[0]
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
    C, K, M = model.split(X, Y, A, setup)
    p_true = tf.transform_points(tf.invert(C) @ M, K[:3, 3])
    cov_p = check_point_cov(point_cov, len(A))
    if cov_p is None:
        raise CalibrationError("point_cov is required for the Cramér-Rao bound")
    problem = model.Linearization(M, p_true, model.whitener(cov_p))
    cov = model.camera_block(model.information(problem, C, K))
    return float(np.sqrt(np.trace(cov[:3, :3]))), float(np.sqrt(np.trace(cov[3:, 3:]))), cov


def error_vector(T_est, T_true) -> np.ndarray:
    """Error ``[delta_rotvec, delta_t]`` (6,) of an estimate in the `handeye.calib.result` convention.

    ``R_true = Exp(delta_rotvec) R_est``, ``t_true = t_est + delta_t``; rad and m.
    """
    T_est = tf.check_transform(T_est, "T_est")
    T_true = tf.check_transform(T_true, "T_true")
    d = tf.so3_log((T_true[:3, :3] @ T_est[:3, :3].T)[None])[0]
    return np.concatenate([d, T_true[:3, 3] - T_est[:3, 3]])


def nees(T_est, T_true, cov) -> float:
    """Normalised estimation error squared ``e^T cov^-1 e`` of a 6-dof estimate (mean 6 if ``cov`` is honest)."""
    cov = np.asarray(cov, dtype=float)
    if cov.shape != (6, 6):
        raise CalibrationError(f"cov must have shape (6, 6), got {cov.shape}")
    e = error_vector(T_est, T_true)
    return float(e @ np.linalg.solve(cov, e))


def residuals(X, Y, problem: CalibrationProblem) -> Residuals:
    """Per-sample residuals of ``A_i X = Y B_i`` (paper eq. 1) in the camera frame.

    Translation: distance between the measured and the predicted marker center
    (m). Rotation (pose data only): angle of ``R_B^T R_C^T R_M R_K`` (rad).
    """
    return _residuals(tf.check_transform(X, "X"), tf.check_transform(Y, "Y"), problem.A, problem.B, problem.setup)


def _residuals(X, Y, A, B, setup) -> Residuals:
    C, K, M = model.split(X, Y, A, setup)
    return Residuals(*model.residual_norms(C, K, M, B))


def refine(initial: CalibrationResult, problem: CalibrationProblem, *, max_iterations: int = 50) -> CalibrationResult:
    """Maximum-likelihood refinement of a calibration from any closed-form start.

    Point data (``B`` (N, 3)): minimises ``sum_i r_i^T Sigma_i^-1 r_i`` with the
    equation of translation (paper eq. 5) in the camera frame,
    ``r_i = p_i - (C^-1 M_i K)`` translation (module docstring), over the camera
    transform (6 dof) and the marker translation (3). ``Sigma_i`` is
    ``point_cov`` or the depth model of `handeye.calib.noise`. Pose data
    (``B`` (N, 4, 4) ``T_cam_marker``): adds the rotation residual and
    estimates both transforms (6 + 6 dof); the rotation and translation noise
    levels are re-estimated from the residuals between two LM passes.

    Setups: eye-to-hand ``X = T_flange_marker``, ``Y = T_base_cam``;
    eye-in-hand ``X = T_flange_cam``, ``Y = T_base_marker`` (``initial.setup``).

    Parameters
    ----------
    initial : CalibrationResult
        Start (e.g. YKronT'). Its method name is kept with ``"+ML"`` appended.
    problem : CalibrationProblem
        The samples (its ``setup`` must be the start's).
    max_iterations : int
        Per LM pass.

    Returns
    -------
    CalibrationResult
        With ``cov`` (see `covariance`), ``converged``, ``iterations`` and
        ``refinement`` (`handeye.calib.result.RefineDetails`: final and initial
        chi-square, the variance factor for point data).

    Raises
    ------
    CalibrationError, InsufficientDataError, DegenerateMotionError
    """
    if not isinstance(initial, CalibrationResult):
        raise CalibrationError(f"initial must be a CalibrationResult, got {type(initial).__name__}")
    setup = initial.setup
    if problem.setup != setup:
        raise CalibrationError(f"initial is a {setup} result, the problem is {problem.setup}")
    A, B = problem.A, problem.B
    lin, C, K, given = _prepare(initial.X, initial.Y, problem)
    if lin.points:
        initial_cost = lin.cost(C, K)
        C, K, _, cost, iters, converged = model.minimize(lin, C, K, max_iterations=max_iterations)
        factor = _variance_factor(cost, 3 * len(lin.p) - 9, given)
        cov = factor * model.camera_block(model.information(lin, C, K))
        details = RefineDetails(cost=cost, initial_cost=initial_cost, variance_factor=factor)
        rotation_known = initial.marker_rotation_known
    else:
        W0 = lin.W_t
        iters, initial_cost = 0, None
        # Pass 1 weights come from the start's residuals, pass 2 from pass 1's.
        for _ in range(2):
            sigma_rot, scale_t = _pose_noise(lin, C, K, W0)
            lin.sigma_rot, lin.W_t = sigma_rot, W0 / np.sqrt(scale_t)
            if initial_cost is None:
                initial_cost = lin.cost(C, K)
            C, K, _, cost, it, converged = model.minimize(lin, C, K, max_iterations=max_iterations)
            iters += it
        sigma_rot, scale_t = _pose_noise(lin, C, K, W0)
        lin.sigma_rot, lin.W_t = sigma_rot, W0 / np.sqrt(scale_t)
        cov = model.camera_block(model.information(lin, C, K))
        details = RefineDetails(cost=cost, initial_cost=initial_cost, sigma_rotation=sigma_rot,
                                translation_scale=scale_t)
        rotation_known = True
    X, Y = model.join(C, K, setup)
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
        refinement=details,
    )
