"""``auto``'s fit: variance components and the maximum-likelihood fit to them, and a fitted model variant.

Eye-to-hand ``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand
``X = T_flange_cam``, ``Y = T_base_marker`` (paper eq. 1).
"""

from __future__ import annotations

import numpy as np

from handeye.calib import model
from handeye.calib.errors import InsufficientDataError

#: Smallest held-out improvement that counts, m (below it noise-free data would choose at random).
MIN_LOO_GAIN_M = 1e-6


#: A model variant (orientations, a camera parameter) must lower the held-out point error by this fraction.
MIN_LOO_GAIN = 0.03


#: Variance-component rounds: stop when no level changes by more than 1% or after this many.
MAX_ROUNDS = 12


#: LM step (rad, m) below which the fit counts as converged: 10 nm, ~1e-4 of any 1-sigma here (the
#: default 1e-10 of `handeye.calib.model.minimize` often costs one more iteration for nothing).
FIT_TOL = 1e-8


#: Once no noise level changes by more than this, the fit is converged before the next update
#: (that update then usually moves them by under 1%: the last round).
POLISH_CHANGE = 0.05


def fit_components(data: model.WeightedData, C, K, theta, noise, free, estimate=(True, True, True)):
    """Variance components and the fit to them, until both settle.

    Rounds of one LM (Gauss-Newton) step and one variance-component update
    (Fisher scoring of the restricted likelihood in both) while the noise
    levels still move by `POLISH_CHANGE` or more; then the fit is converged
    with those levels and the components are updated once more, until
    that update moves them by less than 1%. The fixed point is
    the one of alternating full fits and updates, without 3-4 LM
    iterations per round on a fit to levels that are about to change.
    A round whitens once: the update after the step uses the robot
    cofactor of the round's start (it moves with the estimate by the
    step's share of the lever arm, a negligible change of the levels).
    """
    iters, converged, polish = 0, False, False
    for _ in range(MAX_ROUNDS):
        prob, cof = data.linearize(C, K, noise, free)
        C, K, theta, _, it, converged = model.minimize(prob, C, K, theta, max_iterations=50 if polish else 1,
                                                       tol=FIT_TOL)
        iters += it
        new, shares = model.variance_components(prob, C, K, theta, data.shape, cof, noise, estimate=estimate)
        change = max(abs(new.point_scale / noise.point_scale - 1), abs(new.robot / max(noise.robot, 1e-12) - 1),
                     0.0 if new.rotation is None else abs(new.rotation / noise.rotation - 1))
        noise = new
        if change < 0.01 and polish:
            break
        polish = change < POLISH_CHANGE
    else:
        prob, _ = data.linearize(C, K, noise, free)
        C, K, theta, _, it, converged = model.minimize(prob, C, K, theta, max_iterations=50, tol=FIT_TOL)
        iters += it
    prob, _ = data.linearize(C, K, noise, free)
    return C, K, theta, noise, prob, iters, converged


class Candidate:
    """One fitted model variant; its linearised leave-one-out point prediction error and its
    information with every camera parameter free are computed when first asked for, once."""

    def __init__(self, fit, C, K, theta, noise, prob, iterations, converged, *, fitted=True):
        self.fit, self.C, self.K, self.theta, self.noise, self.prob = fit, C, K, theta, noise, prob
        self.iterations, self.converged = iterations, converged
        self.fitted = fitted          # False: a start (closed form, initial noise levels), not yet fitted
        self._loo = None
        self._info_all = None

    @property
    def loo_errors(self):
        """Held-out errors and their predicted RMS, m (`handeye.calib.model.leave_one_out`), or None if undetermined."""
        if self._loo is None:
            cof = self.fit.cofactor(self.C, self.K)
            try:
                self._loo = model.leave_one_out(self.prob, self.C, self.K, self.theta,
                                                self.noise.point_cov(self.fit.shape, cof))
            except InsufficientDataError:
                self._loo = False     # a sample the fit cannot do without: no held-out comparison
        return self._loo or None

    @property
    def loo(self) -> float:
        """RMS linearised leave-one-out point prediction error, m (inf when undetermined)."""
        out = self.loo_errors
        return float("inf") if out is None else float(np.sqrt(np.mean(out[0] ** 2)))

    def information(self, free) -> tuple[np.ndarray, int]:
        """Information of the pose unknowns and the ``free`` camera parameters, and the number of pose unknowns.

        A sub-block of the information with all three camera parameters free
        (their Jacobian columns do not depend on which are free), computed once.
        """
        if self._info_all is None:
            prob, _ = self.fit.linearize(self.C, self.K, self.noise, (True, True, True))
            self._info_all = (model.information(prob, self.C, self.K, self.theta), prob.n_pose)
        info, n_pose = self._info_all
        idx = np.concatenate([np.arange(n_pose), n_pose + np.flatnonzero(free)])
        return info[idx][:, idx], n_pose


def better(cand: Candidate, best: Candidate) -> bool:
    """Whether ``cand`` predicts held-out points clearly better than ``best``."""
    return cand.loo < (1.0 - MIN_LOO_GAIN) * best.loo and best.loo - cand.loo > MIN_LOO_GAIN_M
