"""The robot base declares what the app asks of any backend: limits, a limit check, a kinematic model, and for
a simulator its true pose and a production program; limits and model come from a config without a driver."""

import math

import numpy as np
import pytest

from handeye.calib.robot_error import UR_ALPHA, ur_dh_error_factor
from handeye.drivers.errors import DeviceError
from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.base import Robot, RobotLimits, RobotState
from handeye.drivers.robot.registry import kinematic_model, robot_limits
from handeye.drivers.robot.ur import URKinematics, URKinematicError, URRobotConfig

POSE = np.eye(4)


class Readable(Robot):
    """Reads, moves and stops, but declares none of the app's capabilities."""

    def __init__(self, config=None):
        self.config = config
        self.calls = []

    def connect(self):
        self.calls.append("connect")

    def disconnect(self):
        self.calls.append("disconnect")
        raise DeviceError("half dead")

    @property
    def is_connected(self):
        return True

    def read(self):
        return RobotState(0.0, 0.0, POSE, np.zeros(6), np.zeros(6), 7, 1)

    def pose_at(self, t_host):
        return POSE

    def move_to(self, T_base_flange):
        return self.read()

    def stop(self):
        pass


class Complete(Readable):
    """`Readable` plus the declared capabilities: a box, a check that accepts everything, no kinematic model."""

    @classmethod
    def limits_for(cls, config):
        return RobotLimits((-1.0, -1.0, 0.0), (1.0, 1.0, 1.0), 0.2, 0.8)

    @classmethod
    def kinematics_for(cls, config):
        return None

    def check_target(self, T_base_flange, *, q_start=None):
        return np.zeros(6)


def test_a_backend_missing_a_capability_cannot_be_built():
    with pytest.raises(TypeError) as e:
        Readable()
    for name in ("check_target", "limits_for", "kinematics_for"):
        assert name in str(e.value)


def test_the_base_defaults_of_a_real_backend():
    robot = Complete()
    assert not robot.simulated
    assert robot.limits == RobotLimits((-1.0, -1.0, 0.0), (1.0, 1.0, 1.0), 0.2, 0.8)
    assert robot.kinematics is None and robot.shared_error_factor(np.zeros((2, 6))) is None
    assert robot.true_flange_pose() is POSE         # a real robot's best is its reading
    with pytest.raises(DeviceError, match="runs no production program"):
        robot.start_program({"waypoints": []})
    robot.reconnect()                                # the disconnect's error is ignored, then it connects
    assert robot.calls == ["disconnect", "connect"]


def _ur_config(**kw) -> URRobotConfig:
    return URRobotConfig(host="127.0.0.1", workspace_min=(-0.9, -0.8, 0.1), workspace_max=(0.9, 0.8, 1.2),
                         speed=0.3, acceleration=1.5, **kw)


def test_ur_limits_and_kinematic_model_come_from_the_config_alone():
    cfg = _ur_config(model="ur5e", kinematic_error=URKinematicError(joint_offset_deg=0.05))
    assert robot_limits(cfg) == RobotLimits((-0.9, -0.8, 0.1), (0.9, 0.8, 1.2), 0.3, 1.5)
    assert robot_limits(URRobotConfig(host="h", read_only=True)).workspace_min is None
    model = kinematic_model(cfg)
    assert model == URKinematics("ur5e", cfg.kinematic_error) and model.name == "ur5e"
    q = np.array([[0.1, -1.2, 1.5, -1.9, -1.6, 0.3], [0.4, -1.0, 1.2, -1.7, -1.5, -0.2]])
    np.testing.assert_allclose(model.forward(q), kin.forward(q, "ur5e"))
    np.testing.assert_allclose(model.inverse_nearest(model.forward(q[0]), q[0] + 0.01), q[0], atol=1e-9)
    g = kin.geometry("ur5e")
    expected = ur_dh_error_factor(q, math.radians(0.05), cfg.kinematic_error.link_length_m,
                                  math.radians(cfg.kinematic_error.twist_deg), dh={"d": g.d, "a": g.a, "alpha": UR_ALPHA})
    np.testing.assert_allclose(model.shared_error_factor(q), expected)
    assert kinematic_model(_ur_config()).shared_error_factor(q) is None   # no kinematic_error configured

