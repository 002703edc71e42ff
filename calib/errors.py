"""The one exception tree of handeye.

Every layer raises from here so that the CLI can print one line and exit 1 for
any ``HandeyeError``, and let anything else surface as a bug.
"""


class HandeyeError(Exception):
    """Base of every error handeye expects and reports to users."""


class ConfigError(HandeyeError, ValueError):
    """A configuration field is missing or out of range (the message names it)."""


class CalibrationError(HandeyeError, ValueError):
    """Input to a solver is malformed: bad shape, NaN/inf, not a rigid transform."""


class InsufficientDataError(CalibrationError):
    """Too few samples for the chosen method."""


class DegenerateMotionError(CalibrationError):
    """The motions do not constrain every unknown (e.g. all rotations about one axis)."""


class ExtractionError(HandeyeError):
    """A frame could not be turned into a marker measurement (the frame is skipped)."""


class MarkerNotFoundError(ExtractionError):
    """No marker (or not the requested one) was detected in the image."""


class DepthError(ExtractionError):
    """Too few valid depth pixels on the marker, or the plane fit is bad."""


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


class SessionError(HandeyeError):
    """A recorded session is missing, unreadable, or of an unknown version."""
