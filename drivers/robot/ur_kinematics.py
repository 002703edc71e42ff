"""Forward and analytic inverse kinematics of Universal Robots arms.

Pure numpy, no I/O: the UR driver uses it to check joint limits and the path
of a motion *before* anything is sent, and the simulated controller
(``mocks.ur_sim``) uses it to move. Poses are ``T_base_flange`` (4x4, m): the
flange (tool0) in the robot base frame, TCP offset NOT included.

The DH parameters are Universal Robots' published nominal values (standard
DH, ``T_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``). A real robot carries a
factory calibration that moves the flange by up to a few mm against these, so
the driver uses this module for limit checks, never as the source of truth
for the measured pose (that is the controller's ``actual_TCP_pose``).

The inverse kinematics follows the closed form for the UR geometry
(K. P. Hawkins, "Analytic inverse kinematics for the Universal Robots UR-5/
UR-10 arms", 2013): up to 8 solutions, each verified by forward kinematics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.errors import ConfigError, DeviceError

_ALPHA = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])


@dataclass(frozen=True)
class URGeometry:
    """Nominal DH lengths of one UR model (m); ``a2``, ``a3`` are negative as published."""

    d1: float
    a2: float
    a3: float
    d4: float
    d5: float
    d6: float

    @property
    def d(self) -> np.ndarray:
        return np.array([self.d1, 0.0, 0.0, self.d4, self.d5, self.d6])

    @property
    def a(self) -> np.ndarray:
        return np.array([0.0, self.a2, self.a3, 0.0, 0.0, 0.0])

    @property
    def reach(self) -> float:
        """Upper bound on the flange distance from the shoulder axis, m."""
        return abs(self.a2) + abs(self.a3) + self.d4 + self.d5 + self.d6


# Universal Robots, "DH parameters for calculations of kinematics and dynamics".
UR_MODELS: dict[str, URGeometry] = {
    "ur3": URGeometry(0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819),
    "ur5": URGeometry(0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823),
    "ur10": URGeometry(0.1273, -0.612, -0.5723, 0.163941, 0.1157, 0.0922),
    "ur3e": URGeometry(0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921),
    "ur5e": URGeometry(0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996),
    "ur10e": URGeometry(0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655),
    "ur16e": URGeometry(0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655),
}

# Every UR joint turns +-363 deg mechanically; the controller default is +-360 deg.
UR_JOINT_LIMITS = np.array([[-2 * np.pi, 2 * np.pi]] * 6)


def geometry(model: str) -> URGeometry:
    """DH lengths of ``model`` (case-insensitive, e.g. ``"ur10"``, ``"UR10e"``)."""
    key = str(model).lower().replace("-", "")
    if key not in UR_MODELS:
        raise ConfigError(f"model: unknown UR model {model!r}; known: {sorted(UR_MODELS)}")
    return UR_MODELS[key]


def check_q(q, name: str = "q") -> np.ndarray:
    """Validate joint vector(s) ``(..., 6)`` in rad, finite."""
    q = np.asarray(q, dtype=float)
    if q.shape[-1:] != (6,):
        raise DeviceError(f"{name} must have shape (..., 6), got {q.shape}")
    if not np.isfinite(q).all():
        raise DeviceError(f"{name} contains NaN or inf")
    return q


def _dh(theta: np.ndarray, d: float, a: float, alpha: float) -> np.ndarray:
    """Stack of standard-DH link transforms for angles ``theta`` (N,) -> (N, 4, 4)."""
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    T = np.zeros(theta.shape + (4, 4))
    T[..., 0, 0] = ct
    T[..., 0, 1] = -st * ca
    T[..., 0, 2] = st * sa
    T[..., 0, 3] = a * ct
    T[..., 1, 0] = st
    T[..., 1, 1] = ct * ca
    T[..., 1, 2] = -ct * sa
    T[..., 1, 3] = a * st
    T[..., 2, 1] = sa
    T[..., 2, 2] = ca
    T[..., 2, 3] = d
    T[..., 3, 3] = 1.0
    return T


def forward(q, model: str | URGeometry) -> np.ndarray:
    """Flange pose(s) ``T_base_flange`` of joint vector(s) ``q``.

    Parameters
    ----------
    q : array_like, shape (..., 6)
        Joint angles, rad.
    model : str or URGeometry

    Returns
    -------
    T_base_flange : ndarray, shape (..., 4, 4)
    """
    g = model if isinstance(model, URGeometry) else geometry(model)
    q = check_q(q)
    flat = q.reshape(-1, 6)
    T = np.broadcast_to(np.eye(4), (len(flat), 4, 4)).copy()
    for i in range(6):
        T = T @ _dh(flat[:, i], g.d[i], g.a[i], _ALPHA[i])
    return T.reshape(q.shape[:-1] + (4, 4))


def _inv(T: np.ndarray) -> np.ndarray:
    R = T[:3, :3].T
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = -R @ T[:3, 3]
    return out


def inverse_all(T_base_flange, model: str | URGeometry, *, tol: float = 1e-7) -> np.ndarray:
    """All closed-form IK solutions of one flange pose, each wrapped to (-pi, pi].

    Parameters
    ----------
    T_base_flange : array_like, shape (4, 4)
    model : str or URGeometry
    tol : float
        Solutions whose forward kinematics misses the pose by more than
        ``tol`` (m, and rad on the rotation matrix entries) are dropped.

    Returns
    -------
    q : ndarray, shape (K, 6), K in 0..8
        Empty when the pose is out of reach. At a wrist singularity
        (``sin q5 = 0``) q6 is not determined and 0 is returned for it.
    """
    g = model if isinstance(model, URGeometry) else geometry(model)
    T = np.asarray(T_base_flange, dtype=float)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise DeviceError(f"T_base_flange must be a finite (4, 4) array, got shape {T.shape}")
    d, a = g.d, g.a
    p05 = T @ np.array([0.0, 0.0, -d[5], 1.0])
    r = np.hypot(p05[0], p05[1])
    if r < abs(d[3]):
        return np.zeros((0, 6))
    psi = np.arctan2(p05[1], p05[0])
    phi = np.arccos(np.clip(d[3] / r, -1.0, 1.0))
    T60 = _inv(T)
    sols = []
    for q1 in (psi + phi + np.pi / 2, psi - phi + np.pi / 2):
        s1, c1 = np.sin(q1), np.cos(q1)
        c5 = (T[0, 3] * s1 - T[1, 3] * c1 - d[3]) / d[5]
        if abs(c5) > 1.0 + 1e-9:
            continue
        for q5 in (np.arccos(np.clip(c5, -1, 1)), -np.arccos(np.clip(c5, -1, 1))):
            s5 = np.sin(q5)
            if abs(s5) < 1e-9:
                q6 = 0.0
            else:
                q6 = np.arctan2(
                    (-T60[1, 0] * s1 + T60[1, 1] * c1) / s5,
                    (T60[0, 0] * s1 - T60[0, 1] * c1) / s5,
                )
            T01 = _dh(np.array(q1), d[0], a[0], _ALPHA[0])
            T45 = _dh(np.array(q5), d[4], a[4], _ALPHA[4])
            T56 = _dh(np.array(q6), d[5], a[5], _ALPHA[5])
            T14 = _inv(T01) @ T @ _inv(T45 @ T56)
            p13 = T14 @ np.array([0.0, -d[3], 0.0, 1.0])
            n13 = np.hypot(p13[0], p13[1])
            c3 = (n13**2 - a[1] ** 2 - a[2] ** 2) / (2 * a[1] * a[2])
            if abs(c3) > 1.0 + 1e-9:
                continue
            for q3 in (np.arccos(np.clip(c3, -1, 1)), -np.arccos(np.clip(c3, -1, 1))):
                q2 = -np.arctan2(p13[1], -p13[0]) + np.arcsin(np.clip(a[2] * np.sin(q3) / n13, -1, 1))
                T12 = _dh(np.array(q2), d[1], a[1], _ALPHA[1])
                T23 = _dh(np.array(q3), d[2], a[2], _ALPHA[2])
                T34 = _inv(T12 @ T23) @ T14
                q4 = np.arctan2(T34[1, 0], T34[0, 0])
                sols.append([q1, q2, q3, q4, q5, q6])
    if not sols:
        return np.zeros((0, 6))
    q = np.angle(np.exp(1j * np.asarray(sols)))  # wrap to (-pi, pi]
    err = np.abs(forward(q, g) - T).max(axis=(1, 2))
    return q[err < tol]


def inverse_nearest(T_base_flange, q_near, model: str | URGeometry, limits=UR_JOINT_LIMITS) -> np.ndarray | None:
    """The IK solution closest to ``q_near`` (max joint distance) within ``limits``.

    Each joint may be shifted by multiples of 2 pi to come closest to
    ``q_near``; a solution is kept only if every joint then lies inside
    ``limits`` (shape (6, 2), rad).

    Returns
    -------
    q : ndarray, shape (6,), or None when no solution is reachable within the limits.
    """
    q_near = check_q(q_near, "q_near")
    limits = np.asarray(limits, dtype=float)
    best, best_cost = None, np.inf
    for q in inverse_all(T_base_flange, model):
        # Each joint: the 2-pi multiple nearest q_near among those inside the limits.
        cand = q[None, :] + 2 * np.pi * np.arange(-2, 3)[:, None]
        ok = (cand >= limits[:, 0]) & (cand <= limits[:, 1])
        if not ok.any(axis=0).all():
            continue
        dist = np.where(ok, np.abs(cand - q_near), np.inf)
        shifted = cand[np.argmin(dist, axis=0), np.arange(6)]
        cost = np.max(np.abs(shifted - q_near))
        if cost < best_cost:
            best, best_cost = shifted, cost
    return best
