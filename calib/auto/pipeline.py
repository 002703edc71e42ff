"""``solve_auto``: the stages of ``solve("auto")`` (the package docstring describes them)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from handeye.calib import model
from handeye.calib import transforms as tf
from handeye.calib.auto.blocked import MIN_SAMPLES_BLOCKED, blocked_choice
from handeye.calib.auto.camera import CAMERA_CORRECTIONS, MIN_SAMPLES_CAMERA, free_for, select_camera, step_helps
from handeye.calib.auto.consider import camera_consider, shared_robot_consider
from handeye.calib.auto.determined import MotionPrior, determined_note, held_start, motion_prior
from handeye.calib.auto.fit import Candidate, better, fit_components
from handeye.calib.diagnostics import consistency, initial_noise
from handeye.calib.errors import CalibrationError
from handeye.calib.methods import closed_form
from handeye.calib.problem import CalibrationProblem
from handeye.calib.result import AutoDetails, CalibrationResult, CameraParameter, Residuals
from handeye.calib.robust import robust_solve
from handeye.calib.symmetry import resolve_flips

#: Quantiles of chi-square with 3 dof of the outlier test (`_needs_robust`), computed once.
_CHI2_3_MEDIAN = float(chi2.ppf(0.5, 3))
_CHI2_3_OUTLIER = float(chi2.ppf(0.9999, 3))


@dataclass
class _Start:
    """Stage 1's output: the closed-form start (robust when needed), the inlier samples and what stage 2 reuses."""

    result: CalibrationResult
    tried: list
    inliers: np.ndarray
    shape: np.ndarray          # the camera's point covariance shape, all samples
    W_shape: np.ndarray        # its whitener
    d2: np.ndarray | None      # the start's whitened squared point residuals (None after the outlier search)


def solve_auto(problem: CalibrationProblem, *, camera_correction: str = "auto",
               rng: np.random.Generator | None = None) -> CalibrationResult:
    """Calibrate with every measurement and the extended model (`handeye.calib.auto`).

    Parameters
    ----------
    problem : CalibrationProblem
        The samples (marker points, or poses whose orientations are then used
        too). Eye-to-hand ``X = T_flange_marker``, ``Y = T_base_cam``;
        eye-in-hand ``X = T_flange_cam``, ``Y = T_base_marker``. Its point
        covariance gives the shape of the point noise (its scale is
        estimated). Its ``robot_shared_error`` (N, 6, P), the robot's error
        that all samples share (sample ``i``'s true flange pose is
        ``A_i Exp(F_i z)``, ``z ~ N(0, I_P)`` the same for every sample), joins
        the covariance as a "consider" term (`shared_robot_consider`); the
        white robot error stays a variance component.
    camera_correction : {"auto", "none", "depth", "depth+focal"}
        Which camera parameters to estimate: "depth" = depth scale and
        offset, "depth+focal" adds the focal scale, "auto" = all three that
        the motions determine.
    rng : numpy.random.Generator, optional
        For the LMedS subsets; ``default_rng(0)`` if not given.

    Returns
    -------
    CalibrationResult
        ``method`` ``"auto"``; ``cov`` the camera block of the inverse
        information of the extended model (nuisances marginalised), plus the
        "consider" covariance of camera parameters left at nominal
        (`CONSIDER_SIGMA`, unless ``camera_correction="none"``) and of the
        robot's shared error; ``cov_kind`` "fisher-extended"; ``self_check``;
        ``auto`` (`handeye.calib.result.AutoDetails`); ``undetermined``: what the
        motions leave open (`handeye.calib.auto.determined`; ``cov`` is then the one
        given the value held), empty when they determine everything or the
        problem's ``marker_offset`` completes it.
    """
    if camera_correction not in CAMERA_CORRECTIONS:
        raise CalibrationError(f"camera_correction must be one of {', '.join(CAMERA_CORRECTIONS)}, got {camera_correction!r}")
    notes: list[str] = []
    problem, flips = _resolve_flips(problem, notes)
    motion = motion_prior(problem)
    if motion.note:
        notes.append(motion.note)
    start = _robust_start(problem, rng, notes, motion)
    inlying = problem.subset(start.inliers)
    best = _choose_measurements(inlying, start, notes, motion.prior)
    best, free, data_sigma = _choose_camera(best, camera_correction, inlying.n, notes)
    blocked = None
    if inlying.n >= MIN_SAMPLES_BLOCKED:
        best, free, note, blocked = blocked_choice(best, free, inlying, start.shape[start.inliers],
                                                   start.W_shape[start.inliers], start.result,
                                                   _start_solver(start.result.method, motion))
        if note:
            notes.append(note)
    return _result(problem, start, best, free, data_sigma, camera_correction, blocked, flips, notes, motion)


def _start_solver(name: str, motion: MotionPrior):
    """``solver(problem) -> CalibrationResult`` of the start ``name``: a closed form, or `held_start` when the
    motions leave part of the translations open."""
    if motion.leaves_open:
        return lambda sub: held_start(sub, motion)
    return lambda sub: closed_form(name.split("+")[0], sub)


