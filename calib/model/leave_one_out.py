"""Linearised leave-one-out prediction errors of the marker points (hat matrix, Woodbury)."""

from __future__ import annotations

import numpy as np

from handeye.calib.errors import InsufficientDataError
from handeye.calib.model.linearization import Linearization
from handeye.calib.model.rows import inv3, rows, sym3_positive, sym3_positive_rows


#: Leave-one-out: a sample whose residual block has an eigenvalue of ``I - H_ii`` at or below this is one
#: the others cannot do without (leverage 1).
LEVERAGE_MARGIN = 1e-9


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


def leave_one_out(problem: Linearization, C, K, theta=None, point_cov=None) -> tuple[np.ndarray, np.ndarray]:
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


def leave_one_out_after_step(problem: Linearization, C, K, theta=None, point_cov=None):
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
        The step (`Linearization.retract` order).
    """
    return _leave_one_out(problem, C, K, theta, point_cov, step=True)


def _leave_one_out(problem, C, K, theta, point_cov, *, step):
    (r, e, J_t, J_e), rw, G, _, Nmat = problem.system(C, K, theta)
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
    # both from 3x3 closed forms (cheaper than a batched LAPACK call per sample), on entry rows (9, N).
    if k == 3:
        h00, h01, h02, h11, h12, h22 = _hat_rows(G, Ninv)
        s00, s11, s22 = 1.0 - h00, 1.0 - h11, 1.0 - h22
        singular = not sym3_positive_rows(s00, -h01, -h02, s11, -h12, s22, LEVERAGE_MARGIN).all()
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
        X_m = S12 @ inv3(S22 - shift)
        singular = not (sym3_positive(S22, LEVERAGE_MARGIN).all()
                        and sym3_positive(S11 - X_m @ S21, LEVERAGE_MARGIN).all())
        if not singular:
            X = S12 @ inv3(S22)
            S_inv = rows(inv3(S11 - X @ S21))
            rp = (rw[:, :3] - (X @ rw[:, 3:, None])[:, :, 0]).T
    if singular:
        raise InsufficientDataError(f"leave-one-out needs more than {n} samples: without one of them the "
                                    "others do not determine every unknown")
    # Point rows of S^-1 r, back in unwhitened units through L = W^-1 (lower triangular).
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = S_inv
    r0 = a00 * rp[0] + a01 * rp[1] + a02 * rp[2]
    r1 = a10 * rp[0] + a11 * rp[1] + a12 * rp[2]
    r2 = a20 * rp[0] + a21 * rp[1] + a22 * rp[2]
    w00, _, _, w10, w11, _, w20, w21, w22 = rows(W)
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
