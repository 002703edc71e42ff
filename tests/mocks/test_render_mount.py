"""The rendered camera's mount drifts and gets knocked on schedule ([camera.mount]), and the frames follow it."""

import numpy as np
import pytest

from handeye.calib import transforms as tf
from handeye.calib.errors import ParameterError
from handeye.calib.setup import Setup
from handeye.drivers.camera.registry import CAMERAS
from handeye.mocks.render.camera import RenderedCameraConfig

# The default cell's start flange pose: the marker is in view of the default camera.
FLANGE = tf.make_transform(np.eye(3), [0.9, 0.1, 0.5])


class Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


def _camera(mount: dict, setup: str = "eye_to_hand"):
    cam = CAMERAS.create({"backend": "rendered", "setup": setup, "mount": mount})
    cam.clock = Clock()
    if setup == "eye_to_hand":
        T_base_flange = _facing_flange(cam.config)
    else:
        T_base_flange = tf.make_transform(np.diag([1.0, -1.0, -1.0]), [0.9, 0.05, 0.5])
    cam.follow(lambda: T_base_flange)
    cam.connect()
    return cam


def _facing_flange(c: RenderedCameraConfig) -> np.ndarray:
    """A flange pose 0.6 m in front of the camera with the marker facing it."""
    T_cam_marker = tf.make_transform(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 0.6])
    return np.asarray(c.T_base_cam) @ T_cam_marker @ tf.invert(np.asarray(c.T_flange_marker))


def _moved(cam, t: float):
    cam.clock.t = 1000.0 + t
    T0 = np.asarray(getattr(cam.config, cam.config.setup.camera_name))
    return cam.camera_transform(), T0


def test_drift_moves_the_camera_by_rate_times_time_along_its_direction():
    cam = _camera({"drift_mm_per_h": 0.5, "drift_deg_per_h": 0.04, "drift_direction": [0.0, 3.0, 4.0],
                   "drift_axis": [0.0, 0.0, 1.0]})
    for hours in (0.0, 1.0, 8.0):
        T, T0 = _moved(cam, hours * 3600.0)
        np.testing.assert_allclose((T[:3, 3] - T0[:3, 3]) * 1e3, 0.5 * hours * np.array([0.0, 0.6, 0.8]), atol=1e-9)
        rot, _ = tf.pose_error(T, tf.make_transform(T0[:3, :3], T[:3, 3]))
        assert np.rad2deg(rot) == pytest.approx(0.04 * hours, abs=1e-9)
    # The frames and the truth are the drifted camera's: what a calibration of that moment must find.
    frame = cam.read()
    np.testing.assert_allclose(frame.truth["Y"], T, atol=1e-12)
    np.testing.assert_allclose(cam.truth()["T_base_cam"], T, atol=1e-12)
    np.testing.assert_allclose(frame.truth["T_cam_marker"],
                               tf.invert(T) @ frame.truth["T_base_flange"] @ np.asarray(cam.config.T_flange_marker),
                               atol=1e-9)


def test_an_unset_drift_direction_is_a_seeded_unit_vector():
    a = _camera({"drift_mm_per_h": 1.0, "seed": 5})
    b = _camera({"drift_mm_per_h": 1.0, "seed": 5})
    c = _camera({"drift_mm_per_h": 1.0, "seed": 6})
    Ta, T0 = _moved(a, 3600.0)
    Tb, _ = _moved(b, 3600.0)
    Tc, _ = _moved(c, 3600.0)
    np.testing.assert_allclose(Ta, Tb, atol=0)
    assert np.linalg.norm(Ta[:3, 3] - T0[:3, 3]) * 1e3 == pytest.approx(1.0, abs=1e-9)
    assert np.linalg.norm(Ta[:3, 3] - Tc[:3, 3]) > 1e-4


def test_bumps_fire_at_their_times_and_stay():
    cam = _camera({"bumps": [{"at_s": 7200.0, "translation_mm": 5.0, "rotation_deg": 0.3},
                             {"at_s": 16200.0, "translation_mm": 2.0, "rotation_deg": 0.0,
                              "direction": [0.0, 0.0, 1.0]}]})
    T, T0 = _moved(cam, 7199.0)
    np.testing.assert_allclose(T, T0, atol=0)
    T, _ = _moved(cam, 7200.0)
    rot, trans = tf.pose_error(T, T0)
    assert trans * 1e3 == pytest.approx(5.0, abs=1e-9) and np.rad2deg(rot) == pytest.approx(0.3, abs=1e-9)
    np.testing.assert_allclose((T[:3, 3] - T0[:3, 3]) * 1e3, [5.0, 0.0, 0.0], atol=1e-9)
    T2, _ = _moved(cam, 16200.0)
    np.testing.assert_allclose((T2[:3, 3] - T0[:3, 3]) * 1e3, [5.0, 0.0, 2.0], atol=1e-9)
    # A bump added at run time (the demo's --bump) joins the schedule at the mount's current time.
    cam.add_bump(1.0, 0.0, direction=(0.0, 1.0, 0.0))
    T3, _ = _moved(cam, 16200.0)
    np.testing.assert_allclose((T3[:3, 3] - T0[:3, 3]) * 1e3, [5.0, 1.0, 2.0], atol=1e-9)


def test_time_scale_speeds_up_the_mount_clock_and_eye_in_hand_moves_the_camera_on_the_flange():
    cam = _camera({"drift_mm_per_h": 1.0, "drift_direction": [1.0, 0.0, 0.0], "time_scale": 60.0}, "eye_in_hand")
    assert cam.config.setup == Setup.EYE_IN_HAND
    T, T0 = _moved(cam, 60.0)  # one wall minute = one mount hour
    assert cam.mount_time() == pytest.approx(3600.0)
    np.testing.assert_allclose(T, T0 @ tf.make_transform(np.eye(3), [1e-3, 0.0, 0.0]), atol=1e-12)
    frame = cam.read()
    np.testing.assert_allclose(frame.truth["X"], T, atol=1e-12)
    np.testing.assert_allclose(cam.truth()["T_flange_cam"], T, atol=1e-12)


def test_a_still_mount_keeps_the_configured_camera():
    cam = _camera({})
    T, T0 = _moved(cam, 10 * 3600.0)
    np.testing.assert_array_equal(T, T0)


def test_bad_mount_directions_are_refused_by_name():
    with pytest.raises(ParameterError, match="mount: drift_direction"):
        RenderedCameraConfig(mount={"drift_direction": [0.0, 0.0, 0.0]})
    with pytest.raises(ParameterError, match="at_s"):
        RenderedCameraConfig(mount={"bumps": [{"at_s": -1.0}]})
