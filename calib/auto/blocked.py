"""``auto``'s check of its model choice on blocked folds: contiguous stretches of the recording held out in turn,
a stand-in for another session.
"""

from __future__ import annotations

import numpy as np

from handeye.calib import model
from handeye.calib import transforms as tf
from handeye.calib.auto.fit import FIT_TOL, Candidate, fit_components
from handeye.calib.diagnostics import initial_noise
from handeye.calib.errors import CalibrationError
from handeye.calib.problem import CalibrationProblem
from handeye.calib.result import BlockedCandidate, BlockedFolds, CalibrationResult

#: Contiguous blocks of the recording `blocked_choice` holds out in turn (3 below 30 samples).
BLOCKED_FOLDS = 5


#: Fewest samples for the blocked-fold check of the chosen model: 5 stretches of 20. Shorter stretches judge
#: a model by a handful of points, a noisier test than the information-based choice it would overrule (on the
#: realistic profile at N = 30, checking with 6-sample stretches dropped a real 1.5 % depth scale in 13 % of the
#: cells and raised the workspace error from 1.24 to 1.40 times the bias-free cell's).
MIN_SAMPLES_BLOCKED = 100


#: A simpler model replaces the leave-one-out choice if it predicts the held-out blocks within this share of it.
BLOCKED_GAIN = 0.0


#: Gauss-Newton iterations of a blocked-fold refit from the whole recording's estimate (it moves little).
BLOCKED_ITERATIONS = 5


#: The closed-form start replaces the maximum-likelihood fit only if it predicts the held-out blocks this much
#: better: it is not a simpler model of the same kind but an estimate that ignores the noise model, and at a
#: smaller margin (0) it won on the stretches of one ETH half while predicting the other half 1.8 % worse.
START_GAIN = 0.05


#: Blocked-fold errors beyond this many times the leave-one-out error: the rest of the recording does not
#: determine the model without the block (too few or too similar samples); the check is skipped.
BLOCKED_SANE = 5.0


def blocked_folds(n: int) -> list[np.ndarray]:
    """Contiguous stretches of the recording (`BLOCKED_FOLDS` of them, 3 below 30 samples): each held out in
    turn, a stand-in for another session (random folds share each stretch's conditions with the training set)."""
    return [b for b in np.array_split(np.arange(n), 3 if n < 30 else BLOCKED_FOLDS) if len(b)]


def _blocked_error(cand: Candidate, free, problem: CalibrationProblem, shape, folds) -> float:
    """RMS (m) of the marker points of each block of ``folds`` predicted by the candidate's model refitted
    without them (its noise levels kept; a Gauss-Newton fit from the candidate's estimate)."""
    A, B, setup, p = problem.A, problem.B, problem.setup, problem.points
    misses = []
    for test in folds:
        train = np.setdiff1d(np.arange(len(A)), test)
        fit = model.WeightedData(A[train], B[train], setup, shape[train], cand.fit.use_rotation, prior=cand.fit.prior)
        prob, _ = fit.linearize(cand.C, cand.K, cand.noise, tuple(bool(f) for f in free))
        try:
            C, K, theta, *_ = model.minimize(prob, cand.C, cand.K, cand.theta, max_iterations=BLOCKED_ITERATIONS,
                                              tol=FIT_TOL)
        except CalibrationError:
            return float("inf")
        M = model.split(np.eye(4), np.eye(4), A[test], setup)[2]
        misses.append(p[test] - model.predict_points(C, K[:3, 3], M, theta))
    return float(np.sqrt(np.mean(np.sum(np.concatenate(misses) ** 2, axis=1))))


