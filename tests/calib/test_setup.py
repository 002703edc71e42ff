import pytest

from handeye.app.errors import ConfigError, SessionError
from handeye.calib.errors import CalibrationError, HandeyeError, ParameterError
from handeye.calib.setup import Setup, check_setup
from handeye.drivers.errors import ConnectionLostError, DeviceError, LimitViolationError, RobotStoppedError


def test_setup_names_the_frames_of_x_y_and_the_camera():
    e2h, eih = Setup("eye_to_hand"), Setup("eye_in_hand")
    assert (e2h.x_name, e2h.y_name, e2h.camera_name, e2h.marker_name) == (
        "T_flange_marker", "T_base_cam", "T_base_cam", "T_flange_marker")
    assert (eih.x_name, eih.y_name, eih.camera_name, eih.marker_name) == (
        "T_flange_cam", "T_base_marker", "T_flange_cam", "T_base_marker")
    assert eih.camera_on_flange and not e2h.camera_on_flange
    assert e2h == "eye_to_hand" and f"{eih}" == "eye_in_hand"


def test_check_setup_names_the_bad_value_and_field():
    assert check_setup("eye_in_hand") is Setup.EYE_IN_HAND
    with pytest.raises(CalibrationError, match=r"camera.setup must be one of .*'eye_on_base'"):
        check_setup("eye_on_base", "camera.setup")
    with pytest.raises(SessionError):
        check_setup(None, error=SessionError)


def test_every_error_hangs_under_the_one_root():
    for cls in (ConfigError, SessionError, ParameterError, CalibrationError, DeviceError, ConnectionLostError,
                RobotStoppedError, LimitViolationError):
        assert issubclass(cls, HandeyeError)
    assert issubclass(ConfigError, ParameterError)
