"""``solve("auto")``: every measurement the data carry, the extended model of `calib.model`.

Pipeline (both setups; eye-to-hand ``X = T_flange_marker``, ``Y = T_base_cam``;
eye-in-hand ``X = T_flange_cam``, ``Y = T_base_marker``; paper eq. 1):

1. Start: the best closed form of the paper for the data (YKronT' from the
   marker points; with marker poses also YQuatT' and YKronRT), chosen by the
   median point residual. Pose data first get their half-turn / flip
   ambiguity resolved (`calib.symmetry`).
2. Outliers: if the start's residuals show any (chi-square test at a robust
   scale), the LMedS search of `calib.robust` around that closed form.
3. Maximum likelihood on the inliers with the extended model: marker points
   (always), marker orientations (pose data), robot pose error propagated
   into the points, and the camera's depth scale / depth offset / focal
   scale (`camera_correction`), in rounds with the variance-component
   estimate of the noise levels (`calib.model.variance_components`,
   `_Fit.run`). Orientations and camera parameters are model choices made
   by held-out error (`_select_camera`); the well-determined ones are fitted
   together, and a choice that a Gauss-Newton step already shows to be
   useless is not refitted (`_step_helps`).
   From 100 samples on, those choices are checked on contiguous stretches
   of the recording held out in turn (`_blocked_choice`): a simpler model
   that predicts them at least as well is taken instead, and the closed-form
   start if it predicts them clearly better, so that what is reported
   carries to another session.
4. Camera parameters the motions do not determine (from the information
   matrix: their 1-sigma would exceed `IDENTIFIABLE_SIGMA`) stay at nominal
   (zero), with a message naming the motion that would fix it.
5. Self-check (`self_check`): chi-square of the residuals against the
   camera's a-priori noise model, and the linearised leave-one-out
   prediction error of the marker point beside the predicted one (the
   hat-matrix formula of `calib.model.leave_one_out`: no refit, so it runs
   inside every ``solve`` also at N = 1000, where a k-fold refit of ``auto``
   would cost k fits).
"""

from __future__ import annotations

import numpy as np
from scipy.special import chdtrc
from scipy.stats import chi2

from calib import model
from calib import transforms as tf
from calib.errors import CalibrationError, InsufficientDataError
from calib.result import CalibrationResult, Residuals

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
#: Systematic camera errors assumed for a parameter left at nominal, 1-sigma: they widen the
#: covariance of the result ("consider" covariance) instead of being silently taken as zero.
#: Structured-light figures before an infield correction: 1% scale, 3 mm offset, 1% focal.
CONSIDER_SIGMA = {"depth_scale": 0.01, "depth_offset": 0.003, "focal_scale": 0.01}
#: Contiguous blocks of the recording `_blocked_choice` holds out in turn (3 below 30 samples).
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
#: Fewest samples before camera parameters are considered: below it the held-out test that
#: admits them is too noisy (with 8 samples it admits metre-scale nonsense).
MIN_SAMPLES_CAMERA = 12
#: A camera parameter estimated beyond this is taken as the model absorbing something else
#: (a bad sample, robot error) and is not used: 5% scale, 30 mm offset, 5% focal.
PLAUSIBLE = {"depth_scale": 0.05, "depth_offset": 0.03, "focal_scale": 0.05}
#: Smallest held-out improvement that counts, m (below it noise-free data would choose at random).
MIN_LOO_GAIN_M = 1e-6
#: A model variant (orientations, a camera parameter) must lower the held-out point error by this fraction.
MIN_LOO_GAIN = 0.03
#: What to move to determine each camera parameter.
_MOTION_HINT = {
    "depth_scale": "translate the marker over a larger range, especially towards and away from the camera",
    "depth_offset": "vary the marker's distance from the camera more",
    "focal_scale": "move the marker across the whole image, out to its edges",
}
#: Held-out prediction error may differ from the predicted one by this factor before we warn.
LOO_TOLERANCE = 1.5
#: p-value below which the residuals reject the camera's a-priori noise model.
CHI2_ALPHA = 0.001
#: Noise level of the robot before it is estimated (m): a UR10's repeatability order.
ROBOT_SIGMA_START = 2e-4
#: Variance-component rounds: stop when no level changes by more than 1% or after this many.
MAX_ROUNDS = 12
#: LM step (rad, m) below which the fit counts as converged: 10 nm, ~1e-4 of any 1-sigma here (the
#: default 1e-10 of `calib.model.minimize` often costs one more iteration, ~1 ms at N = 1000).
FIT_TOL = 1e-8
#: Once no noise level changes by more than this, the fit is converged before the next update
#: (that update then usually moves them by under 1%: the last round).
POLISH_CHANGE = 0.05
#: Rounds of the noise-level estimate at a fixed estimate (self-check of any method; 3% is plenty there).
CHECK_ROUNDS = 5


def _free_for(mode: str) -> tuple[bool, bool, bool]:
    return {"none": (False, False, False), "depth": (True, True, False)}.get(mode, (True, True, True))