def _resolve_flips(problem: CalibrationProblem, notes: list) -> tuple[CalibrationProblem, dict | None]:
    """Pose data: marker poses flipped by a symmetry of the target turned back (`handeye.calib.symmetry`)."""
    if not problem.has_poses:
        return problem, None
    B, flips = resolve_flips(problem.A, problem.B, setup=problem.setup)
    if flips is not None and flips["n_flipped"]:
        notes.append(f"{flips['n_flipped']} marker poses were flipped by {flips['angle_deg']:.0f} deg "
                     "(symmetric target) and were turned back")
    return problem.with_measurements(B), flips


def _closed_form_start(problem: CalibrationProblem, motion: MotionPrior):
    """Closed-form candidates and the one with the smallest median point residual; `held_start` alone when the
    motions leave part of the translations open (every closed form of the paper needs them determined)."""
    if motion.leaves_open:
        res = held_start(problem, motion)
        return res, [(res.method, float(np.median(res.residuals.translation)))]
    names = ["YKronT'"] + (["YQuatT'", "YKronRT"] if problem.has_poses else [])
    best, best_med, tried, refused = None, np.inf, [], []
    for name in names:
        try:
            res = closed_form(name, problem)
        except CalibrationError as e:
            refused.append(e)
            continue
        med = float(np.median(res.residuals.translation))
        tried.append((name, med))
        if med < best_med:
            best, best_med = res, med
    if best is None:
        # The first candidate's reason (the paper's YKronT'): what the samples lack, and what would fix it.
        raise type(refused[0])(f"no closed-form start could be computed for these samples: {refused[0]}")
    return best, tried


def _needs_robust(d2) -> bool:
    """Whether the start's whitened squared point residuals ``d2`` show outliers at a robust (median) scale."""
    scale = np.median(d2) / _CHI2_3_MEDIAN
    return bool(np.any(d2 > _CHI2_3_OUTLIER * scale * 4.0))


def _robust_start(problem: CalibrationProblem, rng, notes: list, motion: MotionPrior) -> _Start:
    """Stages 1 and 2: the best closed form and, if its residuals show outliers, the LMedS search around it."""
    A, setup, n = problem.A, problem.setup, problem.n
    shape, _ = model.point_shape(problem.B, problem.point_cov)
    start, tried = _closed_form_start(problem, motion)
    inliers = np.ones(n, dtype=bool)
    W_shape = model.whitener(shape)
    d2 = model.point_d2(*model.split(start.X, start.Y, A, setup), problem.points, W_shape)
    if n >= 8 and _needs_robust(d2):
        try:
            # YKronT' needs 5 samples (6 steady it); the pose-based starts 3 (4).
            hyp = robust_solve(_start_solver(start.method, motion), problem,
                               rng=rng if rng is not None else np.random.default_rng(0),
                               min_samples=4 if start.marker_rotation_known else 6)
        except CalibrationError as e:
            notes.append(f"outlier search failed ({e}); all samples used")
        else:
            inliers = hyp.inliers
            start, d2 = hyp, None
    return _Start(start, tried, inliers, shape, W_shape, d2)


def _choose_measurements(problem: CalibrationProblem, start: _Start, notes: list, prior) -> Candidate:
    """Stage 3a: marker orientations are used unless they make held-out points worse (pose data); every fit
    with the translation prior ``prior`` (`handeye.calib.auto.determined`, None without one)."""
    A, B, setup = problem.A, problem.B, problem.setup
    C0, K0, _ = model.split(start.result.X, start.result.Y, A, setup)
    theta = np.zeros(3)
    d2 = start.d2
    best = None
    for rot in ([True, False] if problem.has_poses else [False]):
        fit = model.WeightedData(A, B, setup, start.shape[start.inliers], rot,
                                 shape_whitener=start.W_shape[start.inliers], prior=prior)
        K = K0
        if rot and not start.result.marker_rotation_known:
            K = tf.make_transform(model.marker_rotation(C0, fit.M, B[:, :3, :3]), K0[:3, 3])
        if d2 is None:
            d2 = model.point_d2(C0, K0, fit.M, problem.points, fit.shape_whitener)
        noise = initial_noise(d2, C0, K, fit.M, B[:, :3, :3] if rot else None)
        if not problem.has_poses:
            # Points only: nothing to compare before the camera parameters, which start from here (`select_camera`).
            return Candidate(fit, C0, K, theta, noise, fit.linearize(C0, K, noise, (False, False, False))[0], 0, False,
                             fitted=False)
        if best is not None and not step_helps(best, (False, False, False), fit):
            continue      # without orientations not even a step predicts held-out points better
        cand = Candidate(fit, *fit_components(fit, C0, K, theta, noise, (False, False, False)))
        if best is None or better(cand, best):
            if best is not None:
                notes.append(f"marker orientations left out: held-out points {best.loo * 1e3:.2f} mm with them, "
                             f"{cand.loo * 1e3:.2f} mm without (systematic orientation error, e.g. intrinsics)")
            best = cand
    return best


