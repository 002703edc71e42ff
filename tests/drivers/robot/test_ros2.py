"""The read-only ROS 2 robot through real DDS on loopback: a publisher in another process (tests.ros2_publisher)."""

import threading
import time

import numpy as np
import pytest

from handeye.calib import transforms as tf
from handeye.app.outage import ReconnectConfig, Reconnecting
from handeye.drivers.errors import ConnectionLostError, DeviceError, LimitViolationError, PoseTimeError
from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.ros2 import UR_JOINTS, Ros2Robot, Ros2RobotConfig

pytestmark = [pytest.mark.slow, pytest.mark.every_python]  # the ROS 2 path on every Python (make test-other)
PREFIX = "/robot_test"
Q = [0.3, -1.9, 1.5, -1.2, -1.4, 0.4]
TCP = (0.01, -0.02, 0.15, 0.1, -0.2, 0.3)  # an unusual TCP: forgetting to remove it shows in every pose


@pytest.fixture(scope="module")
def publisher(ros2_publisher):
    return ros2_publisher(PREFIX)


def robot(**kw) -> Ros2Robot:
    return Ros2Robot(Ros2RobotConfig(**{"pose_topic": f"{PREFIX}/pose", "joint_states_topic": f"{PREFIX}/joint_states",
                                        "tcp_offset": TCP, "frozen_timeout": 0.3, **kw}))


def publish(publisher, n=200, rate=100, q=Q, qd=(0.0,) * 6, names=UR_JOINTS, tcp=TCP, order=range(6)):
    """Stream joint states (listed in ``order``) and the TCP pose of ``q`` (ur_robot_driver's, with TCP
    ``tcp``) in a thread."""
    T_tcp = kin.forward(np.array(q), "ur10") @ tf.from_ur_pose(np.array(tcp))
    order = list(order)
    cmd = {"cmd": "robot", "n": n, "rate": rate, "q": [q[i] for i in order], "qd": [qd[i] for i in order],
           "names": [names[i] for i in order],
           "tcp_pose": tf.to_ur_pose(T_tcp).tolist()}
    thread = threading.Thread(target=publisher.send, args=(cmd,))
    thread.start()
    return thread


@pytest.mark.parametrize("source", ["pose", "joints"])
def test_the_flange_pose_comes_from_the_tcp_pose_or_the_joints(publisher, source):
    """TCP pose with the configured TCP removed, or the UR kinematics of the joints (listed in any order):
    the flange pose either way, with the joints recorded, still as the RTDE driver says."""
    thread = publish(publisher, order=[3, 4, 5, 0, 1, 2])
    try:
        with robot(source=source) as r:
            threading.Event().wait(0.2)  # a few states in the buffer
            state = r.read()
            T = r.pose_at(state.t_host - 0.05)
    finally:
        thread.join()
    truth = kin.forward(np.array(Q), "ur10")
    np.testing.assert_allclose(state.T_base_flange, truth, atol=1e-6)
    np.testing.assert_allclose(T, truth, atol=1e-6)
    np.testing.assert_allclose(state.q, Q)
    assert state.is_still and state.robot_mode == -1


def test_moving_joints_are_not_a_standstill(publisher):
    thread = publish(publisher, qd=(0.0, 0.0, 0.05, 0.0, 0.0, 0.0))
    try:
        with robot() as r:
            assert not r.read().is_still
    finally:
        thread.join()


def test_missing_joint_names_are_a_typed_error(publisher):
    thread = publish(publisher, n=400, names=[f"ur_{n}" for n in UR_JOINTS])
    try:
        with pytest.raises(DeviceError, match="has no joint 'shoulder_pan_joint'.*set robot.joint_prefix"):
            with robot() as r:
                r.read()
        with robot(joint_prefix="ur_") as r:
            assert r.read().is_still
    finally:
        thread.join()


def test_a_stopped_publisher_is_a_connection_lost_and_the_robot_is_read_only(publisher):
    thread = publish(publisher, n=60)
    with robot() as r:
        T = r.read().T_base_flange
        with pytest.raises(DeviceError, match="read-only"):
            r.move_to(T)
        with pytest.raises(LimitViolationError, match="read-only"):
            r.check_target(T)
        thread.join()
        with pytest.raises(ConnectionLostError, match="no new message on /robot_test/pose"):
            for _ in range(100):
                r.read()
                threading.Event().wait(0.02)


def test_a_restarted_publisher_ends_the_outage_of_a_pose_asked_for_before_it(publisher):
    """ur_robot_driver restarted while a monitor asked for the pose at a frame's stamp: the outage ends when the
    driver is back, with `PoseTimeError` (the stamp is older than the buffer, which starts afresh). Before, the
    reconnect wrapper retried that stamp for ever: the monitor never sampled again."""
    events, restarted = [], []
    thread = publish(publisher, n=60)
    with Reconnecting("robot", robot(), ReconnectConfig(initial_s=0.1, max_s=0.2), on_event=events.append) as r:
        r.read()
        thread.join()                                   # the driver stops publishing
        threading.Event().wait(0.5)                     # ... long enough to be frozen
        timer = threading.Timer(0.5, lambda: restarted.append(publish(publisher, n=150)))
        timer.start()
        with pytest.raises(PoseTimeError, match="before the robot state buffer"):
            r.pose_at(time.time())                      # a frame stamped while the driver was away
        timer.join()
        restarted[0].join()
    kinds = [e.event for e in events]
    assert kinds[0] == "outage_start" and kinds[-1] == "outage_end" and not r.in_outage, kinds
    assert "no new message" in events[0].error


def test_no_publisher_is_a_typed_error(ros2_graph):
    with pytest.raises(DeviceError, match="no publisher on /nobody/joint_states"):
        Ros2Robot(Ros2RobotConfig(joint_states_topic="/nobody/joint_states", source="joints",
                                  connect_timeout=0.5)).connect()


def test_the_pose_source_needs_the_tcp_offset():
    with pytest.raises(Exception, match="tcp_offset is required with source = 'pose'"):
        Ros2RobotConfig()


def test_the_executor_thread_outlives_a_node_destroyed_while_it_waits():
    """A node closed from another thread while the executor builds its wait set raises rclpy's InvalidHandle
    there (seen on a loaded CI host: the thread ended and no node got a message again); the spin goes on until
    shutdown."""
    from rclpy.exceptions import InvalidHandle
    from rclpy.executors import ExternalShutdownException

    from handeye.drivers.ros2 import spin_until_shutdown

    class Executor:
        def __init__(self, *outcomes):
            self.outcomes, self.spins = list(outcomes), 0

        def spin(self):
            self.spins += 1
            if self.outcomes:
                raise self.outcomes.pop(0)

    e = Executor(InvalidHandle("cannot use Destroyable because destruction was requested"), InvalidHandle("again"))
    spin_until_shutdown(e)
    assert e.spins == 3
    e = Executor(ExternalShutdownException())
    spin_until_shutdown(e)
    assert e.spins == 1
    with pytest.raises(ValueError):          # anything else is a defect to see, not to spin past
        spin_until_shutdown(Executor(ValueError("a callback's bug")))
