"""How far to trust a calibration: noise levels at an estimate and the self-check of any method's result.

Works for any estimate ``(X, Y)`` of paper eq. 1 ``A_i X = Y B_i`` (eye-to-hand
``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand ``X = T_flange_cam``,
``Y = T_base_marker``) under the extended measurement model of `handeye.calib.model`.
"""

from __future__ import annotations

import numpy as np
from scipy.special import chdtrc

from handeye.calib import model
from handeye.calib import transforms as tf
from handeye.calib.problem import CalibrationProblem
from handeye.calib.result import SelfCheck

#: Held-out prediction error may differ from the predicted one by this factor before we warn.
LOO_TOLERANCE = 1.5
#: p-value below which the residuals reject the camera's a-priori noise model.
CHI2_ALPHA = 0.001
#: Noise level of the robot before it is estimated (m): a UR10's repeatability order.
ROBOT_SIGMA_START = 2e-4
#: Rounds of the noise-level estimate at a fixed estimate (3% change is plenty for a self-check).
CHECK_ROUNDS = 5


def initial_noise(d2, C, K, M, R_B) -> model.NoiseLevels:
    """Starting noise levels: the camera model at the scale of the whitened squared point residuals ``d2``
    (`handeye.calib.model.point_d2`), a small robot error, and the orientation residuals' RMS for pose data ``R_B``."""
    rot0 = None
    if R_B is not None:
        e0 = model.rotation_residuals(C, K, M, R_B)[0]
        rot0 = max(float(np.sqrt(np.mean(e0**2))), 1e-4)
    return model.NoiseLevels(point_scale=max(float(np.mean(d2)) / 3.0, model.MIN_POINT_SCALE),
                             robot=ROBOT_SIGMA_START, rotation=rot0)


def noise_at(data: model.WeightedData, C, K, theta, free) -> model.NoiseLevels:
    """Variance components of ``data`` at a fixed estimate ``(C, K, theta)`` (no refit)."""
    noise = initial_noise(model.point_d2(C, K, data.M, data.points, data.shape_whitener), C, K, data.M,
                          data.B[:, :3, :3] if data.use_rotation else None)
    for _ in range(CHECK_ROUNDS):
        # Fixed estimate: the robot cofactor and the Jacobians are computed once (`handeye.calib.model.WeightedData`).
        prob, cof = data.linearize(C, K, noise, free)
        new, _ = model.variance_components(prob, C, K, theta, data.shape, cof, noise)
        settled = abs(new.point_scale / noise.point_scale - 1) < 0.03 and abs(new.robot / noise.robot - 1) < 0.03
        noise = new
        if settled:
            break
    return noise


def _weighted_at(X, Y, problem: CalibrationProblem, use_rotation: bool, marker_rotation_known: bool):
    """The problem's weighted data with ``(C, K)`` at ``(X, Y)``; a point-only estimate's marker rotation fitted to the poses."""
    shape, _ = model.point_shape(problem.B, problem.point_cov)
    data = model.WeightedData(problem.A, problem.B, problem.setup, shape, use_rotation)
    C, K, _ = model.split(X, Y, problem.A, problem.setup)
    if use_rotation and not marker_rotation_known:
        K = tf.make_transform(model.marker_rotation(C, data.M, problem.marker_rotations), K[:3, 3])
    return data, C, K


def estimate_noise(X, Y, problem: CalibrationProblem, *, marker_rotation_known: bool = True) -> model.NoiseLevels:
    """Noise levels (`handeye.calib.model.NoiseLevels`) of the data at a given estimate, e.g. a closed form's.

    The variance components of `handeye.calib.model.variance_components` at ``(X, Y)``
    held fixed, no camera correction. Orientations are used for pose data;
    with ``marker_rotation_known`` False (a point-only estimate) the
    marker-side rotation is first fitted to them.
    """
    data, C, K = _weighted_at(X, Y, problem, problem.has_poses, marker_rotation_known)
    return noise_at(data, C, K, np.zeros(3), (False, False, False))


