"""Forward and analytic inverse kinematics of Universal Robots arms.

Pure numpy, no I/O: the UR driver uses it to check joint limits and the path
of a motion *before* anything is sent, and the simulated controller
(``handeye.mocks.ur_sim``) uses it to move. Poses are ``T_base_flange`` (4x4, m): the
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

import math
from dataclasses import dataclass

import numpy as np

from handeye.calib.errors import ParameterError
from handeye.calib.robot_error import UR10_DH, UR_ALPHA, ur_forward
from handeye.drivers.errors import DeviceError

_ALPHA_T = tuple(UR_ALPHA.tolist())


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

    @classmethod
    def from_dh(cls, dh: dict) -> "URGeometry":
        """The lengths of a standard-DH table (``d``, ``a`` (6,) each, as `handeye.calib.robot_error.UR10_DH`)."""
        d, a = dh["d"], dh["a"]
        return cls(float(d[0]), float(a[1]), float(a[2]), float(d[3]), float(d[4]), float(d[5]))


# Universal Robots, "DH parameters for calculations of kinematics and dynamics".
UR_MODELS: dict[str, URGeometry] = {
    "ur3": URGeometry(0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819),
    "ur5": URGeometry(0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823),
    "ur10": URGeometry.from_dh(UR10_DH),   # (calib keeps the UR10 table: its simulations use it)
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
        raise ParameterError(f"model: unknown UR model {model!r}; known: {sorted(UR_MODELS)}")
    return UR_MODELS[key]


def check_q(q, name: str = "q") -> np.ndarray:
    """Validate joint vector(s) ``(..., 6)`` in rad, finite."""
    q = np.asarray(q, dtype=float)
    if q.shape[-1:] != (6,):
        raise DeviceError(f"{name} must have shape (..., 6), got {q.shape}")
    if not np.isfinite(q).all():
        raise DeviceError(f"{name} contains NaN or inf")
    return q


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
    return ur_forward(flat, g.d, g.a, UR_ALPHA, np.zeros(6)).reshape(q.shape[:-1] + (4, 4))


def forward_one(q, model: str | URGeometry) -> np.ndarray:
    """`forward` of a single joint vector (6,), without validation: the simulator's per-tick path."""
    g = model if isinstance(model, URGeometry) else geometry(model)
    return np.array(_fk(q, g) + (0.0, 0.0, 0.0, 1.0)).reshape(4, 4)


# Scalar affine algebra on row-major 3x4 tuples (the top rows of a 4x4 transform): the IK runs
# at every control tick of the simulator and at every sample of a path check, where numpy's
# per-call overhead on 4x4 arrays outweighs the arithmetic (docs/benchmarks-history.md,
# handeye.drivers.robot.ur_kinematics).
def _dh1(theta: float, d: float, a: float, alpha: float) -> tuple:
    ct, st = math.cos(theta), math.sin(theta)
    ca, sa = math.cos(alpha), math.sin(alpha)
    return (ct, -st * ca, st * sa, a * ct, st, ct * ca, -ct * sa, a * st, 0.0, sa, ca, d)


def _mul(A: tuple, B: tuple) -> tuple:
    a0, a1, a2, a3, a4, a5, a6, a7, a8, a9, a10, a11 = A
    b0, b1, b2, b3, b4, b5, b6, b7, b8, b9, b10, b11 = B
    return (a0 * b0 + a1 * b4 + a2 * b8, a0 * b1 + a1 * b5 + a2 * b9, a0 * b2 + a1 * b6 + a2 * b10,
            a0 * b3 + a1 * b7 + a2 * b11 + a3,
            a4 * b0 + a5 * b4 + a6 * b8, a4 * b1 + a5 * b5 + a6 * b9, a4 * b2 + a5 * b6 + a6 * b10,
            a4 * b3 + a5 * b7 + a6 * b11 + a7,
            a8 * b0 + a9 * b4 + a10 * b8, a8 * b1 + a9 * b5 + a10 * b9, a8 * b2 + a9 * b6 + a10 * b10,
            a8 * b3 + a9 * b7 + a10 * b11 + a11)


def _inv(A: tuple) -> tuple:
    r0, r1, r2, x, r4, r5, r6, y, r8, r9, r10, z = A
    return (r0, r4, r8, -(r0 * x + r4 * y + r8 * z), r1, r5, r9, -(r1 * x + r5 * y + r9 * z),
            r2, r6, r10, -(r2 * x + r6 * y + r10 * z))


def _fk(q, g: URGeometry) -> tuple:
    d, a = (g.d1, 0.0, 0.0, g.d4, g.d5, g.d6), (0.0, g.a2, g.a3, 0.0, 0.0, 0.0)
    T = _dh1(float(q[0]), d[0], a[0], _ALPHA_T[0])
    for i in range(1, 6):
        T = _mul(T, _dh1(float(q[i]), d[i], a[i], _ALPHA_T[i]))
    return T


def _clip1(x: float) -> float:
    return -1.0 if x < -1.0 else 1.0 if x > 1.0 else x