class _Fit:
    """State of the extended fit: transforms, camera error, noise levels and the problem."""

    def __init__(self, A, B, setup, shape, use_rotation, shape_whitener=None):
        self.setup = setup
        self.A, self.B = A, B
        self.shape = shape
        self.use_rotation = use_rotation
        self.M = model.split(np.eye(4), np.eye(4), A, setup)[2]
        self._cof_at = None
        self._memo: dict = {}      # the last raw evaluation, shared by the problems of this fit (`model.Problem`)
        self._whitener_at = None   # the last point whitener, with its noise levels and robot cofactor
        self._shape_whitener = shape_whitener

    def cofactor(self, C, K):
        """`calib.model.robot_cofactor` at ``(C, K)``; the last one is kept (rounds re-weight at a fixed estimate)."""
        if self._cof_at is None or not ((self._cof_at[0] is C or np.array_equal(self._cof_at[0], C))
                                        and (self._cof_at[1] is K or np.array_equal(self._cof_at[1], K))):
            self._cof_at = (C, K, model.robot_cofactor(C, K, self.M, self.setup))
        return self._cof_at[2]

    @property
    def shape_whitener(self) -> np.ndarray:
        """`calib.model.whitener` of the camera's point covariance shape alone (no robot error)."""
        if self._shape_whitener is None:
            self._shape_whitener = model.whitener(self.shape)
        return self._shape_whitener

    def problem(self, C, K, noise, free):
        cof = self.cofactor(C, K)
        # The same levels at the same estimate (a fit's final problem, its information, its held-out step).
        if self._whitener_at is None or self._whitener_at[0] != noise or self._whitener_at[1] is not cof:
            self._whitener_at = (noise, cof, model.whitener(noise.point_cov(self.shape, cof)))
        W = self._whitener_at[2]
        return model.Problem(self.M, self.B, W, sigma_rot=noise.rotation, free=free, use_rotation=self.use_rotation,
                             memo=self._memo), cof

    def run(self, C, K, theta, noise, free, estimate=(True, True, True)):
        """Variance components and the fit to them, until both settle.

        Rounds of one LM (Gauss-Newton) step and one variance-component update
        (Fisher scoring of the restricted likelihood in both) while the noise
        levels still move by `POLISH_CHANGE` or more; then the fit is converged
        with those levels and the components are updated once more, until
        that update moves them by less than 1%. The fixed point is
        the one of alternating full fits and updates, without 3-4 LM
        iterations per round on a fit to levels that are about to change
        (at N = 1000 that was two thirds of the time of ``solve("auto")``).
        A round whitens once: the update after the step uses the robot
        cofactor of the round's start (it moves with the estimate by the
        step's share of the lever arm; over 288 cases the noise levels
        changed by at most 5e-4 of themselves, the result by 4e-4 sigma).
        """
        iters, converged, polish = 0, False, False
        for _ in range(MAX_ROUNDS):
            prob, cof = self.problem(C, K, noise, free)
            C, K, theta, _, it, converged = model.minimize(prob, C, K, theta, max_iterations=50 if polish else 1,
                                                           tol=FIT_TOL)
            iters += it
            new, shares = model.variance_components(prob, C, K, theta, self.shape, cof, noise, estimate=estimate)
            change = max(abs(new.point_scale / noise.point_scale - 1), abs(new.robot / max(noise.robot, 1e-12) - 1),
                         0.0 if new.rotation is None else abs(new.rotation / noise.rotation - 1))
            noise = new
            if change < 0.01 and polish:
                break
            polish = change < POLISH_CHANGE
        else:
            prob, _ = self.problem(C, K, noise, free)
            C, K, theta, _, it, converged = model.minimize(prob, C, K, theta, max_iterations=50, tol=FIT_TOL)
            iters += it
        prob, _ = self.problem(C, K, noise, free)
        return C, K, theta, noise, prob, iters, converged


class _Candidate:
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
        """Held-out errors and their predicted RMS, m (`calib.model.leave_one_out`), or None if undetermined."""
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
            prob, _ = self.fit.problem(self.C, self.K, self.noise, (True, True, True))
            self._info_all = (model.information(prob, self.C, self.K, self.theta), prob.n_pose)
        info, n_pose = self._info_all
        idx = np.concatenate([np.arange(n_pose), n_pose + np.flatnonzero(free)])
        return info[idx][:, idx], n_pose


def _better(cand: _Candidate, best: _Candidate) -> bool:
    """Whether ``cand`` predicts held-out points clearly better than ``best``."""
    return cand.loo < (1.0 - MIN_LOO_GAIN) * best.loo and best.loo - cand.loo > MIN_LOO_GAIN_M


def _start(A, B, setup, use_rotation):
    """Closed-form candidates and the one with the smallest median point residual."""
    from calib.api import closed_form

    names = ["YKronT'"] + (["YQuatT'", "YKronRT"] if use_rotation else [])
    best, best_med, tried = None, np.inf, []
    for name in names:
        try:
            res = closed_form(name, A, B, setup=setup, validate=False)     # validated by `solve`
        except CalibrationError:
            continue
        med = float(np.median(res.residuals.translation))
        tried.append((name, med))
        if med < best_med:
            best, best_med = res, med
    if best is None:
        raise InsufficientDataError("no closed-form start could be computed for these samples")
    return best, tried


def _needs_robust(d2) -> bool:
    """Whether the start's whitened squared point residuals ``d2`` (`_point_d2`) show outliers at a robust (median) scale."""
    scale = np.median(d2) / _CHI2_3_MEDIAN
    return bool(np.any(d2 > _CHI2_3_OUTLIER * scale * 4.0))


#: Quantiles of chi-square with 3 dof used by `_needs_robust` (scipy's ppf costs ~50 us a call).
_CHI2_3_MEDIAN = float(chi2.ppf(0.5, 3))
_CHI2_3_OUTLIER = float(chi2.ppf(0.9999, 3))


def _point_d2(C, K, M, p, W_shape) -> np.ndarray:
    """Squared point residuals (N,) at ``(C, K)`` (no camera error) whitened by the camera's shape ``W_shape``."""
    return _whitened_squares(W_shape, p - model.predict_points(C, K[:3, 3], M))


def _whitened_squares(W, r) -> np.ndarray:
    """``|W_i r_i|^2`` (N,) for whitening matrices (N, 3, 3) and residuals (N, 3)."""
    wr = np.einsum("nij,nj->ni", W, r)
    return np.sum(wr * wr, axis=1)


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


