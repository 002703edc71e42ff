"""Time-parameterised motions of the simulated UR arm.

Every motion maps the time since its start (s) to joint positions (rad); the
controller differentiates them for speeds. Profiles are trapezoidal (constant
acceleration, cruise, constant deceleration) like the UR controller's
``movej``/``movel``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from drivers.robot import ur_kinematics as kin

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


class LinearMotion:
    """``movel``: the TCP moves on a straight line (SLERP on orientation).

    Joint positions come from the analytic IK nearest to the previous tick,
    so the arm keeps its configuration; `q_at` returns None when the path
    leaves the reachable set or the joint limits (the controller then raises
    a protective stop, as a real one does).
    """

    kind = "movel"

    def __init__(self, q0, T_base_tcp1, v: float, a: float, model: str, T_flange_tcp: np.ndarray, limits):
        self.model, self.limits = model, limits
        self.T_tcp_flange = np.linalg.inv(T_flange_tcp)
        T0 = kin.forward(q0, model) @ T_flange_tcp
        self.p0, self.p1 = T0[:3, 3], np.asarray(T_base_tcp1)[:3, 3]
        rots = Rotation.from_matrix(np.stack([T0[:3, :3], np.asarray(T_base_tcp1)[:3, :3]]))
        self.slerp = Slerp([0.0, 1.0], rots)
        angle = float(np.linalg.norm((rots[0].inv() * rots[1]).as_rotvec()))
        self.length = max(float(np.linalg.norm(self.p1 - self.p0)), ROTATION_LEVER_M * angle)
        self.v, self.a = v, a
        self.duration = trapezoid_duration(self.length, v, a)
        self.q_prev = np.asarray(q0, dtype=float)

    def q_at(self, t: float) -> np.ndarray | None:
        s = 1.0 if self.length == 0.0 else trapezoid_position(t, self.length, self.v, self.a) / self.length
        T = np.eye(4)
        T[:3, :3] = self.slerp([s]).as_matrix()[0]
        T[:3, 3] = self.p0 + s * (self.p1 - self.p0)
        q = kin.inverse_nearest(T @ self.T_tcp_flange, self.q_prev, self.model, self.limits)
        # A jump of more than ~0.5 rad in one tick means the IK switched branch
        # (singularity): a real arm cannot follow that either.
        if q is None or np.max(np.abs(q - self.q_prev)) > 0.5:
            return None
        self.q_prev = q
        return q


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
