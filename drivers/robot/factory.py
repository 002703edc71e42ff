"""``make_robot(config) -> Robot``: the one place that picks a robot backend.

Backends (TOML ``[robot]`` table, key ``type``):

``ur``      a UR arm over RTDE (`drivers.robot.ur.URRobotConfig` fields).
``ur_sim``  the same driver against a simulated controller that is started
            as a subprocess on ``host`` (`mocks.ur_sim.robot.URSimRobotConfig`).

Vendor SDKs (ur_rtde) are imported only when a UR robot actually connects.
"""

from __future__ import annotations

from calib.errors import ParameterError
from drivers.robot.base import Robot


def robot_config_from_dict(d: dict):
    """Config dataclass for a ``[robot]`` TOML table (``type`` selects the backend)."""
    if not isinstance(d, dict):
        raise ParameterError(f"robot config must be a table, got {type(d).__name__}")
    d = dict(d)
    kind = d.pop("type", "ur")
    if kind == "ur":
        from drivers.robot.ur import URRobotConfig

        return URRobotConfig.from_dict(d)
    if kind == "ur_sim":
        from mocks.ur_sim.robot import URSimRobotConfig

        return URSimRobotConfig.from_dict(d)
    raise ParameterError(f"robot.type must be 'ur' or 'ur_sim', got {kind!r}")


def make_robot(config) -> Robot:
    """Build (not connect) the robot for ``config``: a config dataclass or a ``[robot]`` table."""
    if isinstance(config, dict):
        config = robot_config_from_dict(config)
    from drivers.robot.ur import URRobot, URRobotConfig

    try:
        from mocks.ur_sim.robot import URSimRobot, URSimRobotConfig
    except ImportError:  # a production install may ship without mocks/
        URSimRobot = URSimRobotConfig = None
    if URSimRobotConfig is not None and isinstance(config, URSimRobotConfig):
        return URSimRobot(config)
    if isinstance(config, URRobotConfig):
        return URRobot(config)
    raise ParameterError(f"no robot backend for config of type {type(config).__name__}")