def solve_auto(A, B, *, setup: str, point_cov=None, camera_correction: str = "auto", robust: bool = True,
               rng: np.random.Generator | None = None, robot_shared_error=None) -> CalibrationResult:
    """Calibrate with every measurement and the extended model (module docstring).

    Parameters
    ----------
    A : ndarray, shape (N, 4, 4)
        ``T_base_flange`` (validated by the caller).
    B : ndarray, shape (N, 3) or (N, 4, 4)
        Marker center in the camera frame, or ``T_cam_marker``.
    setup : {"eye_to_hand", "eye_in_hand"}
    point_cov : array_like, shape (3, 3) or (N, 3, 3), optional
        Shape of the marker point covariance (m^2); its scale is estimated.
    camera_correction : {"auto", "none", "depth", "depth+focal"}
        Which camera parameters to estimate: "depth" = depth scale and
        offset, "depth+focal" adds the focal scale, "auto" = all three that
        the motions determine.
    robot_shared_error : array_like, shape (N, 6, P), optional
        The robot's error that all samples share (e.g. its kinematic
        error): sample ``i``'s true flange pose is ``A_i Exp(F_i z)`` with
        ``F_i`` this (6, P) factor (flange-frame twist: rotation rad, then
        translation m) and ``z ~ N(0, I_P)`` the same for every sample
        (`calib.robot_error.ur_dh_error_factor` for a UR's DH parameters). It
        joins the covariance as a "consider" term (`_shared_robot_consider`);
        the white robot error stays a variance component.
    robust : bool
        Reject gross outliers (LMedS) when the start shows any.
    rng : numpy.random.Generator, optional
        For the LMedS subsets; ``default_rng(0)`` if not given.

    Returns
    -------
    CalibrationResult
        ``method`` ``"auto"``; ``cov`` the camera block of the inverse
        information of the extended model (nuisances marginalised);
        ``info``: ``start`` (closed form used), ``measurements``,
        ``camera_correction`` (per parameter: value, sigma, estimated,
        note), ``noise`` (point_scale, robot_m, rotation_rad),
        ``self_check`` (see `self_check`), ``blocked_folds`` (`_blocked_choice`'s
        report, None when not run: below `MIN_SAMPLES_BLOCKED` or nothing to check), ``cov_kind`` "fisher-extended"
        (plus the "consider" covariance of camera parameters left at nominal,
        `CONSIDER_SIGMA`, unless ``camera_correction="none"``, and that of
        ``robot_shared_error``, whose share of the camera translation's
        1-sigma is ``robot_shared_error_mm``, None without it).
    """
    from calib.robust import robust_solve
    from calib.symmetry import resolve_flips

    if camera_correction not in CAMERA_CORRECTIONS:
        raise CalibrationError(f"camera_correction must be one of {', '.join(CAMERA_CORRECTIONS)}, got {camera_correction!r}")
    n = len(A)
    if robot_shared_error is not None:
        robot_shared_error = tf.as_real_array(robot_shared_error, "robot_shared_error")
        if robot_shared_error.ndim != 3 or robot_shared_error.shape[:2] != (n, 6) or robot_shared_error.shape[2] < 1:
            raise CalibrationError(f"robot_shared_error must have shape ({n}, 6, P), got {robot_shared_error.shape}")
    use_rotation = B.ndim == 3
    notes = []
    flips = None
    if use_rotation:
        B, flips = resolve_flips(A, B, setup=setup)
        if flips is not None and flips["n_flipped"]:
            notes.append(f"{flips['n_flipped']} marker poses were flipped by {flips['angle_deg']:.0f} deg "
                         "(symmetric target) and were turned back")
    shape, _ = model.point_shape(B, point_cov)
    start, tried = _start(A, B, setup, use_rotation)
    p = B if B.ndim == 2 else B[:, :3, 3]
    inliers = np.ones(n, dtype=bool)
    W_shape = model.whitener(shape)
    d2 = _point_d2(*model.split(start.X, start.Y, A, setup), p, W_shape)   # also the initial noise level's
    if robust and n >= 8 and _needs_robust(d2):
        from calib.api import closed_form

        name = start.method
        try:
            # YKronT' needs 5 samples (6 steady it); the pose-based starts 3 (4).
            hyp = robust_solve(lambda a, b: closed_form(name, a, b, setup=setup), A, B, setup=setup,
                               point_cov=point_cov, rng=rng if rng is not None else np.random.default_rng(0),
                               min_samples=4 if start.marker_rotation_known else 6)
        except CalibrationError as e:
            notes.append(f"outlier search failed ({e}); all samples used")
        else:
            inliers = hyp.inliers
            start, d2 = hyp, None
    A_in, B_in, shape_in = A[inliers], B[inliers], shape[inliers]
    C0, K0, _ = model.split(start.X, start.Y, A_in, setup)
    theta = np.zeros(3)
    # Measurement sets: marker orientations are used unless they make held-out points worse.
    best = None
    for rot in ([True, False] if use_rotation else [False]):
        fit = _Fit(A_in, B_in, setup, shape_in, rot, shape_whitener=W_shape[inliers])
        K = K0
        if rot and not start.marker_rotation_known:
            K = tf.make_transform(model.marker_rotation(C0, fit.M, B_in[:, :3, :3]), K0[:3, 3])
        if d2 is None:
            d2 = _point_d2(C0, K0, fit.M, p[inliers], fit.shape_whitener)
        noise = _initial_noise(d2, C0, K, fit.M, B_in[:, :3, :3] if rot else None)
        if not use_rotation:
            # Points only: nothing to compare before the camera parameters, which start from here (`_select_camera`).
            best = _Candidate(fit, C0, K, theta, noise, fit.problem(C0, K, noise, (False, False, False))[0], 0, False,
                              fitted=False)
            break
        if best is not None and not _step_helps(best, (False, False, False), fit):
            continue      # without orientations not even a step predicts held-out points better
        cand = _Candidate(fit, *fit.run(C0, K, theta, noise, (False, False, False)))
        if best is None or _better(cand, best):
            if best is not None:
                notes.append(f"marker orientations left out: held-out points {best.loo * 1e3:.2f} mm with them, "
                             f"{cand.loo * 1e3:.2f} mm without (systematic orientation error, e.g. intrinsics)")
            best = cand
    wanted = _free_for(camera_correction)
    if any(wanted) and len(A_in) < MIN_SAMPLES_CAMERA:
        notes.append(f"camera correction not attempted: {len(A_in)} samples, it needs {MIN_SAMPLES_CAMERA}")
        wanted = (False, False, False)
    selected = _select_camera(best, wanted, defer=True)
    if selected is None:
        # A parameter taken without a fit of its own came out implausible: choose one at a time, each fitted.
        if not best.fitted:
            best = _Candidate(best.fit, *best.fit.run(best.C, best.K, best.theta, best.noise, (False, False, False)))
        selected = _select_camera(best, wanted, defer=False)
    best, free, data_sigma, camera_notes = selected
    notes.extend(camera_notes)
    blocked = None
    if len(A_in) >= MIN_SAMPLES_BLOCKED:
        best, free, note, blocked = _blocked_choice(best, free, A_in, B_in, shape_in, setup, use_rotation,
                                                    W_shape[inliers], start)
        if note:
            notes.append(note)
    fit = best.fit
    C, K, theta, noise, prob = best.C, best.K, best.theta, best.noise, best.prob
    iters, converged, use_rotation = best.iterations, best.converged, fit.use_rotation
    info_mat, _ = best.information(free)
    full_cov = np.linalg.inv(info_mat)
    cov = model.camera_block(info_mat)
    if camera_correction != "none" and not free.all():
        cov = cov + _consider(best, free, data_sigma)
    shared_mm = None
    if robot_shared_error is not None:
        shared = _shared_robot_consider(best, info_mat, robot_shared_error[inliers])
        cov = cov + shared
        shared_mm = float(np.sqrt(np.trace(shared[3:6, 3:6])) * 1e3)
    sig_theta = np.zeros(3)
    sig_theta[free] = np.sqrt(np.diag(full_cov)[prob.n_pose:])
    correction = {
        name: {"value": float(theta[i]), "sigma": float(sig_theta[i]), "estimated": bool(free[i])}
        for i, name in enumerate(model.CAMERA_PARAMS)
    }
    X, Y = model.join(C, K, setup)
    loo = best.loo_errors
    # Too few samples to hold one out: no self-check, the result stands.
    check = None if loo is None else _consistency(fit, prob, C, K, theta, *loo)
    if check is not None and check["warning"]:
        notes.append(check["warning"])
    if inliers.all():
        # Every sample is in the fit: its residuals at the estimate are evaluated already.
        r, e = prob.raw(C, K, theta)[:2]
        r_all = Residuals(translation=np.linalg.norm(r, axis=1), rotation=None if e is None else np.linalg.norm(e, axis=1))
    else:
        r_all = _residuals(X, Y, A, B, setup, theta, use_rotation)
    return CalibrationResult(
        method="auto",
        setup=setup,
        X=X,
        Y=Y,
        n_samples=n,
        residuals=r_all,
        cov=cov,
        marker_rotation_known=use_rotation,
        inliers=None if inliers.all() else inliers,
        converged=converged,
        iterations=iters,
        info={
            "start": start.method,
            "start_candidates": {name: med for name, med in tried},
            "measurements": ["points", "orientations"] if use_rotation else ["points"],
            "camera_correction": correction,
            # Where the correction holds: its rigid stand-in for uncorrected points is fitted there, on demand.
            "correction_points": p[inliers] if np.any(theta) else None,
            "noise": {"point_scale": noise.point_scale, "robot_m": noise.robot, "rotation_rad": noise.rotation},
            "robot_shared_error_mm": shared_mm,
            "self_check": check,
            "blocked_folds": blocked,
            "notes": notes,
            "flips": flips,
            "cov_kind": "fisher-extended",
            "cost": float(prob.cost(C, K, theta)),
        },
    )


