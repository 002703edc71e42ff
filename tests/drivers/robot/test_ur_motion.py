"""The real ur_rtde RTDEReceiveInterface / RTDEControlInterface, through URRobot,
against the simulated e-Series UR10 controller."""

import threading
import time

import numpy as np
import pytest

from handeye.drivers.errors import DeviceError, LimitViolationError
from handeye.calib.transforms import from_ur_pose, make_transform, pose_error
from handeye.drivers.robot import ur_kinematics as kin
from tests.simulated_ur import SIM_TCP, controller_stamps, START_Q, connect_robot, robot_config, truth_flange



@pytest.fixture(scope="module")
def sim(sim_factory):
    return sim_factory(1, controller="5.11")


@pytest.fixture(scope="module")
def robot(sim):
    # y >= -0.8 m: a half turn of the base (radius 0.88 m) must leave the box on its way
    r = connect_robot(robot_config(sim.host, workspace_min=(-1.3, -0.8, 0.0)))
    yield r
    r.disconnect()


@pytest.fixture
def home(robot, sim):
    """Every test starts at the same idle pose with an empty command log."""
    if np.max(np.abs(robot.read().q - START_Q)) > 1e-6:
        robot.move_joints(START_Q)
    sim.clear_log()
    return robot.read()


def test_stream_rate_is_500_hz_for_e_series(robot):
    stamps = controller_stamps(robot, 1.0, poll=0.0005)
    # the controller stamps 2 ms apart; the client sees (nearly) every package
    assert np.median(np.diff(stamps)) == pytest.approx(0.002, abs=1e-9)
    # A starved simulator drops its backlog (controller time then lags the wall clock), never gains.
    assert 0.6 < stamps[-1] - stamps[0] < 1.05
    assert len(stamps) > 0.5 * 500  # a loaded machine may starve the client poller now and then


def test_flange_pose_equals_simulator_truth_with_tcp_removed(robot, sim, home):
    truth = truth_flange(sim)
    np.testing.assert_allclose(home.T_base_flange, truth, atol=1e-9)
    np.testing.assert_allclose(robot.T_flange_tcp, from_ur_pose(SIM_TCP), atol=1e-12)
    # the controller's TCP pose really differs from the flange by the offset
    tcp = np.array(sim.state()["T_base_tcp"])
    assert np.linalg.norm(tcp[:3, 3] - truth[:3, 3]) > 0.1
    np.testing.assert_allclose(kin.forward(home.q, "ur10"), truth, atol=1e-9)


def test_movel_reaches_target_on_a_straight_tcp_line(robot, sim, home):
    T0 = home.T_base_flange
    target = T0.copy()
    target[:3, 3] += [0.10, -0.05, -0.08]
    t_start = time.time()
    st = robot.move_to(target, motion="linear")
    rot, dist = pose_error(st.T_base_flange, target)
    assert dist < 1e-6 and rot < 1e-6
    np.testing.assert_allclose(truth_flange(sim), st.T_base_flange, atol=1e-9)
    np.testing.assert_allclose(kin.forward(st.q, "ur10"), st.T_base_flange, atol=1e-9)
    # moveL: every buffered TCP position during the move lies on the segment
    p0, p1 = (T0 @ robot.T_flange_tcp)[:3, 3], (target @ robot.T_flange_tcp)[:3, 3]
    ts = np.linspace(t_start + 0.05, st.t_host - 0.05, 25)
    P = np.array([(robot.pose_at(t) @ robot.T_flange_tcp)[:3, 3] for t in ts])
    d = (p1 - p0) / np.linalg.norm(p1 - p0)
    off_line = np.linalg.norm((P - p0) - np.outer((P - p0) @ d, d), axis=1)
    assert off_line.max() < 1e-4
    names = [c["name"] for c in sim.state()["commands"]]
    assert names == ["movel"]


def test_movej_reaches_target_with_joint_and_tcp_values_agreeing(robot, sim, home):
    q_goal = np.array(START_Q) + [0.3, 0.1, -0.2, 0.1, 0.2, -0.4]
    target = kin.forward(q_goal, "ur10")
    st = robot.move_to(target, motion="joint")
    np.testing.assert_allclose(st.q, q_goal, atol=1e-7)
    np.testing.assert_allclose(st.T_base_flange, target, atol=1e-7)
    state = sim.state()
    np.testing.assert_allclose(np.array(state["T_base_tcp"]), target @ from_ur_pose(SIM_TCP), atol=1e-7)
    assert [c["name"] for c in state["commands"]] == ["movej"]
    np.testing.assert_allclose(state["commands"][0]["args"][:6], q_goal, atol=1e-9)


def test_moves_outside_the_limits_are_refused_before_anything_is_sent(robot, sim, home):
    T0 = home.T_base_flange
    too_low = T0.copy()
    too_low[2, 3] = -0.05
    tilted = T0 @ make_transform(np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]]), [0, 0, 0])  # 90 deg about x
    far = T0.copy()
    far[:3, 3] = [1.25, 0.9, 1.1]  # inside the box, 1.8 m from the shoulder
    nan = T0.copy()
    nan[0, 3] = np.nan
    cases = [(too_low, "linear", "workspace"), (tilted, "linear", "tilted"), (far, "joint", "joint solution"),
             (nan, "linear", "finite")]
    for T, motion, msg in cases:
        with pytest.raises(LimitViolationError, match=msg):
            robot.move_to(T, motion=motion)
    # target inside the box, but the moveJ path (half a base turn) swings out of it
    with pytest.raises(LimitViolationError, match="moveJ path"):
        robot.move_joints(np.array(START_Q) + [3.0, 0, 0, 0, 0, 0])
    with pytest.raises(LimitViolationError, match="joint_min"):
        robot.move_joints(np.array(START_Q) + [7.0, 0, 0, 0, 0, 0])
    time.sleep(0.05)
    assert sim.state()["commands"] == []
    np.testing.assert_allclose(robot.read().q, START_Q, atol=1e-9)


def test_stop_interrupts_a_move(robot, sim, home):
    target = home.T_base_flange.copy()
    target[0, 3] += 0.4  # 1.6 s at 0.25 m/s
    errors = []

    def mover():
        try:
            robot.move_to(target)
        except DeviceError as exc:
            errors.append(exc)

    th = threading.Thread(target=mover)
    th.start()
    deadline = time.time() + 3.0
    while robot.read().T_base_flange[0, 3] - home.T_base_flange[0, 3] < 0.05 and time.time() < deadline:
        time.sleep(0.005)
    robot.stop()
    th.join(5.0)
    assert errors and "interrupted by stop" in str(errors[0])
    time.sleep(0.5)
    st = robot.read()
    assert st.is_still
    assert 0.05 < st.T_base_flange[0, 3] - home.T_base_flange[0, 3] < 0.35
    assert [c["name"] for c in sim.state()["commands"]] == ["movel", "stopl"]


def test_pose_at_matches_the_stream_and_refuses_times_outside_the_buffer(robot, home):
    time.sleep(0.3)  # the arm has been still for the last 0.3 s
    t0, t1 = robot.buffered_span()
    assert t1 - t0 > 0.25
    with pytest.raises(DeviceError, match="after the robot state buffer"):
        robot.pose_at(t1 + 1.0)
    with pytest.raises(DeviceError, match="before the robot state buffer"):
        robot.pose_at(t0 - 1.0)
    np.testing.assert_allclose(robot.pose_at(t1 - 0.1234567), home.T_base_flange, atol=1e-9)
