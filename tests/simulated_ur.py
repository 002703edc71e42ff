"""Helpers for the tests that run the simulated UR controller (handeye.mocks.ur_sim) through the real driver.

Each test module launches its own simulated controller (the ``sim_factory`` fixture of tests/conftest.py,
module-scoped because every ur_rtde disconnect sleeps 0.5 s) on its own loopback address, derived from
the process id so that concurrent runs of the suite do not collide.
"""

import os
import time

import numpy as np

from handeye.drivers.robot.ur import URRobot, URRobotConfig

# An unusual TCP so that forgetting to remove it shows up in every pose check.
SIM_TCP = (0.01, -0.02, 0.15, 0.1, -0.2, 0.3)
# UR10, flange pointing down in front of the base.
START_Q = (0.0, -1.2, 1.6, -1.97, -1.5708, 0.0)


def robot_config(host: str, **kw) -> URRobotConfig:
    base = dict(
        host=host,
        model="ur10",
        speed=0.25,
        acceleration=1.2,
        joint_speed=1.0,
        joint_acceleration=2.0,
        workspace_min=(-1.3, -1.0, 0.0),
        workspace_max=(1.3, 1.0, 1.2),
        max_tilt_deg=45.0,
    )
    base.update(kw)
    return URRobotConfig(**base)


def process_net() -> str:
    """A loopback /24 of this test process (``127.a.b``), derived from its pid, so that
    concurrent runs of the suite (CI, several checkouts) never share simulator ports."""
    pid = os.getpid()
    return f"127.{(pid >> 8) % 250 + 1}.{pid % 256}"


def free_host(slot: int) -> str:
    """A loopback address for this test process: concurrent runs of the suite must not share ports."""
    return f"{process_net()}.{slot}"


def connect_robot(cfg) -> URRobot:
    robot = URRobot(cfg)
    robot.connect()
    return robot


def truth_flange(sim) -> np.ndarray:
    return np.array(sim.state()["T_base_flange"])


def controller_stamps(robot, seconds: float, poll: float) -> np.ndarray:
    """Distinct controller timestamps the driver delivered while polled for ``seconds``."""
    t_end = time.time() + seconds
    stamps = []
    while time.time() < t_end:
        stamps.append(robot.read().t_controller)
        time.sleep(poll)
    return np.unique(stamps)
