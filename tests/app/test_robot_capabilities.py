"""The app asks a robot only what `handeye.drivers.robot.base.Robot` declares: limits and the limit check for planning,
``simulated``/``kinematics``/``start_program`` for the production program, ``true_flange_pose`` for the camera."""

import numpy as np

from handeye.app import devices, planning
from handeye.app.config import load_config
from handeye.app.production import start_production
from handeye.calib import transforms as tf
from handeye.drivers.errors import LimitViolationError
from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.base import Robot, RobotLimits, RobotState
from handeye.drivers.robot.ur import URKinematics


class FakeRobot(Robot):
    """A connected robot standing at ``T`` (joints ``q``) that refuses targets above z = 1 m."""

    def __init__(self, T, q=np.zeros(6), true_T=None):
        self.config = None
        self.T, self.q, self.true_T = T, np.asarray(q, float), true_T
        self.reads, self.programs = 0, []

    @classmethod
    def limits_for(cls, config):
        return RobotLimits(None, None, 0.25, 1.0)

    @classmethod
    def kinematics_for(cls, config):
        return URKinematics("ur10")

    def check_target(self, T_base_flange, *, q_start=None):
        if T_base_flange[2, 3] > 1.0:
            raise LimitViolationError("above the box")
        return np.full(6, 0.5)

    def connect(self):
        pass

    def disconnect(self):
        pass

    @property
    def is_connected(self):
        return True

    def read(self):
        self.reads += 1
        return RobotState(0.0, 0.0, self.T, self.q, np.zeros(6), 7, 1)

    def pose_at(self, t_host):
        return self.T

    def move_to(self, T_base_flange):
        raise AssertionError("the app must not move this robot here")

    def stop(self):
        pass


class FakeSimRobot(FakeRobot):
    """The same, simulated: its true flange pose differs from the reported one, and it runs programs."""

    simulated = True

    def true_flange_pose(self):
        return self.true_T

    def start_program(self, program):
        self.programs.append(program)


def test_planner_config_takes_the_configured_backends_limits():
    cfg = load_config(None)
    pcfg = planning.planner_config(cfg)
    assert tuple(pcfg.workspace_min) == tuple(cfg.robot.workspace_min)
    assert tuple(pcfg.workspace_max) == tuple(cfg.robot.workspace_max)
    assert (pcfg.speed_m_s, pcfg.acceleration_m_s2) == (cfg.robot.speed, cfg.robot.acceleration)


def test_reachable_is_the_robots_check_target_and_a_refusal_is_none():
    check = planning.reachable(FakeRobot(np.eye(4)))
    assert check(tf.make_transform(np.eye(3), [0.0, 0.0, 0.5]), None).tolist() == [0.5] * 6
    assert check(tf.make_transform(np.eye(3), [0.0, 0.0, 1.5]), None) is None
    assert planning.reachable(None) is None


def test_production_runs_only_on_a_simulated_robot_with_its_kinematic_model():
    cfg = load_config(None)
    q0 = np.array(cfg.robot.initial_q)
    real = FakeRobot(kin.forward(q0, "ur10"), q0)
    assert start_production(real, cfg, np.random.default_rng(0), say=lambda s: None) is False
    assert real.reads == 0 and real.programs == []
    sim = FakeSimRobot(kin.forward(q0, "ur10"), q0)
    assert start_production(sim, cfg, np.random.default_rng(0), say=lambda s: None) is True
    (program,) = sim.programs
    q = np.array([w["q"] for w in program["waypoints"]])
    assert len(q) >= 2
    # Every stop solved by the robot's own model, near the start.
    assert np.linalg.norm(kin.forward(q, "ur10")[:, :3, 3] - kin.forward(q0, "ur10")[:3, 3], axis=1).max() < 0.5


def test_the_camera_follows_the_robots_true_flange_pose():
    cfg = load_config(None)
    c = cfg.camera
    T_cam_marker = tf.make_transform(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 0.6])
    T_true = np.asarray(c.T_base_cam) @ T_cam_marker @ tf.invert(np.asarray(c.T_flange_marker))
    robot = FakeSimRobot(tf.make_transform(np.eye(3), [5.0, 5.0, 5.0]), true_T=T_true)
    with devices.open_camera(cfg, robot) as camera:
        frame = camera.read()
    assert frame.color.any() and robot.reads == 0     # rendered at the true pose, never the reported one
