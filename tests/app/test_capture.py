"""A monitor's sample keeps its frame when the robot stood still at the frame's stamp and a guard after it, though
the robot left before the measurement was done; a frame the robot left during is skipped. The real ur_rtde client
against the simulated controller (eye-to-hand: ``A_i = T_base_flange``)."""

import time

import numpy as np

from handeye.app.runs.monitor import CAPTURE_GUARD_S, left_standstill
from handeye.calib import transforms as tf
from handeye.drivers.robot.ur import URRobot, URRobotConfig
from handeye.mocks.ur_sim import launch
from tests.simulated_ur import START_Q


def leave_time(robot, T, t0: float, t1: float) -> float:
    """When the robot's recorded pose first is 1 mm / 0.2 deg off ``T`` (the monitor's standstill tolerance),
    between host times ``t0`` (at ``T``) and ``t1`` (away), by bisection over its buffered states."""
    for _ in range(40):
        mid = 0.5 * (t0 + t1)
        rot, trans = tf.pose_error(robot.pose_at(mid), T)
        if trans < 1e-3 and rot < np.deg2rad(0.2):
            t0 = mid
        else:
            t1 = mid
    return t1


def test_a_frame_exposed_during_the_standstill_is_kept_after_the_robot_left(loopback):
    with launch(loopback(51), "ur10", "5.11", initial_q=START_Q) as sim:
        robot = URRobot(URRobotConfig(host=sim.host, tcp_offset=(0, 0, 0.1, 0, 0, 0), speed=0.25, acceleration=4.0,
                                      workspace_min=(-2.0, -2.0, -2.0), workspace_max=(2.0, 2.0, 2.0)))
        robot.connect()
        try:
            time.sleep(0.5)
            still = robot.read()
            exposed = still.t_host - 0.3                     # a frame of the standstill
            robot.move_to(still.T_base_flange @ tf.make_transform(np.eye(3), [0.0, 0.0, 0.05]))
            left = leave_time(robot, still.T_base_flange, still.t_host, robot.read().t_host)
            # Measured while the robot left: the frame and its pose are of one place.
            assert left_standstill(robot, still.T_base_flange, exposed) is None
            assert left_standstill(robot, still.T_base_flange, left - 1.5 * CAPTURE_GUARD_S) is None
            # A frame stamped as the robot left, or within the guard before it left: skipped.
            assert left_standstill(robot, still.T_base_flange, left + 0.05) == "robot moved during the capture"
            assert left_standstill(robot, still.T_base_flange, left - 0.5 * CAPTURE_GUARD_S) == \
                "robot moved during the capture"
            # A frame older than the robot states kept has no pose.
            assert left_standstill(robot, still.T_base_flange, time.time() - 3600.0) == \
                "no robot pose at the frame's time"
        finally:
            robot.disconnect()