def blocked_folds(n: int) -> list[np.ndarray]:
    """Contiguous stretches of the recording (`BLOCKED_FOLDS` of them, 3 below 30 samples): each held out in
    turn, a stand-in for another session (random folds share each stretch's conditions with the training set)."""
    return [b for b in np.array_split(np.arange(n), 3 if n < 30 else BLOCKED_FOLDS) if len(b)]


def _blocked_error(cand: _Candidate, free, A, B, shape, setup, folds) -> float:
    """RMS (m) of the marker points of each block of ``folds`` predicted by the candidate's model refitted
    without them (its noise levels kept; a Gauss-Newton fit from the candidate's estimate)."""
    p = B if B.ndim == 2 else B[:, :3, 3]
    misses = []
    for test in folds:
        train = np.setdiff1d(np.arange(len(A)), test)
        fit = _Fit(A[train], B[train], setup, shape[train], cand.fit.use_rotation)
        prob, _ = fit.problem(cand.C, cand.K, cand.noise, tuple(bool(f) for f in free))
        try:
            C, K, theta, *_ = model.minimize(prob, cand.C, cand.K, cand.theta, max_iterations=BLOCKED_ITERATIONS,
                                              tol=FIT_TOL)
        except CalibrationError:
            return float("inf")
        M = model.split(np.eye(4), np.eye(4), A[test], setup)[2]
        misses.append(p[test] - model.predict_points(C, K[:3, 3], M, theta))
    return float(np.sqrt(np.mean(np.sum(np.concatenate(misses) ** 2, axis=1))))


def _closed_form_blocked_error(name: str, A, B, setup, folds) -> float:
    """`_blocked_error` of the closed form ``name`` (solved again without each block); inf where it fails."""
    from calib.api import closed_form

    p = B if B.ndim == 2 else B[:, :3, 3]
    misses = []
    for test in folds:
        train = np.setdiff1d(np.arange(len(A)), test)
        try:
            res = closed_form(name, A[train], B[train], setup=setup)
        except CalibrationError:
            return float("inf")
        C, K, M = model.split(res.X, res.Y, A[test], setup)
        misses.append(p[test] - model.predict_points(C, K[:3, 3], M))
    return float(np.sqrt(np.mean(np.sum(np.concatenate(misses) ** 2, axis=1))))


