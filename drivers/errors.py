"""Errors of the device layer (robots, cameras), under `calib.errors.HandeyeError`."""

from calib.errors import HandeyeError


class DeviceError(HandeyeError):
    """A robot or camera failed."""


class ConnectionLostError(DeviceError):
    """The connection to a device dropped or its data stream froze."""


class RobotStoppedError(DeviceError):
    """The robot entered a protective or emergency stop."""


class LimitViolationError(DeviceError):
    """A motion target lies outside the configured workspace, tilt or joint limits.

    Raised before anything is sent to the robot.
    """
