"""The two hand-eye setups and the frame names that go with each.

Both are solved as the paper's ``A_i X = Y B_i`` (eq. 1) with
``A_i = T_base_flange`` and ``B_i = T_cam_marker``:

===============  ==============  ===============  ===================
setup            camera          X                Y
===============  ==============  ===============  ===================
``eye_to_hand``  static          T_flange_marker  T_base_cam
``eye_in_hand``  on the flange   T_flange_cam     T_base_marker
===============  ==============  ===============  ===================

`Setup` is a `StrEnum`, so a member compares equal to its string value and
is written to JSON as that string.
"""

from __future__ import annotations

from handeye.calib.compat import StrEnum

from handeye.calib.errors import CalibrationError, HandeyeError


class Setup(StrEnum):
    """Where the camera sits: static (``EYE_TO_HAND``) or on the flange (``EYE_IN_HAND``)."""

    EYE_TO_HAND = "eye_to_hand"
    EYE_IN_HAND = "eye_in_hand"

    @property
    def camera_on_flange(self) -> bool:
        """True when the camera rides on the flange (eye-in-hand); the marker is then static."""
        return self is Setup.EYE_IN_HAND

    @property
    def x_name(self) -> str:
        """Frame name of the unknown ``X``: ``T_flange_marker`` or ``T_flange_cam``."""
        return "T_flange_cam" if self.camera_on_flange else "T_flange_marker"

    @property
    def y_name(self) -> str:
        """Frame name of the unknown ``Y``: ``T_base_cam`` or ``T_base_marker``."""
        return "T_base_marker" if self.camera_on_flange else "T_base_cam"

    @property
    def camera_name(self) -> str:
        """Name of the camera transform: ``T_base_cam`` (eye-to-hand, ``Y``) or ``T_flange_cam`` (eye-in-hand, ``X``)."""
        return self.x_name if self.camera_on_flange else self.y_name

    @property
    def marker_name(self) -> str:
        """Name of the marker transform: ``T_flange_marker`` (``X``) or ``T_base_marker`` (``Y``)."""
        return self.y_name if self.camera_on_flange else self.x_name

    @property
    def equation(self) -> str:
        """The frame chain this setup closes, in ``T_a_b`` names."""
        if self.camera_on_flange:
            return "T_base_flange @ T_flange_cam @ T_cam_marker = T_base_marker"
        return "T_base_flange @ T_flange_marker = T_base_cam @ T_cam_marker"


def check_setup(setup, name: str = "setup", error: type[HandeyeError] = CalibrationError) -> Setup:
    """``setup`` (a `Setup` or its string value) as a `Setup` member.

    Parameters
    ----------
    setup : Setup or str
    name : str
        What to call the value in the message (e.g. ``"camera.setup"``).
    error : type
        The error to raise: `CalibrationError` for solver input; the config
        and session layers pass their own.

    Raises
    ------
    CalibrationError (or ``error``)
        If ``setup`` is not ``"eye_to_hand"`` or ``"eye_in_hand"``; the message names ``name`` and the value.
    """
    try:
        return Setup(setup)
    except ValueError:
        raise error(f"{name} must be one of {[s.value for s in Setup]}, got {setup!r}") from None
