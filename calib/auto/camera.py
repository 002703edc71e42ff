"""``auto``'s camera correction: which of the depth scale, depth offset and focal scale the data determine and
use (`handeye.calib.model.CAMERA_PARAMS`), chosen by the information matrix and the held-out point error.
"""

from __future__ import annotations

import numpy as np

from handeye.calib import model
from handeye.calib.auto.fit import Candidate, MIN_LOO_GAIN, better, fit_components
from handeye.calib.errors import InsufficientDataError

#: Allowed values of ``camera_correction``.
CAMERA_CORRECTIONS = ("auto", "none", "depth", "depth+focal")


#: A camera parameter counts as determined by the motions if its 1-sigma (information
#: matrix, with the parameters chosen before it) is below this: five times the
#: systematic error a structured-light camera has before an infield correction
#: (2% scale, 10 mm offset, 2% focal), i.e. the data could not tell its value from zero.
IDENTIFIABLE_SIGMA = {"depth_scale": 0.1, "depth_offset": 0.05, "focal_scale": 0.1}


#: Below this 1-sigma a camera parameter is estimated without further test (the data pin it
#: down to half the typical error); between this and `IDENTIFIABLE_SIGMA` only if it lowers
#: the held-out point error.
#: Only the depth errors, the most common ones (1-2% and millimetres for structured light
#: and stereo), which also shift predictions most when extrapolating in depth.
WELL_DETERMINED_SIGMA = {"depth_scale": 0.01, "depth_offset": 0.01, "focal_scale": 0.0}


#: Fewest samples before camera parameters are considered: below it the held-out test that
#: admits them is too noisy (with 8 samples it admits metre-scale nonsense).
MIN_SAMPLES_CAMERA = 12


#: A camera parameter estimated beyond this is taken as the model absorbing something else
#: (a bad sample, robot error) and is not used: 5% scale, 30 mm offset, 5% focal.
PLAUSIBLE = {"depth_scale": 0.05, "depth_offset": 0.03, "focal_scale": 0.05}


#: What to move to determine each camera parameter.
_MOTION_HINT = {
    "depth_scale": "translate the marker over a larger range, especially towards and away from the camera",
    "depth_offset": "vary the marker's distance from the camera more",
    "focal_scale": "move the marker across the whole image, out to its edges",
}


def free_for(mode: str) -> tuple[bool, bool, bool]:
    return {"none": (False, False, False), "depth": (True, True, False)}.get(mode, (True, True, True))


def identifiability(info: np.ndarray, free, n_pose: int) -> dict[str, float]:
    """1-sigma of each free camera parameter from the information matrix (inf if singular)."""
    names = [n for n, f in zip(model.CAMERA_PARAMS, free) if f]
    try:
        cov = np.linalg.inv(info)
        sig = np.sqrt(np.clip(np.diag(cov)[n_pose:], 0.0, None))
        if not np.all(np.isfinite(sig)):
            raise np.linalg.LinAlgError
    except np.linalg.LinAlgError:
        sig = np.full(len(names), np.inf)
    ev = np.linalg.eigvalsh(info)
    if ev[0] <= model.MIN_INFORMATION_RATIO * ev[-1]:
        sig = np.full(len(names), np.inf)
    return dict(zip(names, sig.tolist()))


