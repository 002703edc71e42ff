"""`type = "ur_sim"` from a TOML table: the registered robot launches its own simulator."""

import numpy as np
import pytest

from handeye.drivers.errors import DeviceError
from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.registry import ROBOTS
from handeye.drivers.robot.ur import URKinematics
from handeye.mocks.ur_sim.robot import URSimRobot, URSimRobotConfig

from tests.simulated_ur import START_Q, free_host


def test_ur_sim_robot_launches_moves_and_stops_its_simulator():
    table = {
        "type": "ur_sim", "host": free_host(5), "model": "ur10", "controller": "3.15",
        "initial_q": list(START_Q), "sim_tcp_offset": [0, 0, 0.12, 0, 0, 0],
        "workspace_min": [-1.3, -1.0, 0.0], "workspace_max": [1.3, 1.0, 1.2], "speed": 0.5, "acceleration": 2.0,
    }
    robot = ROBOTS.create(table)
    with robot:
        sim = robot.sim
        st = robot.read()
        np.testing.assert_allclose(st.T_base_flange, kin.forward(START_Q, "ur10"), atol=1e-9)
        np.testing.assert_allclose(robot.T_flange_tcp[:3, 3], [0, 0, 0.12])
        target = st.T_base_flange.copy()
        target[2, 3] += 0.05
        np.testing.assert_allclose(robot.move_to(target).T_base_flange, target, atol=1e-6)
    assert robot.sim is None and sim.proc.poll() is not None


def test_the_simulator_declares_itself_and_needs_its_controller_for_a_program():
    robot = URSimRobot(URSimRobotConfig(host="127.0.0.1", workspace_min=(-1, -1, 0), workspace_max=(1, 1, 1)))
    assert robot.simulated and robot.kinematics == URKinematics("ur10")
    with pytest.raises(DeviceError, match="not connected"):
        robot.start_program({"waypoints": []})