def _blocked_choice(best: _Candidate, free, A, B, shape, setup, has_rotation: bool, W_shape, start):
    """The model choices made by leave-one-out, checked against blocked folds: a simpler model that predicts
    contiguous held-out stretches of the recording at least as well replaces them.

    The leave-one-out choices of `_select_camera` and of the measurement set
    judge a model on samples like its own; a camera correction or a dropped
    measurement set that only fits one stretch of the recording better does
    not carry to the next session. The candidates: with and without the
    marker orientations (pose data), each with no camera correction and with
    the chosen one; each is refitted without each stretch (`blocked_folds`)
    and predicts its points. The simplest (every measurement, no correction,
    then fewer changes) whose error is within `BLOCKED_GAIN` of the chosen
    model's replaces it: when the evidence for the extra model is weak, the
    simpler one is reported; a more complex one than the chosen is never
    taken. Last, the closed-form start, solved again without each stretch:
    if it predicts them better by `START_GAIN`, it is reported (its
    covariance that of the plain model at its estimate), so that ``auto``
    does not carry worse to another session than where it started.

    Returns ``(best, free, note or None, report)``; ``report`` (for
    ``info["blocked_folds"]``): the number of folds, each candidate's
    held-out RMS (m), and what decided.
    """
    folds = blocked_folds(len(A))
    free = np.asarray(free, dtype=bool)
    none = np.zeros(3, dtype=bool)
    fits = {best.fit.use_rotation: best.fit}
    if has_rotation and not best.fit.use_rotation:
        fits[True] = _Fit(A, B, setup, shape, True, shape_whitener=W_shape)
    elif has_rotation:
        fits[False] = _Fit(A, B, setup, shape, False, shape_whitener=W_shape)
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
            noise = _initial_noise(_point_d2(best.C, best.K, fit.M, B if B.ndim == 2 else B[:, :3, 3],
                                             fit.shape_whitener), best.C, K, fit.M, B[:, :3, :3] if rot else None)
            cand = _Candidate(fit, *fit.run(best.C, K, best.theta if corr else np.zeros(3), noise,
                                            tuple(bool(v) for v in (free if corr else none))))
        scored.append((cand, free if corr else none, _blocked_error(cand, free if corr else none, A, B, shape,
                                                                    setup, folds)))
    report = {"folds": len(folds), "chosen_by": "leave-one-out",
              "candidates": [{"orientations": bool(c.fit.use_rotation),
                              "camera_correction": [n for n, f in zip(model.CAMERA_PARAMS, cf) if f],
                              "heldout_m": float(e)} for c, cf, e in scored]}
    if not all(np.isfinite(e) and e <= BLOCKED_SANE * best.loo for _, _, e in scored):
        # The stretches left out take what determines the model with them (a refit runs away): no evidence.
        return best, free, None, {**report, "chosen_by": "leave-one-out (blocked folds undetermined)"}
    e_best = next(e for c, _, e in scored if c is best)
    # The simplest model that predicts the held-out stretches at least as well as the leave-one-out choice.
    simpler = [item for item in scored[:next(i for i, (c, _, _) in enumerate(scored) if c is best)]
               if item[2] <= (1.0 + BLOCKED_GAIN) * e_best]
    chosen = simpler[0] if simpler else next(item for item in scored if item[0] is best)
    # The closed-form start, plainer still: reported when the fits do not predict the stretches better.
    name = start.method.split("+")[0]
    e_start = _closed_form_blocked_error(name, A, B, setup, folds)
    report["candidates"].insert(0, {"closed_form": name, "heldout_m": e_start})
    if e_start < (1.0 - START_GAIN) * chosen[2]:
        plain = scored[0][0]
        C, K, _ = model.split(start.X, start.Y, A, setup)
        if plain.fit.use_rotation and not start.marker_rotation_known:
            K = tf.make_transform(model.marker_rotation(C, plain.fit.M, B[:, :3, :3]), K[:3, 3])
        prob, _ = plain.fit.problem(C, K, plain.noise, (False, False, False))
        cand = _Candidate(plain.fit, C, K, np.zeros(3), plain.noise, prob, best.iterations, True)
        report["chosen_by"] = "blocked folds: closed form"
        return cand, np.zeros(3, dtype=bool), (
            f"the closed form {name} is reported: the maximum-likelihood fits predicted contiguous stretches of the "
            f"recording held out in turn no better ({chosen[2] * 1e3:.2f} mm, {e_start * 1e3:.2f} mm by {name}); "
            "its covariance is that of the plain model at its estimate"), report
    if chosen[0] is best:
        return best, free, None, report
    cand, cfree, err = chosen
    report["chosen_by"] = "blocked folds"
    cand.iterations += best.iterations
    dropped = []
    if free.any() and not cfree.any():
        dropped.append(f"the camera correction ({', '.join(n for n, f in zip(model.CAMERA_PARAMS, free) if f)})")
    if cand.fit.use_rotation != best.fit.use_rotation:
        dropped.append("the marker orientations " + ("back in" if cand.fit.use_rotation else "left out"))
    return cand, cfree, (
        f"{' and '.join(dropped)}: contiguous stretches of the recording held out in turn are predicted "
        f"{err * 1e3:.2f} mm this way, {e_best * 1e3:.2f} mm as chosen by leave-one-out; the plainer model "
        "carries to another session"), report