def select_camera(best: Candidate, wanted, *, defer: bool):
    """Camera parameters, forward selection in the order of how common the error is.

    Depth scale, depth offset, focal: one joins if the motions determine it
    well (1-sigma from the information matrix below `WELL_DETERMINED_SIGMA`),
    or determine it at all (below `IDENTIFIABLE_SIGMA`) and it lowers the
    held-out prediction error of the points. With ``defer``, well-determined
    parameters are fitted together, in one run of variance components and fit
    when a comparison needs it or at the end, instead of one run each (the
    same fixed point, at a fraction of the cost);
    their 1-sigma where they are found decides (``best``, or an unfitted start
    for points: the thresholds are an order of magnitude apart, either is close).

    Returns ``(best, free, data_sigma, notes)``, or None when a parameter taken
    that way came out implausible (`PLAUSIBLE`): the caller then selects again
    from a fitted start without ``defer``, one parameter at a time, each fitted.
    """
    fit, free = best.fit, np.zeros(3, dtype=bool)
    fitted = best.fitted            # best is fitted with the parameters `free`
    data_sigma: dict[str, float] = {}
    notes: list[str] = []
    for k, name in enumerate(model.CAMERA_PARAMS):
        if not wanted[k]:
            continue
        trial = free.copy()
        trial[k] = True
        sigmas = _sigmas(best, trial)
        if sigmas[name] <= IDENTIFIABLE_SIGMA[name] and sigmas[name] > WELL_DETERMINED_SIGMA[name] and not fitted:
            # A held-out comparison needs a fitted model to compare with: fit what was taken so far, probe again.
            best, fitted = _fitted(best, free), True
            if best is None:
                return None
            sigmas = _sigmas(best, trial)
        data_sigma[name] = sigmas[name]
        if sigmas[name] > IDENTIFIABLE_SIGMA[name]:
            notes.append(f"{name} is not determined by these motions (1-sigma {_fmt(name, sigmas[name])}); "
                         f"kept at nominal: {_MOTION_HINT[name]}")
            continue
        if defer and sigmas[name] <= WELL_DETERMINED_SIGMA[name]:
            free, fitted = trial, False     # fitted with the others taken this way, when needed
            continue
        if sigmas[name] > WELL_DETERMINED_SIGMA[name] and not step_helps(best, trial):
            notes.append(_not_helpful(name, sigmas[name]))
            continue
        cand = Candidate(fit, *fit_components(fit, best.C, best.K, best.theta, best.noise, tuple(trial)))
        wild = [n for i, n in enumerate(model.CAMERA_PARAMS) if trial[i] and abs(cand.theta[i]) > PLAUSIBLE[n]]
        if wild:
            notes.append(f"{name} not estimated: with it, {', '.join(wild)} came out implausibly large "
                         "(the model would absorb another error)")
            continue
        if sigmas[name] <= WELL_DETERMINED_SIGMA[name] or better(cand, best):
            cand.iterations += best.iterations
            best, free = cand, trial
        else:
            notes.append(_not_helpful(name, sigmas[name]))
    if not fitted:
        best = _fitted(best, free)
        if best is None:
            return None
    return best, free, data_sigma, notes


def _sigmas(best: Candidate, trial) -> dict[str, float]:
    """`identifiability` of the camera parameters ``trial`` at ``best``."""
    info, n_pose = best.information(trial)
    return identifiability(info, trial, n_pose)


def _not_helpful(name: str, sigma: float) -> str:
    return (f"{name} not estimated: these motions determine it to {_fmt(name, sigma)} (1-sigma) and it did not "
            f"improve held-out predictions; to pin it down, {_MOTION_HINT[name]}")


def step_helps(best: Candidate, trial, fit: model.WeightedData | None = None) -> bool:
    """Whether freeing the camera parameters ``trial`` (or the measurement set of ``fit``) is worth a refit.

    The Gauss-Newton step from ``best`` with ``trial`` free, at ``best``'s
    noise levels (`handeye.calib.model.leave_one_out_after_step`): if that does not
    lower the held-out point error by half of `MIN_LOO_GAIN`, the refit would
    not lower it by `MIN_LOO_GAIN` either. (The refit differs from the step
    by its own noise levels and the model's curvature only; over 162 such
    comparisons on the realistic profile, N = 30, the two held-out errors
    agreed within 0.13% of the reference for camera parameters and 1.2% for
    the measurement set.) Otherwise the refit decides, as before. A step to an implausible value also goes to the refit, which
    reports it. Saves one fit with its variance components per parameter
    that does not help (the focal scale, usually), and the fit without
    marker orientations when they are good.
    """
    fit = best.fit if fit is None else fit
    prob, _ = fit.linearize(best.C, best.K, best.noise, tuple(bool(f) for f in trial))
    try:
        errors, _, delta = model.leave_one_out_after_step(prob, best.C, best.K, best.theta,
                                                          best.noise.point_cov(fit.shape, fit.cofactor(best.C, best.K)))
    except InsufficientDataError:
        return True
    theta = np.array(best.theta, dtype=float)
    theta[np.asarray(trial, dtype=bool)] += delta[prob.n_pose:]
    if any(abs(theta[i]) > PLAUSIBLE[n] for i, n in enumerate(model.CAMERA_PARAMS)):
        return True
    return float(np.sqrt(np.mean(errors**2))) < (1.0 - 0.5 * MIN_LOO_GAIN) * best.loo


def _fitted(start: Candidate, free) -> Candidate | None:
    """``start`` fitted with the camera parameters ``free``; None if one of them comes out implausible."""
    fit = start.fit
    cand = Candidate(fit, *fit_components(fit, start.C, start.K, start.theta, start.noise, tuple(bool(f) for f in free)))
    cand.iterations += start.iterations
    if any(free[i] and abs(cand.theta[i]) > PLAUSIBLE[n] for i, n in enumerate(model.CAMERA_PARAMS)):
        return None
    return cand


def _fmt(name: str, sigma: float) -> str:
    if not np.isfinite(sigma):
        return "unbounded"
    return f"{sigma * 1e3:.1f} mm" if name == "depth_offset" else f"{sigma * 100:.2f}%"
