"""A UR robot backed by a simulated controller it starts itself (``type = "ur_sim"``).

The real driver (`drivers.robot.ur.URRobot`, ur_rtde over loopback) talks to
a `mocks.ur_sim` subprocess that `connect` launches on ``host`` and
`disconnect` stops, so the demo and the app exercise exactly the production
code path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.errors import ParameterError
from drivers.robot.registry import ROBOTS
from drivers.robot.ur import URRobot, URRobotConfig
from mocks.ur_sim import SimProcess, launch
from mocks.ur_sim.controller import parse_version


@dataclass
class URSimRobotConfig(URRobotConfig):
    """`URRobotConfig` plus the simulated controller's settings.

    Attributes
    ----------
    controller : str
        PolyScope version of the simulator (``"5.11"`` e-Series 500 Hz, ``"3.15"`` CB3 125 Hz).
    initial_q : 6 floats or None
        Start joints of the simulated arm, rad (None: simulator default).
    sim_tcp_offset : 6 floats
        Active TCP configured on the simulated controller (UR pose, m / rad).
    """

    controller: str = "5.11"
    initial_q: tuple[float, ...] | None = None
    sim_tcp_offset: tuple[float, ...] = (0.0, 0.0, 0.1, 0.0, 0.0, 0.0)

    def __post_init__(self):
        super().__post_init__()
        try:
            parse_version(self.controller)
        except ValueError as exc:
            raise ParameterError(f"URSimRobotConfig.controller: {exc}") from None
        if self.initial_q is not None:
            self.initial_q = _six(self.initial_q, "initial_q")
        self.sim_tcp_offset = _six(self.sim_tcp_offset, "sim_tcp_offset")


def _six(value, name: str) -> tuple[float, ...]:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = np.zeros(0)
    if arr.shape != (6,) or not np.isfinite(arr).all():
        raise ParameterError(f"URSimRobotConfig.{name} must be 6 finite numbers, got {value!r}")
    return tuple(float(x) for x in arr)


@ROBOTS.register("ur_sim", URSimRobotConfig)
class URSimRobot(URRobot):
    """`URRobot` that owns its simulated controller process (``self.sim``)."""

    simulated = True

    def __init__(self, config: URSimRobotConfig):
        super().__init__(config)
        self.sim: SimProcess | None = None

    def connect(self) -> None:
        if self.sim is None:
            cfg = self.config
            self.sim = launch(cfg.host, cfg.model, cfg.controller, cfg.initial_q, cfg.sim_tcp_offset)
        super().connect()

    def disconnect(self) -> None:
        super().disconnect()
        if self.sim is not None:
            self.sim.stop()
            self.sim = None