def _wrap(x: float) -> float:
    """Angle wrapped to (-pi, pi]."""
    return math.atan2(math.sin(x), math.cos(x))


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
    d1, a2, a3, d4, d5, d6 = g.d1, g.a2, g.a3, g.d4, g.d5, g.d6
    Tt = tuple(T[:3].ravel().tolist())
    nx, ox, ax, px, ny, oy, ay, py = Tt[:8]
    p05x, p05y = px - d6 * ax, py - d6 * ay
    r = math.hypot(p05x, p05y)
    if r < abs(d4):
        return np.zeros((0, 6))
    psi = math.atan2(p05y, p05x)
    phi = math.acos(_clip1(d4 / r))
    sols = []
    for q1 in (psi + phi + math.pi / 2, psi - phi + math.pi / 2):
        s1, c1 = math.sin(q1), math.cos(q1)
        c5 = (px * s1 - py * c1 - d4) / d6
        if abs(c5) > 1.0 + 1e-9:
            continue
        T01_inv = _inv(_dh1(q1, d1, 0.0, math.pi / 2))
        for q5 in (math.acos(_clip1(c5)), -math.acos(_clip1(c5))):
            s5 = math.sin(q5)
            # T60 entries are the transposed rotation of T: T60[1,0] = ox, T60[0,1] = ny.
            q6 = 0.0 if abs(s5) < 1e-9 else math.atan2((-ox * s1 + oy * c1) / s5, (nx * s1 - ny * c1) / s5)
            T14 = _mul(_mul(T01_inv, Tt), _inv(_mul(_dh1(q5, d5, 0.0, -math.pi / 2), _dh1(q6, d6, 0.0, 0.0))))
            x13 = T14[3] - d4 * T14[1]  # T14 @ [0, -d4, 0, 1]
            y13 = T14[7] - d4 * T14[5]
            n13 = math.hypot(x13, y13)
            c3 = (n13 * n13 - a2 * a2 - a3 * a3) / (2 * a2 * a3)
            if abs(c3) > 1.0 + 1e-9:
                continue
            for q3 in (math.acos(_clip1(c3)), -math.acos(_clip1(c3))):
                q2 = -math.atan2(y13, -x13) + math.asin(_clip1(a3 * math.sin(q3) / n13))
                T34 = _mul(_inv(_mul(_dh1(q2, 0.0, a2, 0.0), _dh1(q3, 0.0, a3, 0.0))), T14)
                q = tuple(_wrap(x) for x in (q1, q2, q3, math.atan2(T34[4], T34[0]), q5, q6))
                if max(abs(u - v) for u, v in zip(_fk(q, g), Tt)) < tol:
                    sols.append(q)
    return np.array(sols) if sols else np.zeros((0, 6))


# The three singularities of the UR geometry, as distances from them (see `singularity_margins`).
SINGULARITIES = ("wrist", "elbow", "shoulder")
# Below these margins a controller cannot follow a straight TCP line (joint speeds blow up):
# the simulated controller protective-stops there, like a real one. The driver refuses paths
# that come closer than `SINGULARITY_REFUSE` (larger, so that its samples between the
# controller's own cannot hide a dip below `SINGULARITY_STOP`).
SINGULARITY_STOP = np.array([0.05, 0.05, 0.03])  # |sin q5|, |sin q3|, m
SINGULARITY_REFUSE = np.array([0.12, 0.12, 0.08])


def singularity_margins(q, model: str | URGeometry) -> np.ndarray:
    """How far joint vector ``q`` (6,) is from each UR singularity, in the order of `SINGULARITIES`.

    - wrist: ``|sin q5|`` (joint 4 and 6 axes align at 0);
    - elbow: ``|sin q3|`` (arm stretched or folded at 0);
    - shoulder: ``sqrt(r^2 - d4^2)`` (m), where ``r`` is the horizontal distance of the
      wrist point (flange minus ``d6`` along its z axis) from the base z axis; at 0 the
      wrist point lies on the plane of the joint 1 and 2 axes and the two shoulder
      solutions of the IK merge.

    Returns
    -------
    margins : ndarray, shape (3,)
    """
    g = model if isinstance(model, URGeometry) else geometry(model)
    T = _fk(q, g)
    px, py = T[3] - g.d6 * T[2], T[7] - g.d6 * T[6]
    return np.array([abs(math.sin(q[4])), abs(math.sin(q[2])), math.sqrt(max(px * px + py * py - g.d4 * g.d4, 0.0))])


def inverse_nearest(T_base_flange, q_near, model: str | URGeometry, limits=UR_JOINT_LIMITS) -> np.ndarray | None:
    """The IK solution closest to ``q_near`` (max joint distance) within ``limits``.

    Each joint may be shifted by multiples of 2 pi to come closest to
    ``q_near``; a solution is kept only if every joint then lies inside
    ``limits`` (shape (6, 2), rad).

    Returns
    -------
    q : ndarray, shape (6,), or None when no solution is reachable within the limits.
    """
    return nearest_solution(inverse_all(T_base_flange, model), q_near, limits)


def nearest_solution(solutions: np.ndarray, q_near, limits=UR_JOINT_LIMITS) -> np.ndarray | None:
    """`inverse_nearest` on the solutions (K, 6) of `inverse_all` (computed once, chosen from many ``q_near``)."""
    q_near = check_q(q_near, "q_near").tolist()
    lims = np.asarray(limits, dtype=float).tolist()
    best, best_cost = None, math.inf
    for sol in solutions.tolist():
        # Each joint: the 2-pi multiple nearest q_near among those inside the limits.
        q, cost = [], 0.0
        for x, near, (lo, hi) in zip(sol, q_near, lims):
            pick, dist = None, math.inf
            for k in (-2, -1, 0, 1, 2):
                c = x + 2 * math.pi * k
                if lo <= c <= hi and abs(c - near) < dist:
                    pick, dist = c, abs(c - near)
            if pick is None:
                break
            q.append(pick)
            cost = max(cost, dist)
        else:
            if cost < best_cost:
                best, best_cost = q, cost
    return None if best is None else np.array(best)
