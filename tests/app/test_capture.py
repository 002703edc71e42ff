"""A monitor's sample keeps its frame when the robot stood still at the frame's stamp and a guard after it, though
the robot left before the measurement was done; a frame the robot left during is skipped. The real ur_rtde client
against the simulated controller (eye-to-hand: ``A_i = T_base_flange``)."""

import time

import numpy as np

from app.runs.monitor import CAPTURE_GUARD_S, left_standstill
from calib import transforms as tf
from drivers.robot.ur import URRobot, URRobotConfig
from mocks.ur_sim import launch

START_Q = (0.0, -1.2, 1.6, -1.97, -1.5708, 0.0)


def test_a_frame_exposed_during_the_standstill_is_kept_after_the_robot_left(loopback):
    with launch(loopback(51), "ur10", "5.11", initial_q=START_Q) as sim:
        robot = URRobot(URRobotConfig(host=sim.host, tcp_offset=(0, 0, 0.1, 0, 0, 0), speed=0.25, acceleration=4.0,
                                      workspace_min=(-2.0, -2.0, -2.0), workspace_max=(2.0, 2.0, 2.0)))
        robot.connect()
        try:
            time.sleep(0.5)
            still = robot.read()
            exposed = still.t_host - 0.3                     # a frame of the standstill
            leaving = time.time()
            robot.move_to(still.T_base_flange @ tf.make_transform(np.eye(3), [0.0, 0.0, 0.05]))
            # Measured while the robot left: the frame and its pose are of one place.
            assert left_standstill(robot, still.T_base_flange, exposed) is None
            # A frame stamped as the robot left, or within the guard before it left: skipped.
            assert left_standstill(robot, still.T_base_flange, leaving + 0.1) == "robot moved during the capture"
            assert left_standstill(robot, still.T_base_flange, leaving - 0.2 * CAPTURE_GUARD_S) == \
                "robot moved during the capture"
            # A frame older than the robot states kept has no pose.
            assert left_standstill(robot, still.T_base_flange, time.time() - 3600.0) == \
                "no robot pose at the frame's time"
        finally:
            robot.disconnect()
