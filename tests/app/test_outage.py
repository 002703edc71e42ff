"""Outages are ridden out: an unplugged camera and a dropped or frozen robot stream reconnect with backoff."""

import threading
import time

import numpy as np
import pytest

from handeye.app.acquire import pose_at_frame
from handeye.app.errors import OutageError
from handeye.app.outage import ReconnectConfig, Reconnecting
from handeye.calib import transforms as tf
from handeye.drivers.camera.registry import CAMERAS
from handeye.drivers.errors import ConnectionLostError, PoseTimeError
from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.ur import URRobot, URRobotConfig
from handeye.mocks.ur_sim import launch
from tests.simulated_ur import START_Q
FAST = ReconnectConfig(initial_s=0.1, factor=2.0, max_s=0.4)


def test_backoff_is_immediate_then_exponential_and_capped():
    delays = ReconnectConfig(initial_s=0.5, factor=2.0, max_s=3.0).delays()
    assert [next(delays) for _ in range(7)] == [0.0, 0.5, 1.0, 2.0, 3.0, 3.0, 3.0]


class Unplug:
    """Makes a camera's read and connect fail as an unplugged USB camera's do, until ``until`` (monotonic)."""

    def __init__(self, camera):
        self.until = 0.0
        self.camera = camera
        read, connect = camera.read, camera.connect

        def guarded(fn):
            def call():
                if time.monotonic() < self.until:
                    raise ConnectionLostError("camera unplugged")
                return fn()
            return call

        camera.read, camera.connect = guarded(read), guarded(connect)

    def pull(self, seconds: float) -> None:
        self.until = time.monotonic() + seconds


def _rendered_camera():
    cam = CAMERAS.create({"backend": "rendered"})
    c = cam.config
    T_cam_marker = tf.make_transform(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 0.6])
    T_base_flange = np.asarray(c.T_base_cam) @ T_cam_marker @ tf.invert(np.asarray(c.T_flange_marker))
    cam.follow(lambda: T_base_flange)
    return cam


def test_an_unplugged_camera_is_an_outage_and_the_next_frame_comes_after_it_is_back():
    cam = _rendered_camera()
    events = []
    with Reconnecting("camera", cam, FAST, on_event=events.append) as rc:
        first = rc.call(lambda c: c.read())
        plug = Unplug(cam)
        plug.pull(1.2)
        t0 = time.monotonic()
        frame = rc.call(lambda c: c.read())
        waited = time.monotonic() - t0
    assert frame.index == first.index + 1 and frame.depth.any()  # the same stream, continued
    kinds = [e.event for e in events]
    assert kinds[0] == "outage_start" and kinds[-1] == "outage_end" and set(kinds[1:-1]) == {"reconnect_failed"}
    assert "camera unplugged" in events[0].error
    # Back within one capped wait of the replug; the waits grow to max_s and no further.
    assert 1.2 <= waited < 1.2 + 0.4 + 0.5, waited
    failed_at = [e.outage_s for e in events if e.event == "reconnect_failed"]
    gaps = np.diff(failed_at)
    assert gaps.max() < 0.4 + 0.15 and gaps[0] < gaps[-1], gaps
    assert events[-1].outage_s == pytest.approx(waited, abs=0.1) and rc.outages == 1 and not rc.in_outage
    assert "back after" in events[-1].message()


def test_a_device_that_reopens_but_still_fails_keeps_backing_off():
    """Reopening works, reading does not (a camera whose flange-pose source is a dropped robot): no busy loop."""
    cam = _rendered_camera()
    broken = {"until": time.monotonic() + 1.0}

    def read(c):
        if time.monotonic() < broken["until"]:
            raise ConnectionLostError("no flange pose")
        return c.read()

    events = []
    with Reconnecting("camera", cam, FAST, on_event=events.append) as rc:
        rc.call(read)
    failed = [e for e in events if e.event == "reconnect_failed"]
    # waits 0, 0.1, 0.2, 0.4, 0.4 ... over 1 s: about five attempts, not thousands
    assert 3 <= len(failed) <= 7, len(failed)
    assert events[-1].event == "outage_end" and events[-1].outage_s >= 1.0


def test_a_stop_ends_an_outage_wait_at_once_and_max_outage_bounds_it():
    cam = _rendered_camera()
    stop = threading.Event()
    with Reconnecting("camera", cam, ReconnectConfig(initial_s=30.0, max_s=30.0), stop=stop,
                      on_event=lambda e: None) as rc:
        Unplug(cam).pull(1e9)
        threading.Timer(0.3, stop.set).start()
        t0 = time.monotonic()
        with pytest.raises(OutageError, match="camera: stopped during an outage"):
            rc.call(lambda c: c.read())
        assert time.monotonic() - t0 < 1.0
    cam = _rendered_camera()
    with Reconnecting("camera", cam, ReconnectConfig(initial_s=0.1, max_s=0.2, max_outage_s=0.6),
                      on_event=lambda e: None) as rc:
        Unplug(cam).pull(1e9)
        t0 = time.monotonic()
        with pytest.raises(OutageError, match="max_outage_s = 0.6 s"):
            rc.call(lambda c: c.read())
        assert time.monotonic() - t0 < 0.6 + 0.1


