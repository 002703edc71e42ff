"""Abstract robot: read the flange pose, move within limits."""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

from drivers.device import Device


@dataclass(frozen=True)
class RobotState:
    """One reading of the robot.

    Attributes
    ----------
    t_host : float
        Host receive time, seconds (``time.time()`` clock).
    t_controller : float
        Controller timestamp, seconds since controller start.
    T_base_flange : ndarray, shape (4, 4)
        Flange pose in the robot base frame (m), TCP offset removed.
    q : ndarray, shape (6,)
        Joint positions, rad.
    qd : ndarray, shape (6,)
        Joint speeds, rad/s.
    robot_mode : int
        UR robot mode (7 = running).
    safety_mode : int
        UR safety mode (1 = normal, 3 = protective stop, 7 = emergency stop ...).
    """

    t_host: float
    t_controller: float
    T_base_flange: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    robot_mode: int
    safety_mode: int

    @property
    def is_still(self) -> bool:
        return bool(np.max(np.abs(self.qd)) < 1e-3)


class Robot(Device):
    """A robot arm. Use as a context manager: ``with ROBOTS.create(cfg) as robot: ...``."""

    def shared_error_factor(self, q) -> np.ndarray | None:
        """The flange-pose error all samples at joints ``q`` (N, 6) share (e.g. the kinematic model's), as
        `calib.auto.solve_auto`'s ``robot_shared_error`` factor (N, 6, P); None: the backend models none."""
        return None

    @abc.abstractmethod
    def read(self) -> RobotState:
        """Latest state; raises ConnectionLostError if the stream dropped or froze."""

    @abc.abstractmethod
    def pose_at(self, t_host: float) -> np.ndarray:
        """``T_base_flange`` (4, 4) interpolated at host time ``t_host`` from the recent buffer."""

    @abc.abstractmethod
    def move_to(self, T_base_flange: np.ndarray) -> RobotState:
        """Move the flange to a pose after checking it against the configured limits.

        Blocks until the robot has settled; returns the settled state. Raises
        LimitViolationError before sending anything if the target is outside
        the limits, RobotStoppedError on a protective/emergency stop, and
        DeviceError in read-only mode.
        """

    @abc.abstractmethod
    def stop(self) -> None:
        """Decelerate and stop any motion now."""
