"""Errors of the device layer (robots, cameras), under `handeye.calib.errors.HandeyeError`."""

from handeye.calib.errors import HandeyeError


class DeviceError(HandeyeError):
    """A robot or camera failed."""


class ConnectionLostError(DeviceError):
    """The connection to a device dropped or its data stream froze."""


class PoseTimeError(DeviceError):
    """No robot pose at the time asked for: it lies outside the robot states buffered (a frame stamped ahead of
    the newest state, or older than the buffer). A question about the data, not a device fault: a stream that
    dropped or froze raises `ConnectionLostError` instead. ``ahead``: the time is after the newest state (a
    wait may bring it)."""

    def __init__(self, message: str, *, ahead: bool):
        super().__init__(message)
        self.ahead = ahead


class RobotStoppedError(DeviceError):
    """The robot entered a protective or emergency stop."""


class LimitViolationError(DeviceError):
    """A motion target lies outside the configured workspace, tilt or joint limits.

    Raised before anything is sent to the robot.
    """