def _closed_form_blocked_error(solve_start, problem: CalibrationProblem, folds) -> float:
    """`_blocked_error` of the start, ``solve_start(problem)`` solved again without each block; inf where it fails."""
    misses = []
    for test in folds:
        try:
            res = solve_start(problem.subset(np.setdiff1d(np.arange(problem.n), test)))
        except CalibrationError:
            return float("inf")
        C, K, M = model.split(res.X, res.Y, problem.A[test], problem.setup)
        misses.append(problem.points[test] - model.predict_points(C, K[:3, 3], M))
    return float(np.sqrt(np.mean(np.sum(np.concatenate(misses) ** 2, axis=1))))


def _scored(best: Candidate, free, problem: CalibrationProblem, shape, W_shape, folds) -> list:
    """``(candidate, its free camera parameters, blocked-fold error)`` of each model `blocked_choice` weighs,
    the plainest first: with and without the orientations (pose data), each without and with the camera
    correction ``free``; the chosen ``best`` among them."""
    A, B, setup, has_rotation = problem.A, problem.B, problem.setup, problem.has_poses
    none = np.zeros(3, dtype=bool)
    fits = {best.fit.use_rotation: best.fit}
    if has_rotation and not best.fit.use_rotation:
        fits[True] = model.WeightedData(A, B, setup, shape, True, shape_whitener=W_shape, prior=best.fit.prior)
    elif has_rotation:
        fits[False] = model.WeightedData(A, B, setup, shape, False, shape_whitener=W_shape, prior=best.fit.prior)
    # (complexity, rotation, free): the plainest first; a dropped measurement set counts half a parameter.
    grid = sorted({(int(f.any()) * int(free.sum()) + (0.5 if not rot and has_rotation else 0.0), rot, f.any())
                   for rot in fits for f in ([none, free] if free.any() else [none])})
    scored = []
    for _, rot, corr in grid:
        if rot == best.fit.use_rotation and corr == bool(free.any()):
            cand = best
        else:
            fit = fits[rot]
            K = best.K
            if rot and not best.fit.use_rotation:
                K = tf.make_transform(model.marker_rotation(best.C, fit.M, B[:, :3, :3]), best.K[:3, 3])
            noise = initial_noise(model.point_d2(best.C, best.K, fit.M, problem.points, fit.shape_whitener),
                                  best.C, K, fit.M, B[:, :3, :3] if rot else None)
            cand = Candidate(fit, *fit_components(fit, best.C, K, best.theta if corr else np.zeros(3), noise,
                                                  tuple(bool(v) for v in (free if corr else none))))
        scored.append((cand, free if corr else none, _blocked_error(cand, free if corr else none, problem, shape,
                                                                    folds)))
    return scored


