"""Residuals of a sample and their Jacobians: the marker point (paper eq. 5 in the camera frame), the
marker orientation (eq. 4), and the robot pose error carried into the point (`robot_cofactor`)."""

from __future__ import annotations

import numpy as np

from handeye.calib import transforms as tf
from handeye.calib.model.correction import measure, measured_points
from handeye.calib.model.rows import COL, ROW
from handeye.calib.setup import Setup


#: Flange rotation error per unit of flange translation error of the robot
#: (rad per m). A UR10's joint zero offsets of 0.01-0.05 deg move the flange
#: by ~0.2-1 mm at 1.2 m reach and turn it by the same order in mrad, so 1.
ROBOT_ROTATION_PER_M = 1.0


def point_residuals(C, t_K, M, p):
    """Translation residuals ``r`` (N, 3) = p - predicted (no camera error), and Jacobians (N, 3, 3) each.

    Returns ``r, J_dC, J_tC, J_tK``: derivatives of ``r`` w.r.t. the left
    rotation perturbation of C, the translation of C and the translation of K.
    """
    R_C, t_C = C[:3, :3], C[:3, 3]
    w = M[:, :3, :3] @ t_K + M[:, :3, 3] - t_C          # marker center minus camera origin, C's parent frame
    r = p - w @ R_C                                      # w @ R_C == (R_C^T w_i)_i
    J_dC = -(R_C.T @ tf.skew(w))
    J_tC = np.broadcast_to(R_C.T, J_dC.shape)
    J_tK = -(R_C.T @ M[:, :3, :3])
    return r, J_dC, J_tC, J_tK


def predict_points(C, t_K, M, theta=None) -> np.ndarray:
    """Predicted measured marker points (N, 3) in the camera frame, camera error ``theta`` applied."""
    R_C, t_C = C[:3, :3], C[:3, 3]
    p = (M[:, :3, :3] @ t_K + M[:, :3, 3] - t_C) @ R_C
    if theta is None or not np.any(theta):
        return p
    return measured_points(p, np.asarray(theta, dtype=float))


def residual_norms(C, K, M, B, theta=None, *, rotation: bool = True):
    """Per-sample residual sizes at ``(C, K, theta)``: translation (N,), m, the distance between the measured
    and the predicted marker point (camera error ``theta`` applied); rotation (N,), rad, the angle of
    ``R_B^T R_C^T R_M R_K`` (paper eq. 4), None for point data ``B`` (N, 3) or without ``rotation``."""
    p = B if B.ndim == 2 else B[:, :3, 3]
    trans = np.linalg.norm(p - predict_points(C, K[:3, 3], M, theta), axis=1)
    if B.ndim == 2 or not rotation:
        return trans, None
    E = np.swapaxes(B[:, :3, :3], 1, 2) @ C[:3, :3].T @ M[:, :3, :3] @ K[:3, :3]
    return trans, np.linalg.norm(tf.so3_log(E), axis=1)


