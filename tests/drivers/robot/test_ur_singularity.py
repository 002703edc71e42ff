"""moveL paths near a singularity: the driver refuses them before sending, consistently
with what the simulated controller executes (it protective-stops on such paths)."""

import numpy as np
import pytest

from handeye.drivers.errors import LimitViolationError
from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.ur import URRobot
from handeye.mocks.ur_sim.motion import LinearMotion
from tests.simulated_ur import START_Q, robot_config

WIDE = dict(workspace_min=(-1.5, -1.5, -0.5), workspace_max=(1.5, 1.5, 1.5), max_tilt_deg=180.0)


def _sim_failure(q0, T_target, cfg):
    """Run the simulator's own moveL model to the end; its failure reason or None."""
    m = LinearMotion(q0, T_target, cfg.speed, cfg.acceleration, cfg.model, np.eye(4), kin.UR_JOINT_LIMITS)
    for t in np.arange(0.0, m.duration + m.KNOT_DT, m.KNOT_DT):
        if m.q_at(t) is None:
            return m.failure
    return None


def test_margins_are_zero_at_each_singularity():
    q = np.array(START_Q)
    assert np.all(kin.singularity_margins(q, "ur10") > kin.SINGULARITY_REFUSE)
    wrist, elbow = q.copy(), q.copy()
    wrist[4], elbow[2] = 0.0, 0.0
    assert kin.singularity_margins(wrist, "ur10")[0] < 1e-12
    assert kin.singularity_margins(elbow, "ur10")[1] < 1e-12


def test_movel_through_the_wrist_singularity_is_refused_and_would_stop_the_sim():
    cfg = robot_config("127.0.0.1", **WIDE)
    qa = np.array([0.0, -1.2, 1.6, -1.97, 0.3, 0.0])
    qb = qa.copy()
    qb[4] = -0.3
    T = kin.forward(qb, "ur10")
    with pytest.raises(LimitViolationError, match="wrist singularity"):
        URRobot(cfg).check_target(T, "linear", q_start=qa)
    assert "wrist singularity" in _sim_failure(qa, T, cfg)
    # the same target by moveJ is fine: joint motions do not care about singularities
    URRobot(cfg).check_target(T, "joint", q_start=qa)


def test_random_movel_targets_accepted_by_the_check_run_through_in_the_sim():
    cfg = robot_config("127.0.0.1", **WIDE)
    robot, rng = URRobot(cfg), np.random.default_rng(7)
    accepted = 0
    for _ in range(40):
        q0 = np.array(START_Q) + rng.normal(0.0, 0.6, 6)
        T = kin.forward(q0 + rng.normal(0.0, 0.4, 6), "ur10")
        try:
            robot.check_target(T, "linear", q_start=q0)
        except LimitViolationError:
            continue
        accepted += 1
        assert _sim_failure(q0, T, cfg) is None
    assert accepted >= 10