def _choose_camera(best: Candidate, camera_correction: str, n: int, notes: list):
    """Stage 3b-4: the camera parameters to estimate (`select_camera`); returns ``(best, free, data_sigma)``."""
    wanted = free_for(camera_correction)
    if any(wanted) and n < MIN_SAMPLES_CAMERA:
        notes.append(f"camera correction not attempted: {n} samples, it needs {MIN_SAMPLES_CAMERA}")
        wanted = (False, False, False)
    selected = select_camera(best, wanted, defer=True)
    if selected is None:
        # A parameter taken without a fit of its own came out implausible: choose one at a time, each fitted.
        if not best.fitted:
            best = Candidate(best.fit, *fit_components(best.fit, best.C, best.K, best.theta, best.noise,
                                                       (False, False, False)))
        selected = select_camera(best, wanted, defer=False)
    best, free, data_sigma, camera_notes = selected
    notes.extend(camera_notes)
    return best, free, data_sigma


def _covariance(best: Candidate, free, data_sigma, camera_correction: str, shared_factor):
    """Camera covariance (6, 6) with its consider terms, the camera parameters' 1-sigma (3,), the shared
    robot error's share of the camera translation's 1-sigma (m, None without one) and the marker-side
    translation's covariance (3, 3; with the camera parameters' consider term)."""
    info_mat, _ = best.information(free)
    full_cov = np.linalg.inv(info_mat)
    cov = model.camera_block(info_mat)
    k = best.prob.n_pose
    cov_K = full_cov[k - 3:k, k - 3:k]
    if camera_correction != "none" and not free.all():
        consider = camera_consider(best, free, data_sigma)
        cov = cov + consider[:6, :6]
        cov_K = cov_K + consider[k - 3:k, k - 3:k]
    shared_m = None
    if shared_factor is not None:
        shared = shared_robot_consider(best, info_mat, shared_factor)
        cov = cov + shared
        shared_m = float(np.sqrt(np.trace(shared[3:6, 3:6])))
    sig_theta = np.zeros(3)
    sig_theta[free] = np.sqrt(np.diag(full_cov)[k:])
    return cov, sig_theta, shared_m, cov_K


def _result(problem, start: _Start, best: Candidate, free, data_sigma, camera_correction, blocked, flips,
            notes, motion: MotionPrior) -> CalibrationResult:
    """Stage 5: covariance, self-check and residuals of the chosen model, as a result."""
    fit, inliers = best.fit, start.inliers
    C, K, theta, prob = best.C, best.K, best.theta, best.prob
    shared_factor = None if problem.robot_shared_error is None else problem.robot_shared_error[inliers]
    cov, sig_theta, shared_m, cov_K = _covariance(best, free, data_sigma, camera_correction, shared_factor)
    X, Y = model.join(C, K, problem.setup)
    loo = best.loo_errors
    # Too few samples to hold one out: no self-check, the result stands.
    check = None if loo is None else consistency(fit, prob, C, K, theta, *loo)
    if check is not None and check.warning:
        notes.append(check.warning)
    if inliers.all():
        # Every sample is in the fit: its residuals at the estimate are evaluated already.
        r, e = prob.raw(C, K, theta)[:2]
        r_all = Residuals(translation=np.linalg.norm(r, axis=1), rotation=None if e is None else np.linalg.norm(e, axis=1))
    else:
        r_all = _residuals(X, Y, problem, theta, fit.use_rotation)
    details = AutoDetails(
        start=start.result.method,
        start_candidates=dict(start.tried),
        measurements=("points", "orientations") if fit.use_rotation else ("points",),
        camera_correction={name: CameraParameter(value=float(theta[i]), sigma=float(sig_theta[i]),
                                                 estimated=bool(free[i]))
                           for i, name in enumerate(model.CAMERA_PARAMS)},
        # Where the correction holds: its rigid stand-in for uncorrected points is fitted there, on demand.
        correction_points=problem.points[inliers] if np.any(theta) else None,
        noise=best.noise, robot_shared_error_m=shared_m, blocked_folds=blocked, notes=tuple(notes), flips=flips,
        cost=float(prob.cost(C, K, theta)))
    result = CalibrationResult(method="auto", setup=problem.setup, X=X, Y=Y, n_samples=problem.n, residuals=r_all,
                               cov=cov, marker_rotation_known=fit.use_rotation,
                               inliers=None if inliers.all() else inliers, converged=best.converged,
                               iterations=best.iterations, cov_kind="fisher-extended", self_check=check, auto=details,
                               undetermined=motion.undetermined)
    note = determined_note(result, motion, cov_K)
    if note is None:
        return result
    return dataclasses.replace(result, auto=dataclasses.replace(details, notes=details.notes + (note,)))


def _residuals(X, Y, problem: CalibrationProblem, theta, use_rotation) -> Residuals:
    """Residuals of every sample (outliers too) at ``(X, Y)`` with the camera correction ``theta``."""
    C, K, M = model.split(X, Y, problem.A, problem.setup)
    return Residuals(*model.residual_norms(C, K, M, problem.B, theta, rotation=use_rotation))