def blocked_choice(best: Candidate, free, problem: CalibrationProblem, shape, W_shape, start: CalibrationResult,
                   solve_start):
    """The model choices made by leave-one-out, checked against blocked folds: a simpler model that predicts
    contiguous held-out stretches of the recording at least as well replaces them.

    The leave-one-out choices of `handeye.calib.auto.camera.select_camera` and of the
    measurement set judge a model on samples like its own; a camera
    correction or a dropped measurement set that only fits one stretch of the
    recording better does not carry to the next session. The candidates
    (`_scored`) are refitted without each stretch (`blocked_folds`) and
    predict its points. The simplest (every measurement, no correction, then
    fewer changes) whose error is within `BLOCKED_GAIN` of the chosen model's
    replaces it: when the evidence for the extra model is weak, the simpler
    one is reported; a more complex one than the chosen is never taken.
    Last, the closed-form start, solved again without each stretch: if it
    predicts them better by `START_GAIN`, it is reported (its covariance that
    of the plain model at its estimate), so that ``auto`` does not carry
    worse to another session than where it started (``solve_start(problem)``
    solves it again: the closed form, or `handeye.calib.auto.determined.held_start`).

    Returns ``(best, free, note or None, BlockedFolds)``.
    """
    folds = blocked_folds(problem.n)
    free = np.asarray(free, dtype=bool)
    scored = _scored(best, free, problem, shape, W_shape, folds)
    candidates = [BlockedCandidate(heldout_m=float(e), orientations=bool(c.fit.use_rotation),
                                   camera_correction=tuple(n for n, f in zip(model.CAMERA_PARAMS, cf) if f))
                  for c, cf, e in scored]
    if not all(np.isfinite(e) and e <= BLOCKED_SANE * best.loo for _, _, e in scored):
        # The stretches left out take what determines the model with them (a refit runs away): no evidence.
        return best, free, None, BlockedFolds(len(folds), "leave-one-out (blocked folds undetermined)",
                                              tuple(candidates))
    e_best = next(e for c, _, e in scored if c is best)
    # The simplest model that predicts the held-out stretches at least as well as the leave-one-out choice.
    simpler = [item for item in scored[:next(i for i, (c, _, _) in enumerate(scored) if c is best)]
               if item[2] <= (1.0 + BLOCKED_GAIN) * e_best]
    chosen = simpler[0] if simpler else next(item for item in scored if item[0] is best)
    # The closed-form start, plainer still: reported when the fits do not predict the stretches better.
    name = start.method.split("+")[0]
    e_start = _closed_form_blocked_error(solve_start, problem, folds)
    candidates.insert(0, BlockedCandidate(heldout_m=e_start, closed_form=name))
    if e_start < (1.0 - START_GAIN) * chosen[2]:
        cand, note = _closed_form_choice(scored[0][0], best, problem, start, name, chosen[2], e_start)
        return cand, np.zeros(3, dtype=bool), note, BlockedFolds(len(folds), "blocked folds: closed form",
                                                                 tuple(candidates), e_start)
    if chosen[0] is best:
        return best, free, None, BlockedFolds(len(folds), "leave-one-out", tuple(candidates), e_best)
    cand, cfree, err = chosen
    cand.iterations += best.iterations
    dropped = []
    if free.any() and not cfree.any():
        dropped.append(f"the camera correction ({', '.join(n for n, f in zip(model.CAMERA_PARAMS, free) if f)})")
    if cand.fit.use_rotation != best.fit.use_rotation:
        dropped.append("the marker orientations " + ("back in" if cand.fit.use_rotation else "left out"))
    return cand, cfree, (
        f"{' and '.join(dropped)}: contiguous stretches of the recording held out in turn are predicted "
        f"{err * 1e3:.2f} mm this way, {e_best * 1e3:.2f} mm as chosen by leave-one-out; the plainer model "
        "carries to another session"), BlockedFolds(len(folds), "blocked folds", tuple(candidates), err)


def _closed_form_choice(plain: Candidate, best: Candidate, problem: CalibrationProblem, start: CalibrationResult,
                        name: str, e_chosen: float, e_start: float) -> tuple[Candidate, str]:
    """The closed-form start as the reported candidate (the plain model at its estimate), and the note."""
    C, K, _ = model.split(start.X, start.Y, problem.A, problem.setup)
    if plain.fit.use_rotation and not start.marker_rotation_known:
        K = tf.make_transform(model.marker_rotation(C, plain.fit.M, problem.marker_rotations), K[:3, 3])
    # The noise levels at the start's own residuals (one update, the estimate held), so that its covariance and
    # self-check judge the start and not the fit it replaces.
    prob, cof = plain.fit.linearize(C, K, plain.noise, (False, False, False))
    noise, _ = model.variance_components(prob, C, K, np.zeros(3), plain.fit.shape, cof, plain.noise)
    prob, _ = plain.fit.linearize(C, K, noise, (False, False, False))
    cand = Candidate(plain.fit, C, K, np.zeros(3), noise, prob, best.iterations, True)
    return cand, (
        f"the closed form {name} is reported: the maximum-likelihood fits predicted contiguous stretches of the "
        f"recording held out in turn no better ({e_chosen * 1e3:.2f} mm, {e_start * 1e3:.2f} mm by {name}); "
        "its covariance is that of the plain model at its estimate, with the noise levels of its own residuals")
