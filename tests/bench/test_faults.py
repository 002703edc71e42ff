"""bench.faults: the target campaign's oracle (the simulator's own execution) and its table row."""

import math

import numpy as np

from bench.faults import format_row, random_valid_start, run_kills, run_targets, sim_path_violation
from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.ur import URRobot
from handeye.mocks.ur_sim.motion import JointMotion, LinearMotion
from tests.simulated_ur import START_Q, robot_config


def test_oracle_flags_a_singular_movel_and_a_box_violation():
    robot = URRobot(robot_config("127.0.0.1", workspace_min=(-1.5, -1.5, -0.5), workspace_max=(1.5, 1.5, 1.5),
                                 max_tilt_deg=180.0))
    qa = np.array([0.0, -1.2, 1.6, -1.97, 0.3, 0.0])
    qb = qa.copy()
    qb[4] = -0.3
    m = LinearMotion(qa, kin.forward(qb, "ur10"), 0.25, 1.2, "ur10", np.eye(4), kin.UR_JOINT_LIMITS)
    assert "wrist singularity" in sim_path_violation(m, robot, robot.config.joint_limits, 0.008)
    small = URRobot(robot_config("127.0.0.1", workspace_min=(0.0, -1.0, 0.0), workspace_max=(1.3, 1.0, 1.2)))
    q1 = np.array(START_Q)
    q1[0] = 2.5  # swings the arm behind the base, out of the box
    assert "workspace" in sim_path_violation(JointMotion(START_Q, q1, 1.0, 2.0), small, small.config.joint_limits,
                                              0.008)


def test_target_campaign_sends_nothing_the_simulator_stops_on():
    row = run_targets(25, seed=3)
    assert row["accepted"] > 5 and row["refused"] > 0
    assert row["bad"] == 0 and row["clean"] == row["runs"] == 25
    assert format_row(row).startswith("| targets vs simulator execution | 25 | 25 | 0 | 0 | - |")


def test_campaign_starts_are_states_the_driver_allows():
    # A start outside the tilt cone made the oracle flag 3 of 10,000 motions that only brought the arm back in.
    robot = URRobot(robot_config("127.0.0.1", workspace_min=(-1.4, -1.4, -0.2), workspace_max=(1.4, 1.4, 1.4),
                                 max_tilt_deg=120.0))
    cfg, rng = robot.config, np.random.default_rng(7)
    for _ in range(300):
        T = kin.forward(random_valid_start(rng, robot), "ur10")
        for p in (T[:3, 3], (T @ robot.T_flange_tcp)[:3, 3]):
            assert np.all(p > cfg.workspace_min) and np.all(p < cfg.workspace_max)
        assert math.degrees(math.acos(T[:3, 2] @ np.asarray(cfg.tilt_reference))) < cfg.max_tilt_deg


def test_a_killed_calibration_resumed_to_any_verdict_counts_as_resumed():
    # The resume's exit status is its verdict's (0 pass, 5 warn, 4 fail); the check took only 0 as completed,
    # so a resumed run judged WARN counted as not resumed.
    row = run_kills(1, iter(range(10, 20)), seed=0)
    assert row["runs"] == row["resumable"] == row["clean"] == 1, row["errors"]
    assert row["lost"] == row["crashes"] == row["hangs"] == 0