def self_check(X, Y, problem: CalibrationProblem, *, noise: model.NoiseLevels | None = None, theta=None,
               free=(False, False, False), use_rotation: bool | None = None,
               marker_rotation_known: bool = True) -> SelfCheck:
    """Consistency of a calibration with the measurement model, in numbers and plain words.

    - ``chi2``/``dof``/``p_value``: the point residuals whitened by the
      camera's a-priori covariance (the problem's ``point_cov``, else the depth
      model of `handeye.calib.noise`) with no robot error: a small p-value
      (``prior_model_rejected``) says the camera noise alone does not explain
      the residuals (the robot or a systematic error does).
    - ``loo_observed_m`` / ``loo_predicted_m``: RMS leave-one-out prediction
      error of the marker point (linearised, `handeye.calib.model.leave_one_out`)
      and the RMS the model predicts for it with the noise levels ``noise``
      (estimated from the residuals at ``(X, Y)`` when not given);
      ``loo_ratio`` is observed / predicted. Outside ``1 / LOO_TOLERANCE ..
      LOO_TOLERANCE`` the ``warning`` says so in plain words.

    Parameters
    ----------
    X, Y : ndarray, shape (4, 4)
    problem : CalibrationProblem
    noise : handeye.calib.model.NoiseLevels, optional
    theta : array_like, shape (3,), optional
        Camera correction (`handeye.calib.model.CAMERA_PARAMS`), zero by default.
    free : sequence of 3 bool
        Which camera parameters were estimated (they count as unknowns).
    use_rotation : bool, optional
        Use the orientation residual of pose data (default: when the problem has poses).
    marker_rotation_known : bool
        False for a point-only estimate: the marker-side rotation is then
        taken as the best fit to the poses.

    Raises
    ------
    InsufficientDataError
        Too few samples to hold one out.
    """
    use_rotation = problem.has_poses if use_rotation is None else use_rotation and problem.has_poses
    theta = np.zeros(3) if theta is None else np.asarray(theta, dtype=float)
    data, C, K = _weighted_at(X, Y, problem, use_rotation, marker_rotation_known)
    if noise is None:
        noise = noise_at(data, C, K, theta, free)
    prob, _ = data.linearize(C, K, noise, free)
    errors, predicted = model.leave_one_out(prob, C, K, theta, noise.point_cov(data.shape, data.cofactor(C, K)))
    return consistency(data, prob, C, K, theta, errors, predicted)


def consistency(data: model.WeightedData, prob: model.Linearization, C, K, theta, errors, predicted) -> SelfCheck:
    """`self_check`'s numbers from the fitted problem and its leave-one-out errors / predicted RMS (m)."""
    r = prob.raw(C, K, theta)[0]          # p minus the prediction (at the fit's estimate: evaluated already)
    d2 = float(np.sum(model.whitened_squares(data.shape_whitener, r)))
    # A prior's rows count as observations (a held direction is no unknown).
    dof = max(3 * len(prob.p) + (0 if prob.prior is None else len(prob.prior.rows)) - prob.n_params, 1)
    p_value = float(chdtrc(dof, d2))           # chi2.sf(d2, dof) without scipy.stats' argument handling
    obs = float(np.sqrt(np.mean(errors**2)))
    pre = float(np.sqrt(np.mean(predicted**2)))
    ratio = obs / pre if pre > 0 else float("inf")
    warning = None
    if not (1.0 / LOO_TOLERANCE <= ratio <= LOO_TOLERANCE):
        worse = "larger" if ratio > 1 else "smaller"
        warning = (f"held-out samples are predicted to {obs * 1e3:.2f} mm, {ratio:.2f}x {worse} than the "
                   f"{pre * 1e3:.2f} mm the model expects: the stated uncertainty is not trustworthy "
                   "(unmodelled error or outliers); add samples or check the cell")
    return SelfCheck(chi2=d2, dof=int(dof), p_value=p_value, prior_model_rejected=bool(p_value < CHI2_ALPHA),
                     loo_observed_m=obs, loo_predicted_m=pre, loo_ratio=ratio, loo_errors_m=errors, warning=warning)
