"""URRobot.check_target without a controller: every limit, on targets and along paths."""

import numpy as np
import pytest

from handeye.drivers.errors import LimitViolationError
from handeye.calib.transforms import from_ur_pose
from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.ur import URRobot, URRobotConfig

Q0 = np.array([0.0, -1.2, 1.6, -1.97, -1.5708, 0.0])  # flange at (-0.86, -0.16, 0.38), z down
T0 = kin.forward(Q0, "ur10")


def _robot(**kw) -> URRobot:
    cfg = dict(host="10.0.0.2", workspace_min=(-1.3, -0.8, 0.2), workspace_max=(1.3, 1.0, 1.2), max_tilt_deg=30.0)
    cfg.update(kw)
    robot = URRobot(URRobotConfig(**cfg))
    robot._T_flange_tcp = from_ur_pose([0, 0, 0.15, 0, 0, 0])  # as read from the controller on connect
    return robot


def _shifted(dx=0.0, dy=0.0, dz=0.0):
    T = T0.copy()
    T[:3, 3] += [dx, dy, dz]
    return T


def test_a_reachable_target_inside_all_limits_passes_for_both_motions():
    robot = _robot()
    q = robot.check_target(_shifted(0.1, 0.05, 0.0), "linear", q_start=Q0)
    np.testing.assert_allclose(kin.forward(q, "ur10"), _shifted(0.1, 0.05, 0.0), atol=1e-9)
    np.testing.assert_allclose(robot.check_target(_shifted(0.1), "joint", q_start=Q0),
                               robot.check_target(_shifted(0.1), "linear", q_start=Q0), atol=1e-9)


def test_the_tcp_counts_not_only_the_flange():
    # flange 0.38 -> 0.33 m stays above z = 0.2, the TCP 15 cm below it does not
    with pytest.raises(LimitViolationError, match="TCP at"):
        _robot().check_target(_shifted(dz=-0.05), "linear", q_start=Q0)


def test_tilt_limit():
    tilted = T0 @ from_ur_pose([0, 0, 0, np.deg2rad(40), 0, 0])
    with pytest.raises(LimitViolationError, match="tilted 40.0 deg"):
        _robot().check_target(tilted, "joint", q_start=Q0)
    assert _robot(max_tilt_deg=45.0).check_target(tilted, "joint", q_start=Q0).shape == (6,)


def test_joint_limits_on_the_target():
    robot = _robot(joint_min=(-0.1, -6.28, -6.28, -6.28, -6.28, -6.28), joint_max=(0.1, 6.28, 6.28, 6.28, 6.28, 6.28))
    q = Q0.copy()
    q[0] = 0.3
    with pytest.raises(LimitViolationError, match="joint_min/joint_max"):
        robot.check_target(kin.forward(q, "ur10"), "joint", q_start=Q0)
    with pytest.raises(LimitViolationError, match="outside joint_min/joint_max"):
        robot.check_target(kin.forward(q, "ur10"), "joint", q_start=Q0, q_target=q)


def test_the_movej_path_is_checked_not_just_the_target():
    robot = _robot(max_tilt_deg=90.0)
    q = Q0.copy()
    q[0] = 3.0  # half a base turn: the flange (radius 0.88 m) sweeps through y = -0.88 < -0.8
    with pytest.raises(LimitViolationError, match="moveJ path"):
        robot.check_target(kin.forward(q, "ur10"), "joint", q_start=Q0, q_target=q)


def test_malformed_targets_and_missing_box():
    robot = _robot()
    bad = T0.copy()
    bad[0, 0] = 2.0
    with pytest.raises(LimitViolationError, match="rigid"):
        robot.check_target(bad, q_start=Q0)
    with pytest.raises(LimitViolationError, match="finite"):
        robot.check_target(np.full((4, 4), np.nan), q_start=Q0)
    with pytest.raises(LimitViolationError, match="motion"):
        robot.check_target(T0, "circular", q_start=Q0)
    ro = URRobot(URRobotConfig(host="10.0.0.2", read_only=True, tcp_offset=(0, 0, 0, 0, 0, 0)))
    with pytest.raises(LimitViolationError, match="workspace"):
        ro.check_target(T0, q_start=Q0)
