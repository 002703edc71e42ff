"""Faults injected in the simulated controller surface as the
documented errors through ur_rtde and URRobot, and reconnect() recovers."""

import os
import signal
import threading
import time

import numpy as np
import pytest

from handeye.drivers.errors import ConnectionLostError, DeviceError, RobotStoppedError
from tests.simulated_ur import START_Q, connect_robot, robot_config



@pytest.fixture(scope="module")
def sim(sim_factory):
    return sim_factory(2, controller="5.11")


@pytest.fixture(scope="module")
def robot(sim):
    r = connect_robot(robot_config(sim.host))
    yield r
    r.disconnect()


def _moved(robot, dx=0.05):
    T = robot.read().T_base_flange.copy()
    T[0, 3] += dx
    return T


def test_protective_stop_during_a_move_raises_robot_stopped_then_recovers(robot, sim):
    target = _moved(robot, 0.3)
    timer = threading.Timer(0.4, sim.protective_stop)
    timer.start()
    with pytest.raises(RobotStoppedError, match="protective stop"):
        robot.move_to(target)
    timer.join()
    st = robot.read()
    assert st.safety_mode == 3 and st.is_still
    # still stopped: refused without sending anything
    sim.clear_log()
    with pytest.raises(RobotStoppedError):
        robot.move_to(target)
    assert sim.state()["commands"] == []
    sim.unlock_protective_stop()
    time.sleep(0.05)  # let the next state package arrive
    with pytest.raises(DeviceError, match="reconnect"):
        robot.move_to(target)  # the safety stop ended the control script
    robot.reconnect()
    st = robot.move_to(target)
    np.testing.assert_allclose(st.T_base_flange, target, atol=1e-6)


def test_emergency_stop_raises_robot_stopped(robot, sim):
    sim.command("sim emergency_stop")
    time.sleep(0.05)
    try:
        with pytest.raises(RobotStoppedError, match="emergency"):
            robot.move_to(_moved(robot))
    finally:
        sim.command("sim release")
    robot.reconnect()


def test_dropped_connection_raises_connection_lost_then_reconnects(robot, sim):
    sim.drop(refuse_s=0.5)
    time.sleep(0.1)
    with pytest.raises(ConnectionLostError, match="dropped"):
        robot.read()
    with pytest.raises(ConnectionLostError):
        robot.move_to(_moved(robot))
    time.sleep(0.5)
    robot.reconnect()
    t0 = robot.read().t_controller
    time.sleep(0.1)
    assert robot.read().t_controller > t0


def test_short_freeze_during_a_move_is_detected_within_a_second(robot, sim):
    target = _moved(robot, 0.3)
    started = []
    timer = threading.Timer(0.3, lambda: (started.append(time.monotonic()), sim.freeze(2.0)))
    timer.start()
    with pytest.raises(ConnectionLostError, match="frozen"):
        robot.move_to(target)
    detected = time.monotonic() - started[0]
    timer.join()
    assert robot.config.frozen_timeout <= detected < 1.0
    with pytest.raises(ConnectionLostError):  # stays failed until reconnect()
        robot.read()
    time.sleep(max(0.0, 2.0 - (time.monotonic() - started[0])))
    robot.reconnect()
    st = robot.move_to(_moved(robot, 0.02))
    assert st.is_still


def test_long_freeze_is_detected_and_disconnect_does_not_wait_for_ur_rtde(robot, sim):
    robot.read()
    sim.freeze(60.0)
    try:
        time.sleep(0.7)  # > frozen_timeout (0.5 s), < ur_rtde's own 2.5 s read deadline
        with pytest.raises(ConnectionLostError, match="frozen"):
            robot.read()
        t0 = time.monotonic()
        robot.disconnect()  # the stale client is killed, not torn down through ur_rtde
        assert time.monotonic() - t0 < 1.0
        time.sleep(3.0)  # past ur_rtde's deadline: its self-reconnect would run now, in no process of ours
    finally:
        sim.freeze(0.0)
    robot.connect()
    st = robot.move_to(_moved(robot))
    assert st.is_still
    np.testing.assert_allclose(robot.read().q[3:], START_Q[3:], atol=0.5)


def _client_pid(host: str) -> int:
    """The RTDE client process this test process started for ``host``."""
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                cmd = f.read().split(b"\0")
            with open(f"/proc/{entry}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
        except OSError:
            continue
        if ppid == os.getpid() and b"handeye.drivers.robot.ur_client" in cmd and host.encode() in b" ".join(cmd):
            return int(entry)
    raise AssertionError(f"no RTDE client process for {host}")


def test_a_native_crash_of_the_rtde_client_is_a_connection_lost_error(robot, sim):
    robot.read()
    os.kill(_client_pid(sim.host), signal.SIGSEGV)  # what a heap corruption in ur_rtde ends as
    time.sleep(0.3)
    with pytest.raises(ConnectionLostError, match="SIGSEGV"):
        robot.read()
    robot.reconnect()
    assert robot.move_to(_moved(robot, 0.02)).is_still


def test_pose_at_after_a_freeze_names_the_frozen_stream(robot, sim):
    robot.read()
    sim.freeze(1.0)
    try:
        time.sleep(0.7)
        with pytest.raises(ConnectionLostError, match="frozen"):
            robot.pose_at(time.time())
    finally:
        time.sleep(0.4)
    robot.reconnect()
    assert robot.read().t_controller > 0
