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
   scale (`camera_correction`), alternating with the variance-component
   estimate of the noise levels (`calib.model.variance_components`).
4. Camera parameters the motions do not determine (from the information
   matrix: their 1-sigma would exceed `IDENTIFIABLE_SIGMA`) stay at nominal
   (zero), with a message naming the motion that would fix it.
5. Self-check (`self_check`): chi-square of the residuals against the
   camera's a-priori noise model, and the linearised leave-one-out
   prediction error of the marker point beside the predicted one.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from calib import model
from calib import transforms as tf
from calib.errors import CalibrationError, InsufficientDataError
from calib.result import CalibrationResult, Residuals

#: Allowed values of ``camera_correction``.
CAMERA_CORRECTIONS = ("auto", "none", "depth", "depth+focal")
#: A camera parameter is estimated only if the data determine it to this 1-sigma
#: (a quarter of the systematic error a structured-light camera has before an
#: infield correction: 2% scale, 8 mm offset, 2% focal).
IDENTIFIABLE_SIGMA = {"depth_scale": 0.005, "depth_offset": 0.002, "focal_scale": 0.005}
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


def _free_for(mode: str) -> tuple[bool, bool, bool]:
    return {"none": (False, False, False), "depth": (True, True, False)}.get(mode, (True, True, True))


class _Fit:
    """State of the extended fit: transforms, camera error, noise levels and the problem."""

    def __init__(self, A, B, setup, shape, use_rotation):
        self.setup = setup
        self.A, self.B = A, B
        self.shape = shape
        self.use_rotation = use_rotation
        self.M = model.split(np.eye(4), np.eye(4), A, setup)[2]

    def problem(self, C, K, noise, free):
        cof = model.robot_cofactor(C, K, self.M, self.setup)
        W = model.whitener(noise.point_cov(self.shape, cof))
        return model.Problem(self.M, self.B, W, sigma_rot=noise.rotation, free=free,
                             use_rotation=self.use_rotation), cof

    def run(self, C, K, theta, noise, free, estimate):
        """Alternate LM and variance components until the noise levels settle."""
        iters, converged = 0, True
        for _ in range(MAX_ROUNDS):
            prob, cof = self.problem(C, K, noise, free)
            C, K, theta, _, it, converged = model.minimize(prob, C, K, theta, max_iterations=50)
            iters += it
            prob, cof = self.problem(C, K, noise, free)
            new, shares = model.variance_components(prob, C, K, theta, self.shape, cof, noise, estimate=estimate)
            change = max(abs(new.point_scale / noise.point_scale - 1), abs(new.robot / max(noise.robot, 1e-12) - 1),
                         0.0 if new.rotation is None else abs(new.rotation / noise.rotation - 1))
            noise = new
            if change < 0.01:
                break
        prob, _ = self.problem(C, K, noise, free)
        return C, K, theta, noise, prob, iters, converged


def _start(A, B, setup, use_rotation):
    """Closed-form candidates and the one with the smallest median point residual."""
    from calib.api import closed_form

    names = ["YKronT'"] + (["YQuatT'", "YKronRT"] if use_rotation else [])
    best, best_med, tried = None, np.inf, []
    for name in names:
        try:
            res = closed_form(name, A, B, setup=setup)
        except CalibrationError:
            continue
        med = float(np.median(res.residuals.translation))
        tried.append((name, med))
        if med < best_med:
            best, best_med = res, med
    if best is None:
        raise InsufficientDataError("no closed-form start could be computed for these samples")
    return best, tried


