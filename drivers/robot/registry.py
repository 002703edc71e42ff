"""The robot backends by name (``[robot] type``): ``ROBOTS.create(config)`` builds one.

Backends register with ``@ROBOTS.register(name, ConfigClass)`` on their robot
class (`handeye.drivers.robot.ur`: ``"ur"``; the simulator `handeye.mocks.ur_sim.robot`:
``"ur_sim"``). A table without ``type`` means ``"ur"``. `robot_limits` and
`kinematic_model` answer from a config alone, without building a driver.
"""

from __future__ import annotations

from handeye.drivers.registry import Registry
from handeye.drivers.robot.base import KinematicModel, RobotLimits

ROBOTS = Registry("robot", "type", default="ur")


def robot_limits(config) -> RobotLimits:
    """`RobotLimits` of a robot config (its backend's `Robot.limits_for`)."""
    return ROBOTS.of_config(config).device.limits_for(config)


def kinematic_model(config) -> KinematicModel | None:
    """`KinematicModel` (or None) of a robot config (its backend's `Robot.kinematics_for`)."""
    return ROBOTS.of_config(config).device.kinematics_for(config)
