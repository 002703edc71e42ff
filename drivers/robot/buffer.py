"""Recent robot states: ring buffer, host-clock mapping and pose interpolation.

A camera frame is stamped on the host clock; the robot pose at that instant
is interpolated between the two bracketing robot samples (linear on the
translation, SLERP on the rotation).
"""

from __future__ import annotations

import bisect
import collections
import threading

import numpy as np
from scipy.spatial.transform import Rotation

from handeye.drivers.errors import DeviceError, PoseTimeError
from handeye.drivers.robot.base import RobotState


class ClockMapper:
    """Maps controller timestamps to the host clock without poll jitter.

    A sample is observed on the host some latency after the controller
    stamped it; the smallest ``t_recv - t_controller`` over a sliding window
    is the best estimate of the clock offset (the fastest delivery), so
    ``t_host = t_controller + min offset``. The window follows slow drift of
    the two clocks.

    Parameters
    ----------
    window : float
        Seconds of controller time over which the minimum is taken.
    """

    def __init__(self, window: float = 5.0):
        self.window = window
        self._q: collections.deque[tuple[float, float]] = collections.deque()  # (t_ctrl, offset), offsets increasing

    def reset(self) -> None:
        self._q.clear()

    def update(self, t_controller: float, t_recv: float) -> float:
        """Record one observation; returns the host time of ``t_controller``."""
        if self._q and t_controller < self._q[-1][0]:
            self._q.clear()  # controller clock restarted (reconnect to a rebooted controller)
        offset = t_recv - t_controller
        while self._q and self._q[-1][1] >= offset:
            self._q.pop()
        self._q.append((t_controller, offset))
        while self._q[0][0] < t_controller - self.window:
            self._q.popleft()
        return t_controller + self._q[0][1]


def interpolate_pose(T0: np.ndarray, T1: np.ndarray, s: float) -> np.ndarray:
    """Pose a fraction ``s`` in [0, 1] of the way from ``T0`` to ``T1`` (lerp + SLERP)."""
    return pose_path(T0, T1)(s)


def pose_path(T0: np.ndarray, T1: np.ndarray):
    """``s -> interpolate_pose(T0, T1, s)`` with the relative rotation's axis and angle taken once
    (a path check evaluates a hundred fractions of one motion)."""
    R0, t0, t1 = T0[:3, :3], T0[:3, 3], T1[:3, 3]
    dr = Rotation.from_matrix(R0.T @ T1[:3, :3]).as_rotvec()
    angle = float(np.linalg.norm(dr))
    K = np.zeros((3, 3))
    if angle > 0:
        kx, ky, kz = dr / angle
        K = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    K2 = K @ K

    def at(s: float) -> np.ndarray:
        a = s * angle
        T = np.eye(4)
        T[:3, :3] = R0 @ (np.eye(3) + np.sin(a) * K + (1.0 - np.cos(a)) * K2)  # Rodrigues
        T[:3, 3] = (1.0 - s) * t0 + s * t1
        return T

    return at


class StateBuffer:
    """Thread-safe ring buffer of `RobotState`, ordered by ``t_host``.

    Parameters
    ----------
    seconds : float
        States older than this (host time) behind the newest one are dropped,
        whatever the stream rate (125 Hz CB3, 500 Hz e-Series).
    """

    def __init__(self, seconds: float):
        self.seconds = seconds
        self._states: collections.deque[RobotState] = collections.deque()
        self._times: collections.deque[float] = collections.deque()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._states)

    def clear(self) -> None:
        with self._lock:
            self._states.clear()
            self._times.clear()

    def append(self, state: RobotState) -> None:
        with self._lock:
            if self._times and state.t_host <= self._times[-1]:
                return  # same or older sample (re-read), keep times strictly increasing
            self._states.append(state)
            self._times.append(state.t_host)
            while self._times[0] < state.t_host - self.seconds:
                self._states.popleft()
                self._times.popleft()

    @property
    def latest(self) -> RobotState | None:
        with self._lock:
            return self._states[-1] if self._states else None

    def span(self) -> tuple[float, float] | None:
        with self._lock:
            return (self._times[0], self._times[-1]) if self._times else None

    def pose_at(self, t_host: float) -> np.ndarray:
        """``T_base_flange`` (4, 4) at host time ``t_host``.

        Raises
        ------
        PoseTimeError
            If ``t_host`` lies outside the buffered interval (the message says
            by how much).
        DeviceError
            If ``t_host`` is not finite, or the buffer is empty.
        """
        if not np.isfinite(t_host):
            raise DeviceError(f"pose_at: t_host must be finite, got {t_host}")
        with self._lock:
            if not self._times:
                raise DeviceError("pose_at: the robot state buffer is empty (not connected yet?)")
            t0, t1 = self._times[0], self._times[-1]
            if t_host < t0 or t_host > t1:
                where = f"{(t0 - t_host) * 1e3:.1f} ms before" if t_host < t0 else f"{(t_host - t1) * 1e3:.1f} ms after"
                raise PoseTimeError(
                    f"pose_at: t_host={t_host:.6f} is {where} the robot state buffer "
                    f"[{t0:.6f}, {t1:.6f}] (host clock, s)", ahead=t_host > t1
                )
            i = bisect.bisect_left(self._times, t_host)
            if self._times[i] == t_host:
                return self._states[i].T_base_flange.copy()
            a, b = self._states[i - 1], self._states[i]
        s = (t_host - a.t_host) / (b.t_host - a.t_host)
        return interpolate_pose(a.T_base_flange, b.T_base_flange, s)
