"""Time-parameterised motions of the simulated UR arm.

Every motion maps the time since its start (s) to joint positions (rad); the
controller differentiates them for speeds. Profiles are trapezoidal (constant
acceleration, cruise, constant deceleration) like the UR controller's
``movej``/``movel``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from handeye.drivers.robot import ur_kinematics as kin

# How far a point 0.1 m off the rotation axis travels counts as path length
# for moveL, so that pure reorientations also get a finite duration.
ROTATION_LEVER_M = 0.1


def trapezoid_duration(distance: float, v: float, a: float) -> float:
    """Duration (s) of a rest-to-rest trapezoidal profile over ``distance``."""
    if distance <= 0.0:
        return 0.0
    if distance <= v * v / a:  # never reaches cruise speed: triangle
        return 2.0 * np.sqrt(distance / a)
    return distance / v + v / a


def trapezoid_position(t: float, distance: float, v: float, a: float) -> float:
    """Distance covered at time ``t`` by the profile of `trapezoid_duration`."""
    T = trapezoid_duration(distance, v, a)
    if t >= T:
        return distance
    if t <= 0.0:
        return 0.0
    if distance <= v * v / a:
        tp = T / 2.0
        return 0.5 * a * t * t if t <= tp else distance - 0.5 * a * (T - t) ** 2
    ta = v / a
    if t <= ta:
        return 0.5 * a * t * t
    if t <= T - ta:
        return 0.5 * a * ta * ta + v * (t - ta)
    return distance - 0.5 * a * (T - t) ** 2


class JointMotion:
    """``movej``: all joints start and stop together; the leading axis obeys v, a."""

    kind = "movej"

    def __init__(self, q0, q1, v: float, a: float):
        self.q0 = np.asarray(q0, dtype=float)
        self.dq = np.asarray(q1, dtype=float) - self.q0
        self.lead = float(np.max(np.abs(self.dq)))
        self.v, self.a = v, a
        self.duration = trapezoid_duration(self.lead, v, a)

    def q_at(self, t: float) -> np.ndarray:
        if self.lead == 0.0:
            return self.q0.copy()
        s = trapezoid_position(t, self.lead, self.v, self.a) / self.lead
        return self.q0 + s * self.dq


def rotvec_to_matrix(w) -> np.ndarray:
    """Rodrigues' formula, (3,) rad -> (3, 3); plain math because it runs every control tick."""
    wx, wy, wz = float(w[0]), float(w[1]), float(w[2])
    th = math.sqrt(wx * wx + wy * wy + wz * wz)
    if th < 1e-12:
        return np.eye(3)
    kx, ky, kz = wx / th, wy / th, wz / th
    c, s_, v = math.cos(th), math.sin(th), 1.0 - math.cos(th)
    return np.array([
        [c + kx * kx * v, kx * ky * v - kz * s_, kx * kz * v + ky * s_],
        [ky * kx * v + kz * s_, c + ky * ky * v, ky * kz * v - kx * s_],
        [kz * kx * v - ky * s_, kz * ky * v + kx * s_, c + kz * kz * v],
    ])


class LinearMotion:
    """``movel``: the TCP moves on a straight line (constant-axis rotation, i.e. SLERP).

    Joint positions come from the analytic IK at knots every `KNOT_DT` of
    motion time, each solved nearest to the previous knot so the arm keeps its
    configuration, and are interpolated linearly in between (the TCP then
    leaves the line by micrometres). `q_at` returns None when the path
    leaves the reachable set or the joint limits, or comes closer to a
    singularity than `handeye.drivers.robot.ur_kinematics.SINGULARITY_STOP` (a real
    controller cannot keep the line there either); `failure` says which, and
    the controller raises a protective stop, as a real one does.
    """

    kind = "movel"
    KNOT_DT = 0.01

    def __init__(self, q0, T_base_tcp1, v: float, a: float, model: str, T_flange_tcp: np.ndarray, limits):
        self.model, self.limits = model, limits
        self.T_tcp_flange = np.linalg.inv(T_flange_tcp)
        T0 = kin.forward(q0, model) @ T_flange_tcp
        T1 = np.asarray(T_base_tcp1, dtype=float)
        self.p0, self.p1, self.R0 = T0[:3, 3], T1[:3, 3], T0[:3, :3]
        self.w = Rotation.from_matrix(self.R0.T @ T1[:3, :3]).as_rotvec()  # rotation in the start TCP frame
        self.length = max(float(np.linalg.norm(self.p1 - self.p0)), ROTATION_LEVER_M * float(np.linalg.norm(self.w)))
        self.v, self.a = v, a
        self.duration = trapezoid_duration(self.length, v, a)
        n = max(1, math.ceil(self.duration / self.KNOT_DT))
        self.knot_t = np.linspace(0.0, self.duration, n + 1)
        self.knots = [np.asarray(q0, dtype=float)]
        self.failure: str | None = None

    def pose_at(self, t: float) -> np.ndarray:
        """``T_base_flange`` on the straight TCP path at motion time ``t``."""
        s = 1.0 if self.length == 0.0 else trapezoid_position(t, self.length, self.v, self.a) / self.length
        T = np.eye(4)
        T[:3, :3] = self.R0 @ rotvec_to_matrix(s * self.w)
        T[:3, 3] = self.p0 + s * (self.p1 - self.p0)
        return T @ self.T_tcp_flange

    def q_at(self, t: float) -> np.ndarray | None:
        if self.duration == 0.0:
            return self.knots[0].copy()
        t = min(max(t, 0.0), self.duration)
        k = min(int(t / self.knot_t[1]), len(self.knot_t) - 2)
        while len(self.knots) <= k + 1:
            q = kin.inverse_nearest(self.pose_at(self.knot_t[len(self.knots)]), self.knots[-1], self.model, self.limits)
            # A jump of more than ~0.5 rad between knots means the IK switched branch
            # (singularity): a real arm cannot follow that either.
            if q is None or np.max(np.abs(q - self.knots[-1])) > 0.5:
                self.failure = "path leaves the reachable joint space"
                return None
            low = kin.singularity_margins(q, self.model) < kin.SINGULARITY_STOP
            if low.any():
                self.failure = f"path passes a {kin.SINGULARITIES[int(np.argmax(low))]} singularity"
                return None
            self.knots.append(q)
        f = (t - self.knot_t[k]) / (self.knot_t[k + 1] - self.knot_t[k])
        return self.knots[k] + f * (self.knots[k + 1] - self.knots[k])


class BrakeMotion:
    """``stopj``/``stopl`` (and stopping a script): decelerate along the current direction."""

    kind = "stop"

    def __init__(self, q0, qd0, duration: float):
        self.q0 = np.asarray(q0, dtype=float)
        self.qd0 = np.asarray(qd0, dtype=float)
        self.duration = max(duration, 0.0)

    def q_at(self, t: float) -> np.ndarray:
        t = min(t, self.duration)
        if self.duration == 0.0:
            return self.q0.copy()
        return self.q0 + self.qd0 * (t - t * t / (2.0 * self.duration))
