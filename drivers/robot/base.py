"""Abstract robot: read the flange pose, move within limits; and what the app may ask of any backend.

Every backend declares its limits (`RobotLimits`), its limit check
(`Robot.check_target`) and its kinematic model (`KinematicModel`, or None),
the last two from its config alone (`Robot.limits_for`,
`Robot.kinematics_for`), so that a planner or a replay needs no driver. A
simulated backend (``simulated = True``) also knows where its flange really
is (`Robot.true_flange_pose`) and runs a production program
(`Robot.start_program`).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

from handeye.drivers.device import Device
from handeye.drivers.errors import DeviceError


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


@dataclass(frozen=True)
class RobotLimits:
    """Where a planner may put the flange and how fast the robot gets there.

    Attributes
    ----------
    workspace_min, workspace_max : 3 floats or None
        Box in the base frame (m) the flange must stay in; None: no box (a read-only robot may have none).
    speed_m_s, acceleration_m_s2 : float
        Tool speed (m/s) and acceleration (m/s^2) of a linear move, for the planner's travel-time model.
    """

    workspace_min: tuple[float, float, float] | None
    workspace_max: tuple[float, float, float] | None
    speed_m_s: float
    acceleration_m_s2: float


class KinematicModel(abc.ABC):
    """A robot's nominal kinematics and the error of its parameters.

    ``name`` names the model in messages (e.g. ``"ur10"``).
    """

    name: str

    @abc.abstractmethod
    def forward(self, q) -> np.ndarray:
        """``T_base_flange`` (..., 4, 4) of joints ``q`` (..., 6), rad."""

    @abc.abstractmethod
    def inverse_nearest(self, T_base_flange: np.ndarray, q_near) -> np.ndarray | None:
        """The joints (6,) reaching ``T_base_flange`` nearest ``q_near``; None if it is out of reach."""

    def shared_error_factor(self, q) -> np.ndarray | None:
        """The flange-pose error all samples at joints ``q`` (N, 6) share (the parameters' error), as
        `handeye.calib.auto.solve_auto`'s ``robot_shared_error`` factor (N, 6, P); None: the model has none."""
        return None


class Robot(Device):
    """A robot arm. Use as a context manager: ``with ROBOTS.create(cfg) as robot: ...``.

    ``config`` is the backend's config model (registered with it in `handeye.drivers.robot.registry.ROBOTS`).
    """

    config: object

    @classmethod
    @abc.abstractmethod
    def limits_for(cls, config) -> RobotLimits:
        """The limits ``config`` sets (no driver needed: plans are made offline too)."""

    @classmethod
    @abc.abstractmethod
    def kinematics_for(cls, config) -> KinematicModel | None:
        """The kinematic model ``config`` describes (no driver needed); None: the backend has none."""

    @property
    def limits(self) -> RobotLimits:
        return self.limits_for(self.config)

    @property
    def kinematics(self) -> KinematicModel | None:
        return self.kinematics_for(self.config)

    def shared_error_factor(self, q) -> np.ndarray | None:
        """The flange-pose error all samples at joints ``q`` (N, 6) share: the kinematic model's
        `KinematicModel.shared_error_factor`; None without a model."""
        model = self.kinematics
        return None if model is None else model.shared_error_factor(q)

    @abc.abstractmethod
    def check_target(self, T_base_flange: np.ndarray, q_start=None) -> np.ndarray:
        """Check a move to ``T_base_flange`` (from joints ``q_start``, None: the current ones) against every
        limit, sending nothing; returns the target joints (6,). Raises LimitViolationError."""

    def true_flange_pose(self) -> np.ndarray:
        """Where the flange is, ``T_base_flange`` (4, 4), as well as the backend knows: what a rendered camera
        sees. A real robot's best is its reading; a simulator overrides this with its truth."""
        return self.read().T_base_flange

    def start_program(self, program: dict) -> None:
        """Run a looping production program (waypoints of joints with tool stops) on a simulated controller.

        Raises
        ------
        DeviceError
            On a real robot, which runs its own programs (only a ``simulated`` backend overrides this).
        """
        raise DeviceError(f"{type(self).__name__} runs no production program: only a simulated controller does")

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