def _select_camera(best: _Candidate, wanted, *, defer: bool):
    """Camera parameters, forward selection in the order of how common the error is.

    Depth scale, depth offset, focal: one joins if the motions determine it
    well (1-sigma from the information matrix below `WELL_DETERMINED_SIGMA`),
    or determine it at all (below `IDENTIFIABLE_SIGMA`) and it lowers the
    held-out prediction error of the points. With ``defer``, well-determined
    parameters are fitted together, in one run of variance components and fit
    when a comparison needs it or at the end, instead of one run each (the
    same fixed point; at N = 1000 it halves the time of ``solve("auto")``);
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
        if sigmas[name] > WELL_DETERMINED_SIGMA[name] and not _step_helps(best, trial):
            notes.append(_not_helpful(name, sigmas[name]))
            continue
        cand = _Candidate(fit, *fit.run(best.C, best.K, best.theta, best.noise, tuple(trial)))
        wild = [n for i, n in enumerate(model.CAMERA_PARAMS) if trial[i] and abs(cand.theta[i]) > PLAUSIBLE[n]]
        if wild:
            notes.append(f"{name} not estimated: with it, {', '.join(wild)} came out implausibly large "
                         "(the model would absorb another error)")
            continue
        if sigmas[name] <= WELL_DETERMINED_SIGMA[name] or _better(cand, best):
            cand.iterations += best.iterations
            best, free = cand, trial
        else:
            notes.append(_not_helpful(name, sigmas[name]))
    if not fitted:
        best = _fitted(best, free)
        if best is None:
            return None
    return best, free, data_sigma, notes


def _sigmas(best: _Candidate, trial) -> dict[str, float]:
    """`identifiability` of the camera parameters ``trial`` at ``best``."""
    info, n_pose = best.information(trial)
    return identifiability(info, trial, n_pose)


def _not_helpful(name: str, sigma: float) -> str:
    return (f"{name} not estimated: these motions determine it to {_fmt(name, sigma)} (1-sigma) and it did not "
            f"improve held-out predictions; to pin it down, {_MOTION_HINT[name]}")


def _step_helps(best: _Candidate, trial, fit: _Fit | None = None) -> bool:
    """Whether freeing the camera parameters ``trial`` (or the measurement set of ``fit``) is worth a refit.

    The Gauss-Newton step from ``best`` with ``trial`` free, at ``best``'s
    noise levels (`calib.model.leave_one_out_after_step`): if that does not
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
    prob, _ = fit.problem(best.C, best.K, best.noise, tuple(bool(f) for f in trial))
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


def _fitted(start: _Candidate, free) -> _Candidate | None:
    """``start`` fitted with the camera parameters ``free``; None if one of them comes out implausible."""
    fit = start.fit
    cand = _Candidate(fit, *fit.run(start.C, start.K, start.theta, start.noise, tuple(bool(f) for f in free)))
    cand.iterations += start.iterations
    if any(free[i] and abs(cand.theta[i]) > PLAUSIBLE[n] for i, n in enumerate(model.CAMERA_PARAMS)):
        return None
    return cand


def _consider(best: _Candidate, free, data_sigma) -> np.ndarray:
    """Camera covariance (6, 6) added by the camera parameters left at nominal ("consider" covariance).

    They are not estimated, but a real camera has such errors: the estimate
    moves by ``S dtheta_c`` with ``S = -N_xx^-1 N_xc`` for an error
    ``dtheta_c``, so ``S diag(sigma_c^2) S^T`` joins the covariance, with
    ``sigma_c`` the typical error (`CONSIDER_SIGMA`) or, if smaller, what the
    data bound it to (``data_sigma``: 1-sigma with the parameter free; it was
    left out because estimating it did not predict better).
    """
    info, n_pose = best.information((True, True, True))
    x = np.r_[np.arange(n_pose), n_pose + np.flatnonzero(free)]
    c = n_pose + np.flatnonzero(~free)
    S = np.linalg.solve(info[np.ix_(x, x)], info[np.ix_(x, c)])[:6]
    names = [model.CAMERA_PARAMS[i - n_pose] for i in c]
    sig = np.array([min(CONSIDER_SIGMA[m], data_sigma.get(m, np.inf)) for m in names])
    out = (S * sig**2) @ S.T
    return 0.5 * (out + out.T)


def _shared_robot_consider(best: _Candidate, info, F) -> np.ndarray:
    """Camera covariance (6, 6) added by a robot error that all samples share (``F``: (N, 6, P), `solve_auto`).

    The estimate responds linearly to a change ``dv`` of the whitened
    residuals: ``dx = N^-1 G^T dv`` (``N`` the information, ``G`` the
    whitened Jacobian). Column ``k`` of ``F`` moves every flange pose by
    ``Exp(F_i[:, k])``, the residuals by ``dv_k`` (central differences), so
    ``S S^T`` with ``S = N^-1 G^T [dv_1 .. dv_P]`` joins the covariance: the
    error does not average out over the samples as white noise would.
    """
    fit, prob, C, K, theta = best.fit, best.prob, best.C, best.K, best.theta
    X, Y = model.join(C, K, fit.setup)
    _, G = prob.whitened(C, K, theta)
    h = 1e-3                      # of each 1-sigma column: the response is linear at this scale
    dv = np.empty((G.shape[0], F.shape[2]))
    twist = np.array([h, -h])[:, None, None, None] * np.swapaxes(F, 1, 2)[None]     # (side, N, P, 6)
    moved = fit.A[None, :, None] @ tf.make_transform(tf.so3_exp(twist[..., :3]), twist[..., 3:])  # (2, N, P, 4, 4)
    for k in range(F.shape[2]):
        sides = []
        for side in range(2):
            M_k = model.split(X, Y, moved[side, :, k], fit.setup)[2]
            p = model.predict_points(C, K[:3, 3], M_k, theta)
            v = -np.einsum("nij,nj->ni", prob.W_t, p).reshape(-1)      # the whitened residual, less W p_measured
            if prob.rotations:
                v = np.concatenate([v, (model.rotation_residuals(C, K, M_k, prob.R_B)[0] / prob.sigma_rot).reshape(-1)])
            sides.append(v)
        dv[:, k] = (sides[0] - sides[1]) / (2 * h)
    S = np.linalg.solve(info, G.T @ dv)[:6]
    out = S @ S.T
    return 0.5 * (out + out.T)


