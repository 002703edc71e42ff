"""Variance components of the model (Helmert / REML scoring): the noise levels from the residuals."""

from __future__ import annotations

import numpy as np

from handeye.calib.model.linearization import Linearization
from handeye.calib.model.rows import COL, EYE_ROW, ROW
from handeye.calib.model.weights import MIN_POINT_SCALE, MIN_ROBOT_SIGMA, MIN_ROTATION_SIGMA, NoiseLevels


def variance_components(problem: Linearization, C, K, theta, shape, robot_cof, noise: NoiseLevels,
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
    (r, e, J_t, J_e), v, G, NG, Nmat = problem.system(C, K, theta)
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
    V[2] = (v[:, ROW] * v[:, COL]).reshape(-1)
    V[3] = np.tile(EYE_ROW, n)
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
    numpy's solve and index bookkeeping would cost more than the arithmetic here.
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
