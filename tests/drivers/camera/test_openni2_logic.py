"""OpenNI2 driver logic (pairing by timestamp, dropped streams, intrinsics from the field of view)
against a scripted stand-in for the ``openni`` bindings, so it runs without a device or library."""

import math
import sys
import types

import numpy as np
import pytest

from handeye.drivers.errors import ConnectionLostError, DeviceError
from handeye.drivers.camera.registry import CAMERAS


class _Mode:
    def __init__(self, w, h, fps, fmt):
        self.resolutionX, self.resolutionY, self.fps, self.pixelFormat = w, h, fps, fmt


class _Frame:
    def __init__(self, ts, idx, w, h, data):
        self.timestamp, self.frameIndex, self.width, self.height, self._data = ts, idx, w, h, data

    def get_buffer_as_uint16(self):
        return self._data

    def get_buffer_as_uint8(self):
        return self._data


class _Stream:
    def __init__(self, fmt, timestamps, dtype):
        self.mode = _Mode(64, 48, 30, fmt)
        self.timestamps = timestamps  # frame number (0-based) -> device timestamp, us
        self.dtype = dtype
        self.n = 0
        self.fail = None

    def get_sensor_info(self):
        return types.SimpleNamespace(videoModes=[self.mode])

    def get_video_mode(self):
        return self.mode

    def set_video_mode(self, mode):
        self.mode = mode

    def start(self):
        pass

    def stop(self):
        pass

    def close(self):
        pass

    def get_horizontal_fov(self):
        return math.radians(58.0)

    def get_vertical_fov(self):
        return math.radians(45.0)

    def read_frame(self):
        if self.fail:
            raise RuntimeError(self.fail)
        ts = self.timestamps(self.n)
        self.n += 1
        shape = (48, 64) if self.dtype == np.uint16 else (48, 64, 3)
        data = np.full(shape, 1000 if self.dtype == np.uint16 else 7, self.dtype)
        if self.dtype == np.uint8:
            data[..., 0] = 200  # R channel: the driver must hand out BGR
        return _Frame(ts, self.n, 64, 48, data.ravel())


def _fake_openni(depth_ts, color_ts, registration=True):
    ni = types.SimpleNamespace(
        IMAGE_REGISTRATION_DEPTH_TO_COLOR=1, PIXEL_FORMAT_DEPTH_1_MM=100, PIXEL_FORMAT_RGB888=200,
    )
    ni.depth = _Stream(100, depth_ts, np.uint16)
    ni.color = _Stream(200, color_ts, np.uint8)
    ni.stalled = False

    class Device:
        def __init__(self, uri):
            self.uri = uri

        @staticmethod
        def open_any():
            return Device(None)

        @staticmethod
        def enumerate_uris():     # one device attached, as the bindings list it
            return [b"1d27/0601@1/2"]

        def is_image_registration_mode_supported(self, mode):
            return registration

        def set_image_registration_mode(self, mode):
            pass

        def set_depth_color_sync_enabled(self, on):
            pass

        def create_depth_stream(self):
            return ni.depth

        def create_color_stream(self):
            return ni.color

        def close(self):
            pass

    ni.Device = Device
    ni.is_initialized = lambda: True
    ni.wait_for_any_stream = lambda streams, timeout: None if ni.stalled else streams[0]
    return ni


@pytest.fixture
def fake(monkeypatch):
    def install(depth_ts, color_ts, **kw):
        ni = _fake_openni(depth_ts, color_ts, **kw)
        pkg = types.ModuleType("openni")
        pkg.openni2 = ni
        monkeypatch.setitem(sys.modules, "openni", pkg)
        monkeypatch.setitem(sys.modules, "openni.openni2", ni)
        return ni

    return install


CFG = {"backend": "openni2", "width": 64, "height": 48, "fps": 30}


def test_pairs_frames_by_device_timestamp(fake):
    # Color starts one frame (33 ms) ahead: the driver drops a depth frame to pair them.
    ni = fake(depth_ts=lambda n: 33_333 * n, color_ts=lambda n: 33_400 + 33_333 * n)
    with CAMERAS.create(CFG) as cam:
        f = cam.read()
        # Field of view 58 deg over 64 px.
        assert cam.intrinsics.fx == pytest.approx(32 / math.tan(math.radians(29)))
    assert f.meta["depth_timestamp_us"] == 33_333 and f.meta["color_timestamp_us"] == 33_400
    assert ni.depth.n == 2 and ni.color.n == 1
    np.testing.assert_allclose(f.depth, 1.0)  # 1000 mm
    assert f.color[0, 0].tolist() == [7, 7, 200]  # RGB -> BGR


def test_streams_that_never_align_are_a_lost_connection(fake):
    fake(depth_ts=lambda n: 0, color_ts=lambda n: 500_000)  # depth frozen in the past
    cfg = dict(CFG, timeout_s=0.05)
    with CAMERAS.create(cfg) as cam, pytest.raises(ConnectionLostError, match="apart"):
        cam.read()


def test_stalled_or_failing_stream_is_a_lost_connection(fake):
    ni = fake(depth_ts=lambda n: 33_333 * n, color_ts=lambda n: 33_333 * n)
    with CAMERAS.create(CFG) as cam:
        cam.read()
        ni.stalled = True
        with pytest.raises(ConnectionLostError, match="no frame within"):
            cam.read()
        ni.stalled = False
        ni.depth.fail = "device unplugged"
        with pytest.raises(ConnectionLostError, match="device unplugged"):
            cam.read()


def test_device_without_registration_is_refused(fake):
    fake(depth_ts=lambda n: 0, color_ts=lambda n: 0, registration=False)
    cam = CAMERAS.create(CFG)
    with pytest.raises(DeviceError, match="cannot register depth to color"):
        cam.connect()
    assert not cam.is_connected