def test_a_dropped_and_a_frozen_robot_stream_reconnect_to_the_simulated_controller(loopback):
    events = []
    with launch(loopback(46), "ur10", "5.11", initial_q=START_Q) as sim:
        cfg = URRobotConfig(host=sim.host, read_only=True, tcp_offset=(0, 0, 0.1, 0, 0, 0), connect_timeout=1.0,
                            frozen_timeout=0.3)
        with Reconnecting("robot", URRobot(cfg), FAST, on_event=events.append) as rc:
            before = rc.call(lambda r: r.read())
            sim.drop(refuse_s=1.5)
            time.sleep(0.2)
            t0 = time.monotonic()
            after = rc.call(lambda r: r.read())
            dropped = time.monotonic() - t0
            assert after.t_controller > before.t_controller
            np.testing.assert_allclose(after.T_base_flange, before.T_base_flange, atol=1e-9)
            sim.freeze(1.5)
            time.sleep(0.5)  # the stream is stale by now
            frozen_state = rc.call(lambda r: r.read())
            assert frozen_state.t_host > after.t_host + 1.0
    starts = [e for e in events if e.event == "outage_start"]
    ends = [e for e in events if e.event == "outage_end"]
    assert len(starts) == 2 and len(ends) == 2, [(e.event, e.error) for e in events]
    assert "lost" in starts[0].error and "frozen" in starts[1].error
    assert 1.0 < dropped < 1.5 + 2.0, dropped
    # The immediate first attempt met a controller that refused connections; the frozen one may come back
    # during the first attempt's wait for data (connect_timeout).
    assert ends[0].attempt >= 2, ends[0]


def test_a_pose_asked_for_outside_the_buffer_is_not_an_outage_and_ends_one(loopback):
    """`PoseTimeError` (a time the robot's buffer does not hold) is the data's answer, not a device fault: raised
    at once, no outage. Asked during a drop, it ends the outage once the robot is back and is raised: before,
    the wrapper retried that time for ever (a monitor on a ROS 2 robot, whose buffer starts afresh at a
    reconnect, never sampled again)."""
    events = []
    with launch(loopback(50), "ur10", "5.11", initial_q=START_Q) as sim:
        cfg = URRobotConfig(host=sim.host, read_only=True, tcp_offset=(0, 0, 0.1, 0, 0, 0), connect_timeout=1.0,
                            frozen_timeout=0.3)
        with Reconnecting("robot", URRobot(cfg), FAST, on_event=events.append) as rc:
            rc.read()
            with pytest.raises(PoseTimeError) as old:
                rc.pose_at(time.time() - 3600.0)
            assert not old.value.ahead and events == []
            # A frame stamped ahead of the newest state: pose_at_frame waits for the states after it.
            t_ahead = time.time() + 0.05
            np.testing.assert_allclose(pose_at_frame(rc, t_ahead), rc.read().T_base_flange, atol=1e-9)
            sim.drop(refuse_s=0.5)
            time.sleep(0.2)
            t0 = time.monotonic()
            with pytest.raises(PoseTimeError):
                rc.pose_at(time.time() - 3600.0)     # the drop first, then, reconnected, the answer
            assert time.monotonic() - t0 < 5.0 and not rc.in_outage
    assert [e.event for e in events][0] == "outage_start" and events[-1].event == "outage_end", events


def test_a_camera_following_a_wrapped_robot_rides_out_the_robots_outage(loopback):
    events = []
    with launch(loopback(47), "ur10", "5.11", initial_q=START_Q) as sim:
        cfg = URRobotConfig(host=sim.host, read_only=True, tcp_offset=(0, 0, 0.1, 0, 0, 0), connect_timeout=1.0,
                            frozen_timeout=0.3)
        with Reconnecting("robot", URRobot(cfg), FAST, on_event=events.append) as robot:
            cam = CAMERAS.create({"backend": "rendered"})
            cam.follow(lambda: robot.read().T_base_flange)    # as handeye.app.devices.open_camera(cfg, robot) does
            with Reconnecting("camera", cam, FAST, on_event=events.append) as camera:
                assert robot.config.host == sim.host           # the device's attributes show through
                camera.read()
                sim.drop(refuse_s=1.0)
                time.sleep(0.2)
                frame = camera.read()
    assert frame.index == 1
    np.testing.assert_allclose(frame.truth["T_base_flange"], kin.forward(START_Q, "ur10"), atol=1e-9)
    # The robot's outage was ridden out inside the camera's read; the camera itself never went away.
    assert [(e.device, e.event) for e in events if e.event != "reconnect_failed"] == [
        ("robot", "outage_start"), ("robot", "outage_end")]
