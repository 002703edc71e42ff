"""The measurement model of a hand-eye sample: residual, Jacobian, whitening, information.

One model shared by `handeye.calib.refine` (ML refinement), `handeye.calib.robust` (inlier
test), `handeye.calib.monitor` (the monitoring engine), `handeye.calib.auto` (``solve("auto")``)
and the pose planner (information matrix).

Modules: `handeye.calib.model.frames`, `handeye.calib.model.correction`, `handeye.calib.model.residuals`,
`handeye.calib.model.weights`, `handeye.calib.model.linearization`, `handeye.calib.model.variance`,
`handeye.calib.model.leave_one_out`, `handeye.calib.model.prior` (what the motions leave open, a prior that holds it),
`handeye.calib.model.rows` (batched 3x3 algebra).

Unknowns
--------
Both setups are one model. The camera measures the marker ``B_i = C^-1 M_i K``
(paper eq. 1 ``A_i X = Y B_i`` rearranged), with

- eye-to-hand: ``C = Y = T_base_cam``, ``K = X = T_flange_marker``, ``M_i = A_i``;
- eye-in-hand: ``C = X = T_flange_cam``, ``K = Y = T_base_marker``,
  ``M_i = A_i^-1`` (from ``A_i X B_i = Y``).

Parameter vector (left perturbations as in `handeye.calib.result`, ``R = Exp(d) R_est``,
``t = t_est + dt``): ``[dC, tC, tK]`` for points, ``[dC, tC, dK, tK]`` for
poses, followed by the free camera nuisance parameters (`CAMERA_PARAMS`).

Measurements
------------
- Marker point (always): ``r_i = p_i - h(R_C^T (R_Mi t_K + t_Mi - t_C); theta)``,
  the equation of translation (paper eq. 5) in the camera frame. ``h`` is the
  camera's systematic error (`CameraCorrection`): measured depth
  ``z_m = (1 + s) z + d`` with the point moved along its pixel ray, and a
  lateral scale ``1 + f`` from a focal length error::

      h(p) = diag(1 + f, 1 + f, 1) p (1 + s + d / z)

  With ``theta = 0``, ``h`` is the identity and the model is the paper's.
- Marker orientation (pose data): ``e_i = Log(R_Bi^T R_C^T R_Mi R_K)`` (eq. 4,
  marker frame), noise ``sigma_rot^2 I``.

Noise (errors in variables)
---------------------------
The point residual's covariance is ``Sigma_i = s_p S_i + sigma_R^2 T_i``:

- ``S_i`` the camera's point covariance shape (given ``point_cov``, else the
  depth model of `handeye.calib.noise`), ``s_p`` its scale;
- ``T_i`` the robot pose error propagated through the lever arm of the
  marker (`robot_cofactor`): the flange pose is ``A_i Exp(xi)`` with
  ``xi = [a, b]`` in the flange frame, ``b ~ N(0, sigma_R^2 I)`` (m),
  ``a ~ N(0, (ROBOT_ROTATION_PER_M sigma_R)^2 I)`` (rad).

`variance_components` estimates ``s_p``, ``sigma_R^2`` and ``sigma_rot^2``
from the residuals (Förstner's iterated variance-component estimate, the
Helmert/REML kind: each component's weighted residual square sum divided by
its share of the redundancy).
"""

from handeye.calib.model.frames import join, marker_rotation, split
from handeye.calib.model.correction import CAMERA_PARAMS, CameraCorrection, measure, measured_points
from handeye.calib.model.residuals import (
    ROBOT_ROTATION_PER_M,
    inv_right_jacobian,
    point_jacobians,
    point_residuals,
    predict_points,
    residual_norms,
    robot_cofactor,
    rotation_residuals,
)
from handeye.calib.model.weights import (
    MIN_POINT_SCALE,
    MIN_ROBOT_SIGMA,
    MIN_ROTATION_SIGMA,
    check_point_cov,
    NoiseLevels,
    point_d2,
    point_shape,
    point_weights,
    whitened_squares,
    whitener,
)
from handeye.calib.model.linearization import (
    MIN_INFORMATION_RATIO,
    camera_block,
    information,
    Linearization,
    minimize,
    WeightedData,
)
from handeye.calib.model.prior import HELD_SIGMA_M, TranslationPrior, held_prior, open_translations
from handeye.calib.model.variance import variance_components
from handeye.calib.model.leave_one_out import LEVERAGE_MARGIN, leave_one_out, leave_one_out_after_step

__all__ = [
    "CAMERA_PARAMS",
    "CameraCorrection",
    "HELD_SIGMA_M",
    "LEVERAGE_MARGIN",
    "Linearization",
    "MIN_INFORMATION_RATIO",
    "MIN_POINT_SCALE",
    "MIN_ROBOT_SIGMA",
    "MIN_ROTATION_SIGMA",
    "NoiseLevels",
    "ROBOT_ROTATION_PER_M",
    "TranslationPrior",
    "WeightedData",
    "camera_block",
    "check_point_cov",
    "held_prior",
    "information",
    "inv_right_jacobian",
    "join",
    "leave_one_out",
    "leave_one_out_after_step",
    "marker_rotation",
    "measure",
    "measured_points",
    "minimize",
    "open_translations",
    "point_d2",
    "point_jacobians",
    "point_residuals",
    "point_shape",
    "point_weights",
    "predict_points",
    "residual_norms",
    "robot_cofactor",
    "rotation_residuals",
    "split",
    "variance_components",
    "whitened_squares",
    "whitener",
]