def point_jacobians(C, K, M, theta, setup: str):
    """Predicted measured point and its Jacobians, per sample, for the recursive filter of `handeye.calib.monitor`.

    Returns ``h (N, 3), H_C (N, 3, 6), H_tK (N, 3, 3), H_theta (N, 3, 3), H_xi (N, 3, 6)``:
    the point the camera reports, ``h(R_C^T (R_Mi t_K + t_Mi - t_C); theta)``, and
    its derivatives w.r.t. the camera transform (left perturbation ``[dC, tC]``),
    the marker-side translation, the camera parameters (all of `CAMERA_PARAMS`)
    and a flange-frame twist ``xi = [a, b]`` (rad, m) of the robot pose
    (``A_i Exp(xi)``, as ``robot_shared_error`` of `handeye.calib.auto`). Eye-to-hand
    the twist moves the marker by ``R_A (a x t_K + b)``; eye-in-hand it moves the
    camera, so the base marker seen from the flange moves by ``-(a x y + b)``,
    ``y`` its flange-frame position.
    """
    R_C, t_C = C[:3, :3], C[:3, 3]
    R_M = M[:, :3, :3]
    y = R_M @ K[:3, 3] + M[:, :3, 3]                   # marker center in C's parent frame
    q = (y - t_C) @ R_C                                # == R_C^T (y - t_C): the point without camera error
    h, J_p, J_theta = measure(q, np.zeros(3) if theta is None else np.asarray(theta, dtype=float))
    Rt = R_C.T
    dq = np.empty((len(q), 3, 6))
    dq[:, :, :3] = Rt @ tf.skew(y - t_C)
    dq[:, :, 3:] = -Rt
    dq_tK = Rt @ R_M
    dq_xi = np.empty((len(q), 3, 6))
    if setup == Setup.EYE_TO_HAND:
        dq_xi[:, :, :3] = -(dq_tK @ tf.skew(K[:3, 3]))
        dq_xi[:, :, 3:] = dq_tK
    else:
        dq_xi[:, :, :3] = Rt @ tf.skew(y)
        dq_xi[:, :, 3:] = -Rt
    return h, J_p @ dq, J_p @ dq_tK, J_theta, J_p @ dq_xi


def inv_right_jacobian(e):
    """Inverse right Jacobian of SO(3), ``Log(Exp(e) Exp(d)) = e + Jr^-1(e) d + O(d^2)``; e (N, 3)."""
    th = np.linalg.norm(e, axis=1)
    S = tf.skew(e)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    c = np.where(small, 1.0 / 12.0, 1.0 / ths**2 - (1.0 + np.cos(ths)) / (2.0 * ths * np.sin(ths)))
    return np.eye(3) + 0.5 * S + c[:, None, None] * (S @ S)


def rotation_residuals(C, K, M, R_B):
    """Rotation residuals ``e`` (N, 3) = Log(R_B^T R_C^T R_M R_K) and Jacobians w.r.t. dC, dK (N, 3, 3)."""
    R_C, R_K, R_M = C[:3, :3], K[:3, :3], M[:, :3, :3]
    E = np.swapaxes(R_B, 1, 2) @ R_C.T @ R_M @ R_K
    e = tf.so3_log(E)
    Jinv = inv_right_jacobian(e)
    J_dK = Jinv @ R_K.T
    J_dC = -(J_dK @ np.swapaxes(R_M, 1, 2))
    return e, J_dC, J_dK


def robot_cofactor(C, K, M, setup: str) -> np.ndarray:
    """Camera-frame covariance (N, 3, 3) of the predicted marker point per unit robot variance ``sigma_R^2``.

    The flange pose is ``A_i Exp([a, b])`` (flange frame), ``b ~ N(0, I)``,
    ``a ~ N(0, ROBOT_ROTATION_PER_M^2 I)``. The marker point (eye-to-hand) or
    the inverse flange motion seen from the flange-mounted camera
    (eye-in-hand) moves by ``b + a x l`` (rotated into C's parent frame), with
    ``l`` the lever arm from the flange to the marker, so the covariance is
    ``R_C^T (I + rho^2 [l]x [l]x^T) R_C``.
    """
    R_C = C[:3, :3]
    lever = np.einsum("nij,j->ni", M[:, :3, :3], K[:3, 3])
    if setup != Setup.EYE_TO_HAND:
        lever = lever + M[:, :3, 3]
    # [l]x [l]x^T = |l|^2 I - l l^T, and R^T (a I - l l^T) R = a I - (R^T l)(R^T l)^T.
    rho2 = ROBOT_ROTATION_PER_M**2
    lc = lever @ R_C
    out = lc[:, ROW] * (-rho2 * lc)[:, COL]         # entries of -rho^2 l l^T as rows (N, 9)
    out[:, ::4] += (1.0 + rho2 * np.sum(lc * lc, axis=1))[:, None]
    return out.reshape(-1, 3, 3)
