"""A UR robot backed by a simulated controller it starts itself (``type = "ur_sim"``).

The real driver (`handeye.drivers.robot.ur.URRobot`, ur_rtde over loopback) talks to
a `handeye.mocks.ur_sim` subprocess that `connect` launches on ``host`` and
`disconnect` stops, so the demo and the app exercise exactly the production
code path.
"""

from __future__ import annotations

import logging
from typing import Literal

import numpy as np
from pydantic import field_validator

from handeye.calib.params import Str, Vector6
from handeye.drivers.errors import DeviceError
from handeye.drivers.robot.registry import ROBOTS
from handeye.drivers.robot.ur import URRobot, URRobotConfig
from handeye.mocks.ur_sim import PortsTakenError, SimProcess, free_loopback, launch, ports_holder
from handeye.mocks.ur_sim.controller import parse_version
from handeye.mocks.ur_sim.truth import SimRobotError

log = logging.getLogger(__name__)


class URSimRobotConfig(URRobotConfig):
    """`URRobotConfig` plus the simulated controller's settings (``[robot] type = "ur_sim"``).

    Attributes
    ----------
    controller : str
        PolyScope version of the simulator (``"5.11"`` e-Series 500 Hz, ``"3.15"`` CB3 125 Hz).
    initial_q : 6 floats or None
        Start joints of the simulated arm, rad (None: simulator default).
    sim_tcp_offset : 6 floats
        Active TCP configured on the simulated controller (UR pose, m / rad).
    sim_robot_error : SimRobotError or None
        The simulated arm's true DH parameters differ from the nominal ones it
        reports through, and each stop has a repeatability error
        (`handeye.mocks.ur_sim.truth`); the rendered camera sees the true flange.
        None (default): the nominal model is exact.
    """

    type: Literal["ur_sim"] = "ur_sim"
    controller: Str = "5.11"
    initial_q: Vector6 | None = None
    sim_tcp_offset: Vector6 = (0.0, 0.0, 0.1, 0.0, 0.0, 0.0)
    sim_robot_error: SimRobotError | None = None

    @field_validator("controller")
    @classmethod
    def _known_version(cls, version: str) -> str:
        parse_version(version)
        return version


@ROBOTS.register("ur_sim", URSimRobotConfig)
class URSimRobot(URRobot):
    """`URRobot` that owns its simulated controller process (``self.sim``)."""

    simulated = True

    def __init__(self, config: URSimRobotConfig):
        super().__init__(config)
        self.sim: SimProcess | None = None

    def connect(self) -> None:
        self.launch_controller()
        super().connect()

    def launch_controller(self) -> SimProcess:
        """The simulated controller of the config, launched on ``host`` unless it runs already."""
        if self.sim is None:
            cfg = self.config
            error = None if cfg.sim_robot_error is None else cfg.sim_robot_error.model_dump()
            try:
                self.sim = launch(cfg.host, cfg.model, cfg.controller, cfg.initial_q, cfg.sim_tcp_offset,
                                  robot_error=error)
            except PortsTakenError as e:
                # Another run (a second user, a CI job) holds the address: a simulated cell is this process's
                # own, so it moves to a free loopback address rather than fail.
                host = free_loopback(cfg.host) if cfg.host.startswith("127.") else None
                if host is None:
                    raise PortsTakenError(f"{e}; stop that run, or give this one another loopback address "
                                          "(127.x.y.z) as [robot] host in its config (-c; the demo's cell is "
                                          "config/sim.toml)") from None
                log.warning("robot: %s is taken (%s); the simulated controller runs on %s", cfg.host,
                            ports_holder(cfg.host), host)
                self.config = cfg.model_copy(update={"host": host})
                self.sim = launch(host, cfg.model, cfg.controller, cfg.initial_q, cfg.sim_tcp_offset,
                                  robot_error=error)
        return self.sim

    def true_flange_pose(self) -> np.ndarray:
        """Where the flange really is, ``T_base_flange`` (4, 4): what a rendered camera sees.

        Without ``sim_robot_error`` that is the reported pose (`read`), with it
        the simulator's truth (true DH parameters and the stop's error).
        """
        if self.config.sim_robot_error is None or self.sim is None:
            return self.read().T_base_flange
        return self.sim.true_flange_pose()

    def start_program(self, program: dict) -> None:
        """Have the simulated controller loop ``program`` (JSON form of `handeye.mocks.ur_sim.program`)."""
        if self.sim is None:
            raise DeviceError("the simulated robot is not connected: no controller to run a program")
        self.sim.start_program(program)

    def disconnect(self) -> None:
        super().disconnect()
        if self.sim is not None:
            self.sim.stop()
            self.sim = None
