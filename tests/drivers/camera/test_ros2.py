"""The ROS 2 camera through real DDS on loopback: a publisher in another process (tests.ros2_publisher)."""

import contextlib
import logging
import sys
import threading

import numpy as np
import pytest
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, rule

from handeye.app.outage import ReconnectConfig, Reconnecting
from handeye.drivers.camera.ros2 import FramePairer, Ros2Camera, Ros2CameraConfig
from handeye.drivers.errors import ConnectionLostError, DeviceError
from handeye.drivers.ros2 import SkipLog, import_rclpy

PREFIX = "/cam_test"
SIZE, SKEW = 4, 0.02


class PairingMachine(RuleBasedStateMachine):
    """Colour and depth messages arriving in any order, late, lost or flooding, with `take` between them:
    the pairs handed out are the newest pairable colour each time, in increasing stamp order, within the
    skew, and the queues never hold more than their size."""

    def __init__(self):
        super().__init__()
        self.frames = FramePairer("c", "d", SIZE, SKEW, SkipLog("test"))
        self.t = 0.0
        self.taken: list[float] = []

    @rule(dt=st.sampled_from([1 / 30, 1 / 100, 0.0]), back=st.sampled_from([0.0, 0.0, 0.2]))
    def colour(self, dt, back):
        self.t += dt
        self.frames.color.add(self.t - back, 0.0, None)

    @rule(offset=st.sampled_from([0.0, 0.005, -0.015, 0.05, -0.2]))
    def depth(self, offset):
        self.frames.depth.add(self.t + offset, 0.0, None)

    @rule()
    def take(self):
        pair = self.frames.take()
        newer = [c for c in self.frames.color.queue if c.stamp > (pair[0].stamp if pair else self.frames.last)]
        pairable = [c for c in newer if (d := self.frames.nearest_depth(c.stamp)) and abs(d.stamp - c.stamp) <= SKEW]
        assert not pairable  # nothing newer could have been handed out instead
        if pair is not None:
            color, depth = pair
            assert abs(depth.stamp - color.stamp) <= SKEW
            assert not self.taken or color.stamp > self.taken[-1]
            self.taken.append(color.stamp)

    @invariant()
    def bounded(self):
        assert len(self.frames.color.queue) <= SIZE and len(self.frames.depth.queue) <= SIZE
        stamps = [m.stamp for m in self.frames.color.queue]
        assert stamps == sorted(set(stamps))


TestPairing = PairingMachine.TestCase


@pytest.fixture(scope="module")
def publisher(ros2_publisher):
    return ros2_publisher(PREFIX)


def camera(**kw) -> Ros2Camera:
    return Ros2Camera(Ros2CameraConfig(**{"color_topic": f"{PREFIX}/color", "depth_topic": f"{PREFIX}/depth",
                                          "info_topic": f"{PREFIX}/info", "connect_timeout_s": 5.0, **kw}))


@contextlib.contextmanager
def streaming(publisher, **cmd):
    """The publisher streams frames while the body runs; yields the dict its answer lands in."""
    answer = {}
    thread = threading.Thread(target=lambda: answer.update(publisher.send({"cmd": "camera", **cmd})))
    thread.start()
    try:
        yield answer
    finally:
        thread.join()


@pytest.mark.slow
def test_frames_pair_colour_and_depth_by_stamp_with_the_camera_info(publisher):
    cam = camera()
    with streaming(publisher, n=60, rate=30) as answer, cam:
        frames = [cam.read() for _ in range(5)]
    t = [f.t for f in frames]
    assert np.all(np.diff(t) > 0) and set(t) <= set(answer["stamps"])  # the colour header stamps, newest first
    f = frames[-1]
    assert f.color.shape == (120, 160, 3) and f.color.dtype == np.uint8
    assert f.depth.dtype == np.float32 and np.allclose(f.depth, 1.0)
    assert (f.intrinsics.width, f.intrinsics.fx, f.intrinsics.cx) == (160, 140.0, 79.5)
    assert f.meta["depth_skew_ms"] == 0.0 and f.meta["frame_id"] == "cam"


@pytest.mark.slow
def test_a_flood_of_out_of_order_stamps_is_skipped_and_logged_in_bounded_memory(publisher, caplog):
    """100 Hz with every third stamp 0.2 s back: those are logged skips, frames come in stamp order, the
    queues never hold more than queue_size messages, nothing raises."""
    cam = camera(queue_size=5)
    caplog.set_level(logging.WARNING, logger="handeye.drivers.ros2")
    with streaming(publisher, n=200, rate=100, shuffle=True), cam:
        frames = [cam.read() for _ in range(20)]
        held = max(len(q) for q in cam.queues())
    assert np.all(np.diff([f.t for f in frames]) > 0)
    assert held <= 5
    skipped = sum(cam.skips.counts.values())
    assert skipped >= 10 and "skipped: /cam_test/color: stamp not after" in caplog.text
    assert len(caplog.records) <= 8  # the 1st, 10th, 100th ... of each kind, not one line per message


@pytest.mark.slow
@pytest.mark.parametrize("cmd, match", [
    ({"depth_frame": "camera_depth_optical_frame"}, "must be registered to colour"),
    ({"depth_offset_s": 0.05, "rate": 10, "n": 30}, r"stamps out of sync: .* 50 ms from the nearest depth"),
    ({"stamp_offset_s": -30.0}, r"stamped \+30\.\d+ s off this host's clock"),
])
def test_bad_streams_are_typed_errors_naming_the_fault(publisher, cmd, match):
    """Depth in another frame, depth stamps that never meet the colour's (at 10 Hz, 50 ms apart), stamps
    30 s behind this host's clock: each a `DeviceError` saying so, at connect or at the first read."""
    cam = camera(timeout_s=0.5, connect_timeout_s=2.0)
    with streaming(publisher, **{"n": 45, "rate": 15, **cmd}), pytest.raises(DeviceError, match=match):
        with cam:
            cam.read()


def test_no_publisher_is_a_typed_error_naming_the_topic(ros2_graph):
    cam = Ros2Camera(Ros2CameraConfig(color_topic="/nobody/color", connect_timeout_s=0.5))
    with pytest.raises(DeviceError, match="no publisher on /nobody/color"):
        cam.connect()
    assert not cam.is_connected


@pytest.mark.slow
def test_a_publisher_that_stops_and_restarts_is_an_outage_ridden_out(publisher):
    """The stream ends: read raises ConnectionLostError (no traceback, the reason named); under
    `Reconnecting` (monitor) that is an outage, and the next frame after the restart ends it."""
    cam = camera(timeout_s=0.5)
    events = []
    with streaming(publisher, n=45, rate=30):
        cam.connect()
    with pytest.raises(ConnectionLostError, match="no new message on /cam_test/color"):
        while True:
            cam.read()
    rc = Reconnecting("camera", cam, ReconnectConfig(initial_s=0.2, max_s=0.5), on_event=events.append)
    restart = threading.Timer(1.0, lambda: publisher.send({"cmd": "camera", "n": 30, "rate": 30}))
    restart.start()
    try:
        frame = rc.read()
    finally:
        restart.join()
        cam.disconnect()
    assert frame.color.shape == (120, 160, 3)
    kinds = [e.event for e in events]
    assert kinds[0] == "outage_start" and kinds[-1] == "outage_end"


def test_without_rclpy_the_backend_says_in_one_line_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "rclpy", None)
    with pytest.raises(DeviceError) as e:
        import_rclpy()
    assert "pip install 'handeye[ros2]'" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(DeviceError, match=r"handeye\[ros2\]"):
        camera().connect()
