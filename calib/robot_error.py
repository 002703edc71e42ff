"""A robot's systematic error shared by all samples, for `handeye.calib.auto.solve_auto`'s ``robot_shared_error``.

An arm's kinematic model is never exact (joint zero offsets, link lengths and
twists off by a little): every flange pose it reports is then off by an error
that depends on the joints but comes from the same few parameters for all
samples. Treated as white noise it averages out over the samples, which it
does not; as a factor ``F`` (N, 6, P) (sample ``i``'s true flange pose is
``A_i Exp(F_i z)`` with ``z ~ N(0, I_P)``) it joins the covariance of the
calibration as what it is.

UR arms: standard-DH forward kinematics (`ur_forward`) and the factor of
their DH parameters (`ur_dh_error_factor`). The UR10 table lives here (calib
does not import drivers); `handeye.drivers.robot.ur_kinematics` takes it from `UR10_DH`.
"""

from __future__ import annotations

import numpy as np

from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError

#: Standard-DH twists of every UR model, rad.
UR_ALPHA = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])
#: UR10 nominal standard-DH parameters (Universal Robots' published values): d, a (m), alpha (rad).
UR10_DH = {
    "d": np.array([0.1273, 0.0, 0.0, 0.163941, 0.1157, 0.0922]),
    "a": np.array([0.0, -0.612, -0.5723, 0.0, 0.0, 0.0]),
    "alpha": UR_ALPHA,
}


def ur_forward(q: np.ndarray, d: np.ndarray, a: np.ndarray, alpha: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Standard-DH forward kinematics ``T_base_flange`` (N, 4, 4) of joints ``q`` (N, 6) with zero offsets (6,)."""
    T = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
    for i in range(6):
        th = q[:, i] + offsets[i]
        ct, st, ca, sa = np.cos(th), np.sin(th), np.cos(alpha[i]), np.sin(alpha[i])
        L = np.zeros((len(q), 4, 4))
        L[:, 0, 0], L[:, 0, 1], L[:, 0, 2], L[:, 0, 3] = ct, -st * ca, st * sa, a[i] * ct
        L[:, 1, 0], L[:, 1, 1], L[:, 1, 2], L[:, 1, 3] = st, ct * ca, -ct * sa, a[i] * st
        L[:, 2, 1], L[:, 2, 2], L[:, 2, 3] = sa, ca, d[i]
        L[:, 3, 3] = 1.0
        T = T @ L
    return T


def ur_dh_error_factor(q, joint_offset_rad: float, link_length_m: float, twist_rad: float,
                       dh: dict | None = None) -> np.ndarray:
    """How a UR's DH errors move its flange poses: the factor ``F`` (N, 6, 24) of ``robot_shared_error``.

    Parameters
    ----------
    q : array_like, shape (N, 6)
        Joint angles of the samples, rad.
    joint_offset_rad, link_length_m, twist_rad : float
        1-sigma of each joint zero offset, each link length ``d`` and ``a``,
        and each twist ``alpha``.
    dh : dict, optional
        Nominal ``d``, ``a``, ``alpha`` (6,) each; `UR10_DH` by default.

    Returns
    -------
    F : ndarray, shape (N, 6, 24)
        Column ``k``: the flange-frame twist (rotation rad, then translation
        m) of every pose when DH parameter ``k`` (offsets, ``d``, ``a``,
        ``alpha``, 6 each) is off by its 1-sigma (central differences).
    """
    dh = UR10_DH if dh is None else dh
    q = tf.as_real_array(q, "q")
    if q.ndim != 2 or q.shape[1] != 6:
        raise CalibrationError(f"q must have shape (N, 6), got {q.shape}")
    nominal = np.r_[np.zeros(6), dh["d"], dh["a"], dh["alpha"]]
    sigma = np.r_[np.full(6, joint_offset_rad), np.full(12, link_length_m), np.full(6, twist_rad)]

    def forward(p):
        return ur_forward(q, p[6:12], p[12:18], p[18:24], p[0:6])

    A_inv = tf.invert(forward(nominal))
    F = np.zeros((len(q), 6, 24))
    h = 1e-6
    for k in np.flatnonzero(sigma):
        step = np.zeros(24)
        step[k] = h
        # A^-1 A(+h) (A^-1 A(-h))^-1 = Exp(2 h twist_k) to first order.
        D = A_inv @ forward(nominal + step) @ tf.invert(A_inv @ forward(nominal - step))
        F[:, :3, k] = tf.so3_log(D[:, :3, :3]) / (2 * h) * sigma[k]
        F[:, 3:, k] = D[:, :3, 3] / (2 * h) * sigma[k]
    return F
