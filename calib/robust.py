"""Outlier-robust hand-eye calibration: LMedS over small subsets, chi-square inliers, final fit.

Gross outliers (a wrong depth, a detection of the wrong marker) break any
least-squares solver. `robust_solve` wraps a closed-form solver of either
setup (eye-to-hand ``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand
``X = T_flange_cam``, ``Y = T_base_marker``; paper eq. 1 ``A_i X = Y B_i``):

1. Least median of squares (Rousseeuw 1984): fit random subsets of
   ``min_samples`` samples and keep the hypothesis whose median Mahalanobis
   point residual (paper eq. 5 in the camera frame, as in `handeye.calib.model`) is
   smallest. Valid up to 50% outliers; the number of subsets is RANSAC's
   ``log(1 - CONFIDENCE) / log(1 - (1 - eps)^m)`` for a design outlier
   fraction ``eps`` (not adapted to the data: a contaminated hypothesis
   inflates the robust scale and would make any data-driven count stop early).
2. Robust scale from the median, inliers = squared Mahalanobis residual below
   the chi-square quantile `INLIER_QUANTILE` (3 dof; 6 with a rotation
   residual for pose data) times that scale.
3. Final fit on the inliers, re-classify, repeat until the inlier set is stable.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
from scipy.stats import chi2

from handeye.calib import model
from handeye.calib.errors import CalibrationError, InsufficientDataError
from handeye.calib.problem import CalibrationProblem
from handeye.calib.result import CalibrationResult, RobustDetails

#: Chi-square quantile below which a sample counts as an inlier.
INLIER_QUANTILE = 0.999
#: Probability that at least one subset is outlier-free when the search stops.
CONFIDENCE = 0.999


def _squared_distances(result: CalibrationResult, A, B, W_t, setup: str) -> np.ndarray:
    """Squared Mahalanobis residual per sample (N,) of a hypothesis and its degrees of freedom.

    Translation: whitened camera-frame point residual (3 dof). Pose data whose
    hypothesis knows the marker rotation add the rotation residual normalised
    by a robust (median) estimate of its own scale (3 more dof).
    """
    C, K, M = model.split(result.X, result.Y, A, setup)
    p = B if B.ndim == 2 else B[:, :3, 3]
    r = model.point_residuals(C, K[:3, 3], M, p)[0]
    d2 = np.sum(np.einsum("nij,nj->ni", W_t, r) ** 2, axis=1)
    if B.ndim == 3 and result.marker_rotation_known:
        e2 = np.sum(model.rotation_residuals(C, K, M, B[:, :3, :3])[0] ** 2, axis=1)
        e2_scale = max(np.median(e2) / chi2.ppf(0.5, 3), 1e-18)
        return d2 + e2 / e2_scale, 6
    return d2, 3


def _trials_needed(inlier_fraction: float, m: int, confidence: float) -> float:
    good = inlier_fraction**m
    if good >= 1.0:
        return 1.0
    return np.log(1.0 - confidence) / np.log(1.0 - good)


def robust_solve(
    solve_fn: Callable[[CalibrationProblem], CalibrationResult],
    problem: CalibrationProblem,
    *,
    rng: np.random.Generator,
    min_samples: int | None = None,
    max_outlier_fraction: float = 0.4,
    max_trials: int = 1000,
    max_refits: int = 5,
) -> CalibrationResult:
    """Calibrate with a closed-form solver despite up to 50% gross outliers.

    Parameters
    ----------
    solve_fn : callable ``(CalibrationProblem) -> CalibrationResult``
        A closed-form method, e.g. ``lambda sub: closed_form("YKronT'", sub)``,
        applied to subsets of ``problem``. It may raise a
        `handeye.calib.errors.CalibrationError` on a degenerate subset (the subset is
        skipped).
    problem : CalibrationProblem
        The samples. Without a point covariance the depth model of
        `handeye.calib.noise` gives its shape; the scale is always estimated robustly
        (and never below a given covariance).
    rng : numpy.random.Generator
        Draws the subsets; required so runs are reproducible.
    min_samples : int, optional
        Subset size; default 6 for points (YKronT' has 15 linear unknowns,
        5 samples determine them, one more steadies them) and 4 for poses.
    max_outlier_fraction : float
        Design outlier fraction in [0, 0.5): sets the number of subsets so
        that one is outlier-free with probability `CONFIDENCE` (0.4 and 6
        samples: 147 subsets).
    max_trials : int
        Upper bound on subsets tried.
    max_refits : int
        Upper bound on final fit / re-classification rounds.

    Returns
    -------
    CalibrationResult
        ``solve_fn``'s fit on the inliers, with ``method`` suffixed ``"+LMedS"``,
        ``inliers`` (bool (N,)) so that ``result.rejected`` lists the outliers,
        ``n_samples = N``, and ``robust`` (`handeye.calib.result.RobustDetails`).
        ``residuals`` and ``cov`` are those of the inlier fit.

    Raises
    ------
    InsufficientDataError
        Fewer than ``min_samples + 1`` samples, or no subset could be solved.
    CalibrationError
        A bad ``rng`` or ``max_outlier_fraction``.
    """
    A, B, setup = problem.A, problem.B, problem.setup
    if not isinstance(rng, np.random.Generator):
        raise CalibrationError("rng must be a numpy.random.Generator")
    n = len(A)
    m = min_samples if min_samples is not None else default_subset(points=B.ndim == 2)
    if n < m + 1:
        raise InsufficientDataError(f"robust estimation needs at least {m + 1} samples, got {n}")
    W_t, given = model.point_weights(B, problem.point_cov)

    if not 0.0 <= max_outlier_fraction < 0.5:
        raise CalibrationError(f"max_outlier_fraction must be in [0, 0.5), got {max_outlier_fraction}")
    needed = int(np.ceil(_trials_needed(1.0 - max_outlier_fraction, m, CONFIDENCE)))
    best, best_med, best_dof, trials = _least_median(solve_fn, problem, W_t, m, min(needed, max_trials), rng)
    scale = _scale(best_med, best_dof, n, m, given)
    threshold = chi2.ppf(INLIER_QUANTILE, best_dof) * scale
    d2, _ = _squared_distances(best, A, B, W_t, setup)
    result, used, scale, threshold = _refit(solve_fn, problem, W_t, given, d2 <= threshold, m, max_refits)
    return dataclasses.replace(
        result,
        method=f"{result.method}+LMedS",
        n_samples=n,
        inliers=used,
        robust=RobustDetails(trials=trials, subset=m, scale=scale, threshold=float(threshold)),
    )


def _least_median(solve_fn, problem: CalibrationProblem, W_t, m: int, trials_max: int, rng):
    """The LMedS search: the hypothesis of random ``m``-subsets with the smallest median squared Mahalanobis
    residual, that median, its degrees of freedom and the number of subsets tried."""
    best, best_med, best_dof, trials = None, np.inf, 3, 0
    while trials < trials_max:
        trials += 1
        idx = rng.choice(problem.n, size=m, replace=False)
        try:
            hyp = solve_fn(problem.subset(idx))
            d2, dof = _squared_distances(hyp, problem.A, problem.B, W_t, problem.setup)
        except CalibrationError:
            continue
        med = float(np.median(d2))
        if med < best_med:
            best, best_med, best_dof = hyp, med, dof
    if best is None:
        raise InsufficientDataError(f"no subset of {m} samples could be solved in {trials} trials")
    return best, best_med, best_dof, trials


def _refit(solve_fn, problem: CalibrationProblem, W_t, given: bool, inliers, m: int, max_refits: int):
    """Fit the inliers, re-classify every sample at that fit, until the inlier set is stable: the last fit,
    its inliers, the robust scale and the threshold."""
    for _ in range(max_refits):
        if inliers.sum() < m:
            raise InsufficientDataError(f"only {int(inliers.sum())} inliers left, need {m}")
        used = inliers
        result = solve_fn(problem.subset(used))
        d2, dof = _squared_distances(result, problem.A, problem.B, W_t, problem.setup)
        # Inliers of a full fit give an unbiased scale: their mean d2 is dof * scale.
        scale = max(float(np.mean(d2[inliers])) / dof, 1.0) if given else float(np.mean(d2[inliers])) / dof
        threshold = chi2.ppf(INLIER_QUANTILE, dof) * scale
        inliers = d2 <= threshold
        if np.array_equal(inliers, used):
            break
    return result, used, scale, threshold


def default_subset(*, points: bool) -> int:
    """Default LMedS subset size: 6 for points (YKronT': 15 linear unknowns, 5 samples
    determine them, one more steadies them), 4 for poses (3 determine every pose method
    but XKronT, whose caller passes its own minimum of 5)."""
    return 6 if points else 4


def _scale(median_d2: float, dof: int, n: int, m: int, given: bool) -> float:
    """Robust variance factor from the median squared residual (Rousseeuw & Leroy 1987, finite-sample factor)."""
    s = median_d2 / chi2.ppf(0.5, dof) * (1.0 + 5.0 / (n - m)) ** 2
    return max(s, 1.0) if given else s