def _fmt(name: str, sigma: float) -> str:
    if not np.isfinite(sigma):
        return "unbounded"
    return f"{sigma * 1e3:.1f} mm" if name == "depth_offset" else f"{sigma * 100:.2f}%"


def _residuals(X, Y, A, B, setup, theta, use_rotation) -> Residuals:
    C, K, M = model.split(X, Y, A, setup)
    p = B if B.ndim == 2 else B[:, :3, 3]
    r = p - model.predict_points(C, K[:3, 3], M, theta)
    rot = None
    if use_rotation:
        rot = np.linalg.norm(model.rotation_residuals(C, K, M, B[:, :3, :3])[0], axis=1)
    return Residuals(translation=np.linalg.norm(r, axis=1), rotation=rot)


def _initial_noise(d2, C, K, M, R_B) -> model.NoiseLevels:
    """Starting noise levels: the camera model at the scale of the residuals (``d2``, `_point_d2`), a small robot error."""
    rot0 = None
    if R_B is not None:
        e0 = model.rotation_residuals(C, K, M, R_B)[0]
        rot0 = max(float(np.sqrt(np.mean(e0**2))), 1e-4)
    return model.NoiseLevels(point_scale=max(float(np.mean(d2)) / 3.0, model.MIN_POINT_SCALE),
                             robot=ROBOT_SIGMA_START, rotation=rot0)


def _noise_at(fit, C, K, theta, free) -> model.NoiseLevels:
    """Variance components at a fixed estimate (no refit)."""
    p = fit.B if fit.B.ndim == 2 else fit.B[:, :3, 3]
    noise = _initial_noise(_point_d2(C, K, fit.M, p, fit.shape_whitener), C, K, fit.M,
                           fit.B[:, :3, :3] if fit.use_rotation else None)
    for _ in range(CHECK_ROUNDS):
        # Fixed estimate: the robot cofactor and the Jacobians are computed once (`_Fit.problem`).
        prob, cof = fit.problem(C, K, noise, free)
        new, _ = model.variance_components(prob, C, K, theta, fit.shape, cof, noise)
        settled = abs(new.point_scale / noise.point_scale - 1) < 0.03 and abs(new.robot / noise.robot - 1) < 0.03
        noise = new
        if settled:
            break
    return noise


def estimate_noise(X, Y, A, B, *, setup: str, point_cov=None, marker_rotation_known: bool = True) -> model.NoiseLevels:
    """Noise levels (`calib.model.NoiseLevels`) of the data at a given estimate, e.g. a closed form's.

    The variance components of `calib.model.variance_components` at ``(X, Y)``
    held fixed (eye-to-hand ``X = T_flange_marker``, ``Y = T_base_cam``;
    eye-in-hand ``X = T_flange_cam``, ``Y = T_base_marker``), no camera
    correction. Orientations are used for pose data ``B`` (N, 4, 4); with
    ``marker_rotation_known`` False (a point-only estimate) the marker-side
    rotation is first fitted to them.
    """
    shape, _ = model.point_shape(B, point_cov)
    fit = _Fit(A, B, setup, shape, B.ndim == 3)
    C, K, _ = model.split(X, Y, A, setup)
    if fit.use_rotation and not marker_rotation_known:
        K = tf.make_transform(model.marker_rotation(C, fit.M, B[:, :3, :3]), K[:3, 3])
    return _noise_at(fit, C, K, np.zeros(3), (False, False, False))


def self_check(X, Y, A, B, *, setup: str, point_cov=None, noise: model.NoiseLevels | None = None,
               theta=None, free=(False, False, False), use_rotation: bool | None = None,
               marker_rotation_known: bool = True) -> dict:
    """Consistency of a calibration with the measurement model, in numbers and plain words.

    Works for any estimate ``(X, Y)`` (eye-to-hand ``X = T_flange_marker``,
    ``Y = T_base_cam``; eye-in-hand ``X = T_flange_cam``, ``Y = T_base_marker``).

    - ``chi2``/``dof``/``p_value``: the point residuals whitened by the
      camera's a-priori covariance (given ``point_cov``, else the depth model
      of `calib.noise`) with no robot error: a small p-value
      (``prior_model_rejected``) says the camera noise alone does not explain
      the residuals (the robot or a systematic error does).
    - ``loo_observed_m`` / ``loo_predicted_m``: RMS leave-one-out prediction
      error of the marker point (linearised, `calib.model.leave_one_out`)
      and the RMS the model predicts for it with the noise levels ``noise``
      (estimated from the residuals at ``(X, Y)`` when not given);
      ``loo_ratio`` is observed / predicted. Outside ``1 / LOO_TOLERANCE ..
      LOO_TOLERANCE`` the ``warning`` says so in plain words.

    Parameters
    ----------
    X, Y : ndarray, shape (4, 4)
    A : ndarray, shape (N, 4, 4)
        ``T_base_flange``.
    B : ndarray, shape (N, 3) or (N, 4, 4)
    setup : {"eye_to_hand", "eye_in_hand"}
    point_cov : array_like, shape (3, 3) or (N, 3, 3), optional
    noise : calib.model.NoiseLevels, optional
    theta : array_like, shape (3,), optional
        Camera correction (`calib.model.CAMERA_PARAMS`), zero by default.
    free : sequence of 3 bool
        Which camera parameters were estimated (they count as unknowns).
    use_rotation : bool, optional
        Use the orientation residual of pose data (default: when B has poses).
    marker_rotation_known : bool
        False for a point-only estimate: the marker-side rotation is then
        taken as the best fit to the poses.

    Returns
    -------
    dict
        ``chi2, dof, p_value, prior_model_rejected, loo_observed_m,
        loo_predicted_m, loo_ratio, loo_errors_m (N,), consistent, warning``.
    """
    use_rotation = B.ndim == 3 if use_rotation is None else use_rotation and B.ndim == 3
    shape, _ = model.point_shape(B, point_cov)
    theta = np.zeros(3) if theta is None else np.asarray(theta, dtype=float)
    fit = _Fit(A, B, setup, shape, use_rotation)
    C, K, _ = model.split(X, Y, A, setup)
    if use_rotation and not marker_rotation_known:
        K = tf.make_transform(model.marker_rotation(C, fit.M, B[:, :3, :3]), K[:3, 3])
    if noise is None:
        noise = _noise_at(fit, C, K, theta, free)
    prob, _ = fit.problem(C, K, noise, free)
    errors, predicted = model.leave_one_out(prob, C, K, theta, noise.point_cov(fit.shape, fit.cofactor(C, K)))
    return _consistency(fit, prob, C, K, theta, errors, predicted)


