"""What the motions leave open of the two translations, and the prior that holds it.

The marker point depends on the translations of the camera transform ``C``
and the marker-side transform ``K`` (`handeye.calib.model`) only through
``w_i = R_Mi t_K + t_Mi - t_C``. A change ``(dt_C, dt_K)`` with
``R_Mi dt_K = dt_C`` for every sample moves no prediction: the samples do not
determine it. That is the null space of the paper's eq. 6 ``[R_A, -I]``
(`open_translations`): three directions when the flange never turns (every
``R_Mi`` the same: pure translations), one when it turns about one axis ``u``
only (``dt_K = u`` eye-to-hand, ``dt_C = u`` eye-in-hand, the other side
``R_A u``). Everything else (the camera's rotation, its correction, the
translations' determined combination) stays determined.

`TranslationPrior` is a Gaussian prior on ``[t_C, t_K]`` (6,): whitened rows
``L`` and a target ``t0``, residual ``L (t - t0)``. It holds a known marker
mount (``L = I / sigma`` on ``t_K``) or, at `HELD_SIGMA_M`, the open
directions at a chosen value; `handeye.calib.model.Linearization` adds it to its
normal equations, so the fit, the variance components, the held-out errors
and the covariance all see it. The covariance is then the one given the held
values: along an open direction the camera's position moves one-for-one
with what was held.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: 1-sigma (m) of a value the prior holds ("held fixed"): small enough to add nothing to any 1-sigma here,
#: large enough that the information stays well conditioned (1e10 m^-2 against ~1e5-1e8 from the data).
HELD_SIGMA_M = 1e-5


@dataclass(frozen=True)
class TranslationPrior:
    """Prior rows on the translations ``t = [t_C, t_K]`` (6,), m: residual ``rows @ (t - target)``, unit variance.

    Attributes
    ----------
    rows : ndarray, shape (k, 6)
        Whitened rows (1/m): a direction divided by its 1-sigma.
    target : ndarray, shape (6,)
        The value held, m.
    """

    rows: np.ndarray
    target: np.ndarray

    def residual(self, C, K) -> np.ndarray:
        """Whitened prior residual (k,) at ``(C, K)``."""
        t = np.concatenate([C[:3, 3], K[:3, 3]])
        return self.rows @ (t - self.target)

    def jacobian(self, n_pose: int, n_params: int) -> np.ndarray:
        """Jacobian (k, n_params) of `residual` in the parameter order of `handeye.calib.model.Linearization`
        (``[dC, tC, (dK), tK, camera]``: ``tC`` columns 3:6, ``tK`` the last three pose columns)."""
        J = np.zeros((len(self.rows), n_params))
        J[:, 3:6] = self.rows[:, :3]
        J[:, n_pose - 3:n_pose] = self.rows[:, 3:]
        return J


def open_translations(M, rtol: float) -> np.ndarray:
    """Directions ``[dt_C, dt_K]`` (6, k) of the translations that the robot transforms ``M`` (N, 4, 4) leave open.

    The right singular vectors of the stacked ``[-I, R_Mi]`` (paper eq. 6 in
    the model's terms) whose singular value is below ``rtol`` times the
    largest, orthonormal; k = 3 for pure translations, 1 for rotations about
    one axis, 0 when the flange turns about two axes or more.
    """
    n = len(M)
    S = np.empty((n, 3, 6))
    S[:, :, :3] = -np.eye(3)
    S[:, :, 3:] = M[:, :3, :3]
    w, V = np.linalg.eigh(np.einsum("nij,nik->jk", S, S))   # ascending
    s = np.sqrt(np.clip(w, 0.0, None))
    return V[:, s < rtol * s[-1]]


def held_prior(directions, target, sigma: float = HELD_SIGMA_M) -> TranslationPrior:
    """`TranslationPrior` holding the components of ``t = [t_C, t_K]`` along ``directions`` (6, k) at ``target`` (6,)."""
    Q, _ = np.linalg.qr(np.asarray(directions, dtype=float))
    return TranslationPrior(rows=Q.T / sigma, target=np.asarray(target, dtype=float))
