"""Shared helpers for the UR driver tests: each test module launches its own
simulated controller (module-scoped, because every ur_rtde disconnect sleeps
0.5 s) on its own loopback address, derived from the process id so that
concurrent runs of the suite do not collide."""

import time

import numpy as np
import pytest

from drivers.errors import DeviceError

from drivers.robot.ur import URRobot, URRobotConfig
from mocks.ur_sim import launch
from tests.conftest import process_net

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


def free_host(slot: int) -> str:
    """A loopback address for this test process: concurrent runs of the suite must not share ports."""
    return f"{process_net()}.{slot}"


@pytest.fixture(scope="module")
def sim_factory():
    """Launch simulators for this module (``make(slot, controller)``); stopped at module end."""
    sims = []

    def make(slot, controller="5.11"):
        for attempt in range(5):
            try:
                sim = launch(free_host(slot + 10 * attempt), model="ur10", controller=controller,
                             initial_q=START_Q, tcp_offset=SIM_TCP)
                break
            except DeviceError as exc:
                if "in use" not in str(exc) or attempt == 4:
                    raise
        sims.append(sim)
        return sim

    yield make
    for sim in sims:
        sim.stop()


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