def _consistency(fit, prob, C, K, theta, errors, predicted) -> dict:
    """`self_check`'s numbers from the fitted problem and its leave-one-out errors / predicted RMS."""
    p = prob.p
    r = prob.raw(C, K, theta)[0]          # p minus the prediction (at the fit's estimate: evaluated already)
    d2 = float(np.sum(_whitened_squares(fit.shape_whitener, r)))
    dof = max(3 * len(p) - prob.n_params, 1)
    p_value = float(chdtrc(dof, d2))           # chi2.sf(d2, dof) without scipy.stats' ~35 us of argument handling
    obs = float(np.sqrt(np.mean(errors**2)))
    pre = float(np.sqrt(np.mean(predicted**2)))
    ratio = obs / pre if pre > 0 else float("inf")
    warning = None
    if not (1.0 / LOO_TOLERANCE <= ratio <= LOO_TOLERANCE):
        worse = "larger" if ratio > 1 else "smaller"
        warning = (f"held-out samples are predicted to {obs * 1e3:.2f} mm, {ratio:.2f}x {worse} than the "
                   f"{pre * 1e3:.2f} mm the model expects: the stated uncertainty is not trustworthy "
                   "(unmodelled error or outliers); add samples or check the cell")
    return {
        "chi2": d2,
        "dof": int(dof),
        "p_value": p_value,
        "prior_model_rejected": bool(p_value < CHI2_ALPHA),
        "loo_observed_m": obs,
        "loo_predicted_m": pre,
        "loo_ratio": ratio,
        "loo_errors_m": errors,
        "consistent": warning is None,
        "warning": warning,
    }


def report(result: CalibrationResult) -> dict | None:
    """The model and self-check part of a result, JSON-ready with units in the keys (for result.yaml, the CLI).

    Returns None when the result carries neither (e.g. the online estimator's).
    Camera correction: depth and focal scale in %, depth offset in mm (value,
    1-sigma, whether estimated) and the misfit (mm) of its rigid stand-in
    (`CalibrationResult.camera_transform_raw_points`); noise levels: camera point covariance scale,
    robot flange error (mm), marker orientation (deg); self-check: chi-square
    against the camera's a-priori model and the held-out (leave-one-out)
    prediction error of the marker point, observed and predicted (mm);
    blocked folds (from `MIN_SAMPLES_BLOCKED` samples): each candidate
    model's error on the contiguous stretches held out (mm) and what decided.
    """
    info = result.info
    check = info.get("self_check")
    if check is None and "camera_correction" not in info:
        return None
    out: dict = {}
    if "measurements" in info:
        out["measurements"] = list(info["measurements"])
    if "camera_correction" in info:
        unit = {"depth_scale": ("depth_scale_percent", 100.0), "depth_offset": ("depth_offset_mm", 1e3),
                "focal_scale": ("focal_scale_percent", 100.0)}
        out["camera_correction"] = {
            unit[name][0]: {"value": c["value"] * unit[name][1], "sigma": c["sigma"] * unit[name][1],
                            "estimated": c["estimated"]}
            for name, c in info["camera_correction"].items()
        }
    if result.raw_points_fit is not None:
        # How far the rigid stand-in for the correction (what a URDF or tf carries) is from the correction itself.
        out["raw_points_misfit_mm"] = result.raw_points_fit["misfit_m"] * 1e3
    if "noise" in info:
        n = info["noise"]
        out["noise"] = {"camera_point_scale": n["point_scale"], "robot_mm": n["robot_m"] * 1e3,
                        "marker_rotation_deg": None if n["rotation_rad"] is None else float(np.rad2deg(n["rotation_rad"]))}
    if info.get("robot_shared_error_mm") is not None:
        # The 1-sigma of the camera translation that the robot's shared (kinematic) error adds.
        out["robot_shared_error_mm"] = info["robot_shared_error_mm"]
    if check is not None:
        out["self_check"] = {
            "chi2": check["chi2"], "dof": check["dof"], "p_value": check["p_value"],
            "camera_noise_model_rejected": check["prior_model_rejected"],
            "heldout_observed_mm": check["loo_observed_m"] * 1e3,
            "heldout_predicted_mm": check["loo_predicted_m"] * 1e3,
            "heldout_ratio": check["loo_ratio"],
            "consistent": check["consistent"],
            "warning": check["warning"],
        }
    blocked = info.get("blocked_folds")
    if blocked:
        out["blocked_folds"] = {
            "folds": blocked["folds"], "chosen_by": blocked["chosen_by"],
            "candidates": [{**{k: v for k, v in c.items() if k != "heldout_m"}, "heldout_mm": c["heldout_m"] * 1e3}
                           for c in blocked["candidates"]]}
    if info.get("notes"):
        out["notes"] = list(info["notes"])
    return out