def _needs_robust(start: CalibrationResult, A, p, shape) -> bool:
    """Whether the start's whitened point residuals show outliers at a robust (median) scale."""
    C, K, M = model.split(start.X, start.Y, A, start.setup)
    r = model.point_residuals(C, K[:3, 3], M, p)[0]
    d2 = np.einsum("ni,nij,nj->n", r, np.linalg.inv(shape), r)
    scale = np.median(d2) / chi2.ppf(0.5, 3)
    return bool(np.any(d2 > chi2.ppf(0.9999, 3) * scale * 4.0))


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
               rng: np.random.Generator | None = None) -> CalibrationResult:
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
        ``self_check`` (see `self_check`), ``cov_kind`` "fisher-extended".
    """
    from calib.robust import robust_solve
    from calib.symmetry import resolve_flips

    if camera_correction not in CAMERA_CORRECTIONS:
        raise CalibrationError(f"camera_correction must be one of {', '.join(CAMERA_CORRECTIONS)}, got {camera_correction!r}")
    n = len(A)
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
    if robust and n >= 8 and _needs_robust(start, A, p, shape):
        from calib.api import closed_form

        name = start.method
        hyp = robust_solve(lambda a, b: closed_form(name, a, b, setup=setup), A, B, setup=setup, point_cov=point_cov,
                           rng=rng if rng is not None else np.random.default_rng(0))
        inliers = hyp.inliers
        start = hyp
    A_in, B_in, shape_in = A[inliers], B[inliers], shape[inliers]
    fit = _Fit(A_in, B_in, setup, shape_in, use_rotation)
    C, K, _ = model.split(start.X, start.Y, A_in, setup)
    if use_rotation and not start.marker_rotation_known:
        K = tf.make_transform(model.marker_rotation(C, fit.M, B_in[:, :3, :3]), K[:3, 3])
    theta = np.zeros(3)
    # Initial levels: the camera model at its own scale from the start's residual, a small robot error.
    noise = _initial_noise(C, K, fit.M, p[inliers], shape_in, B_in[:, :3, :3] if use_rotation else None)
    estimate = (True, True, True)
    C, K, theta, noise, prob, iters, converged = fit.run(C, K, theta, noise, (False, False, False), estimate)

    # Camera parameters, forward selection in the order of how common the error is (depth scale,
    # depth offset, focal): a parameter joins if, with it, every chosen one stays determined.
    wanted = _free_for(camera_correction) if camera_correction != "none" else (False, False, False)
    free = np.zeros(3, dtype=bool)
    for k, name in enumerate(model.CAMERA_PARAMS):
        if not wanted[k]:
            continue
        trial = free.copy()
        trial[k] = True
        cand, _ = fit.problem(C, K, noise, trial)
        sigmas = identifiability(model.information(cand, C, K, theta), trial, cand.n_pose)
        if all(v <= IDENTIFIABLE_SIGMA[n] for n, v in sigmas.items()):
            free = trial
        else:
            notes.append(f"{name} is not determined by these motions (1-sigma {_fmt(name, sigmas[name])}"
                         f"{'' if sigmas[name] > IDENTIFIABLE_SIGMA[name] else ' with the others'}); "
                         f"kept at nominal: {_MOTION_HINT[name]}")
    if free.any():
        C, K, theta, noise, prob, it2, converged = fit.run(C, K, theta, noise, tuple(free), estimate)
        iters += it2
    info_mat = model.information(prob, C, K, theta)
    full_cov = np.linalg.inv(info_mat)
    cov = model.camera_block(info_mat)
    sig_theta = np.zeros(3)
    sig_theta[free] = np.sqrt(np.diag(full_cov)[prob.n_pose:])
    correction = {
        name: {"value": float(theta[i]), "sigma": float(sig_theta[i]), "estimated": bool(free[i])}
        for i, name in enumerate(model.CAMERA_PARAMS)
    }
    X, Y = model.join(C, K, setup)
    check = self_check(X, Y, A_in, B_in, setup=setup, point_cov=shape_in, noise=noise, theta=theta, free=free,
                       use_rotation=use_rotation)
    if check["warning"]:
        notes.append(check["warning"])
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
            "noise": {"point_scale": noise.point_scale, "robot_m": noise.robot, "rotation_rad": noise.rotation},
            "self_check": check,
            "notes": notes,
            "flips": flips,
            "cov_kind": "fisher-extended",
            "cost": float(prob.cost(C, K, theta)),
        },
    )


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


def _initial_noise(C, K, M, p, shape, R_B) -> model.NoiseLevels:
    """Starting noise levels: the camera model at the scale of the residuals, a small robot error."""
    r0 = model.point_residuals(C, K[:3, 3], M, p)[0]
    d2 = np.einsum("ni,nij,nj->n", r0, np.linalg.inv(shape), r0)
    rot0 = None
    if R_B is not None:
        e0 = model.rotation_residuals(C, K, M, R_B)[0]
        rot0 = max(float(np.sqrt(np.mean(e0**2))), 1e-4)
    return model.NoiseLevels(point_scale=max(float(np.mean(d2)) / 3.0, model.MIN_POINT_SCALE),
                             robot=ROBOT_SIGMA_START, rotation=rot0)


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
        p = B if B.ndim == 2 else B[:, :3, 3]
        noise = _initial_noise(C, K, fit.M, p, shape, B[:, :3, :3] if use_rotation else None)
        for _ in range(MAX_ROUNDS):
            prob, cof = fit.problem(C, K, noise, free)
            new, _ = model.variance_components(prob, C, K, theta, shape, cof, noise)
            settled = abs(new.point_scale / noise.point_scale - 1) < 0.01 and abs(new.robot / noise.robot - 1) < 0.01
            noise = new
            if settled:
                break
    prob, _ = fit.problem(C, K, noise, free)
    p = prob.p
    pred = model.predict_points(C, K[:3, 3], prob.M, theta)
    r = p - pred
    d2 = float(np.einsum("ni,nij,nj->", r, np.linalg.inv(fit.shape), r))
    dof = max(3 * len(p) - prob.n_params, 1)
    p_value = float(chi2.sf(d2, dof))
    cof = model.robot_cofactor(C, K, prob.M, fit.setup)
    errors, predicted = model.leave_one_out(prob, C, K, theta, noise.point_cov(fit.shape, cof))
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
