"""The simulated arm with a kinematic error: it reports nominal poses, the camera sees the true flange."""

import numpy as np

from handeye.app import devices
from handeye.app.config import Config
from handeye.calib import transforms as tf
from handeye.calib.vision.extract import TargetConfig, extract
from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.registry import ROBOTS
from handeye.mocks.ur_sim.controller import SimController
from handeye.mocks.ur_sim.program import Program
from handeye.mocks.ur_sim.truth import SimRobotError, TrueArm

from tests.simulated_ur import START_Q, free_host

# Flange positions well in front of the base, the marker facing the default rendered camera.
CELL_Q = (0.367792, -3.559685, 1.448735, -1.704477, -0.767569, 0.521542)


def test_realistic_dh_error_moves_the_true_flange_by_a_fraction_of_a_mm_to_a_few_mm():
    err = SimRobotError(repeatability_m=0.0, repeatability_deg=0.0)
    rng = np.random.default_rng(3)
    q = np.array(START_Q) + rng.uniform(-0.5, 0.5, size=(50, 6))
    dist = []
    for seed in range(5):
        arm = TrueArm("ur10", err.model_copy(update={"seed": seed}))
        dist += [np.linalg.norm(arm.flange(qi)[:3, 3] - kin.forward(qi, "ur10")[:3, 3]) for qi in q]
    dist = np.array(dist) * 1e3
    # RealisticProfile's magnitudes give 1-3 mm at the flange of an uncalibrated UR10 (handeye.calib.simulate).
    assert 0.2 < np.median(dist) < 4.0, np.median(dist)
    assert dist.max() < 8.0


def test_each_stop_lands_with_a_fresh_repeatability_error_that_the_report_does_not_show():
    err = SimRobotError(joint_offset_deg=0.0, link_length_m=0.0, twist_deg=0.0, repeatability_m=1e-4,
                        repeatability_deg=0.01, seed=1)
    ctl = SimController("ur10", "5.11", START_Q, robot_error=err)
    q1 = np.array(START_Q) + [0.2, 0.1, -0.1, 0.0, 0.1, 0.3]
    ctl.program = Program.from_dict({"waypoints": [{"q": list(START_Q), "pause_s": 0.05},
                                                   {"q": q1.tolist(), "pause_s": 0.05}], "speed": 3.0,
                                     "acceleration": 20.0})
    at_start_reported, at_start_true = [], []
    was_moving = False
    for _ in range(20000):
        ctl.tick()
        moving = ctl.motion is not None
        if was_moving and not moving and np.allclose(ctl.q, START_Q, atol=1e-9):
            at_start_reported.append(ctl.T_base_flange)
            at_start_true.append(ctl.T_base_flange_true)
        was_moving = moving
        if len(at_start_true) == 6:
            break
    assert len(at_start_true) == 6
    # The controller reports the same pose at every visit of the stop; the real flange is elsewhere each time.
    np.testing.assert_allclose(np.array(at_start_reported), np.broadcast_to(kin.forward(START_Q, "ur10"), (6, 4, 4)),
                               atol=1e-12)
    rot, trans = tf.pose_error(np.array(at_start_true), np.array(at_start_reported))
    assert np.all(trans > 1e-6) and np.all(trans < 8e-4), trans       # 0.1 mm 1-sigma per axis
    assert np.all(np.rad2deg(rot) < 0.08)
    assert len({round(float(t), 9) for t in trans}) == 6


def test_ur_sim_robot_reports_nominal_kinematics_while_the_rendered_marker_follows_the_true_flange():
    # A large link error (3 mm 1-sigma) so that the marker measurement can tell the two poses apart.
    err = {"joint_offset_deg": 0.05, "link_length_m": 0.003, "twist_deg": 0.05, "seed": 4}
    cfg = Config.model_validate({
        "robot": {"type": "ur_sim", "host": free_host(8), "model": "ur10", "controller": "5.11",
                  "initial_q": list(CELL_Q), "workspace_min": [0.6, -0.2, 0.2], "workspace_max": [1.2, 0.4, 0.8],
                  "tcp_offset": [0.0, 0.0, 0.1, 0.0, 0.0, 0.0], "sim_robot_error": err},
        "camera": {"backend": "rendered", "seed": 1},
    })
    robot = devices.open_robot(cfg, read_only=True)
    with robot, devices.open_camera(cfg, robot) as camera:
        reported = robot.read().T_base_flange
        true = robot.true_flange_pose()
        np.testing.assert_allclose(reported, kin.forward(CELL_Q, "ur10"), atol=1e-6)
        arm = TrueArm("ur10", SimRobotError(**err))
        np.testing.assert_allclose(true, arm.flange(CELL_Q), atol=1e-9)  # no motion yet: no stop error
        gap_mm = np.linalg.norm(true[:3, 3] - reported[:3, 3]) * 1e3
        assert 3.0 < gap_mm < 40.0, gap_mm
        frame = camera.read()
        np.testing.assert_allclose(frame.truth["T_base_flange"], true, atol=1e-12)
        m = extract(frame.color, frame.depth, frame.intrinsics, TargetConfig())
        c = camera.config
        T_cam_base = tf.invert(np.asarray(c.T_base_cam))
        X = np.asarray(c.T_flange_marker)
        seen_true = np.linalg.norm(m.point_cam - (T_cam_base @ true @ X)[:3, 3]) * 1e3
        seen_reported = np.linalg.norm(m.point_cam - (T_cam_base @ reported @ X)[:3, 3]) * 1e3
        assert seen_true < seen_reported - 2.0, (seen_true, seen_reported)


def test_without_a_robot_error_the_truth_is_the_reported_pose():
    robot = ROBOTS.create({"type": "ur_sim", "host": free_host(9), "model": "ur10", "initial_q": list(START_Q),
                           "read_only": True, "tcp_offset": [0.0, 0.0, 0.1, 0.0, 0.0, 0.0]})
    with robot:
        np.testing.assert_allclose(robot.true_flange_pose(), robot.read().T_base_flange, atol=0)
        np.testing.assert_allclose(np.array(robot.sim.state()["T_base_flange_true"]),
                                   kin.forward(START_Q, "ur10"), atol=1e-9)
