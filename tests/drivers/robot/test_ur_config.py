import pytest

from handeye.calib.errors import ParameterError
from handeye.drivers.errors import DeviceError
from handeye.drivers.robot.registry import ROBOTS
from handeye.drivers.robot.ur import URRobot, URRobotConfig
from handeye.mocks.ur_sim import main as sim_main
from handeye.mocks.ur_sim.robot import URSimRobot

BOX = dict(workspace_min=(-1, -1, 0), workspace_max=(1, 1, 1))


@pytest.mark.parametrize(
    "field, value",
    [
        ("host", ""),
        ("model", "ur99"),
        ("frequency", 1000),
        ("speed", 0.0),
        ("joint_acceleration", -1.0),
        ("motion", "circular"),
        ("max_tilt_deg", 200),
        ("tilt_reference", (0, 0, 0)),
        ("joint_min", (0, 0, 0)),
        ("tcp_offset", (0, 0, float("nan"), 0, 0, 0)),
        ("frozen_timeout", 0),
    ],
)
def test_bad_field_is_named_in_the_error(field, value):
    kw = dict(host="10.0.0.2", **BOX)
    kw[field] = value
    with pytest.raises(ParameterError, match=field):
        URRobotConfig(**kw)


def test_moving_robot_needs_a_workspace_box_and_a_sane_one():
    with pytest.raises(ParameterError, match="workspace_min"):
        URRobotConfig(host="10.0.0.2")
    with pytest.raises(ParameterError, match="below workspace_max"):
        URRobotConfig(host="10.0.0.2", workspace_min=(0, 0, 0), workspace_max=(1, -1, 1))
    assert URRobotConfig(host="10.0.0.2", read_only=True).workspace_min is None


def test_factory_builds_from_toml_tables_without_connecting(loopback):
    robot = ROBOTS.create({"type": "ur", "host": "10.0.0.2", "read_only": True, "tcp_offset": [0, 0, 0.1, 0, 0, 0]})
    assert isinstance(robot, URRobot) and not robot.is_connected
    sim = ROBOTS.create({"type": "ur_sim", "host": loopback(98), "controller": "3.15", **BOX})
    assert isinstance(sim, URSimRobot) and sim.config.controller == "3.15"
    with pytest.raises(ParameterError, match="robot.type"):
        ROBOTS.config_from_dict({"type": "kuka", "host": "x"})
    with pytest.raises(ParameterError, match="spede"):
        ROBOTS.config_from_dict({"type": "ur", "host": "x", "spede": 1, **BOX})
    with pytest.raises(ParameterError, match="controller"):
        ROBOTS.config_from_dict({"type": "ur_sim", "host": "x", "controller": "9.1", **BOX})


def test_read_only_without_tcp_offset_fails_clearly_before_any_io():
    robot = URRobot(URRobotConfig(host="10.0.0.2", read_only=True))
    with pytest.raises(ParameterError, match="tcp_offset"):
        robot.connect()
    with pytest.raises(DeviceError, match="not connected"):
        robot.read()


def test_simulator_cli_rejects_bad_arguments(capsys, loopback):
    assert sim_main(["--host", loopback(98), "--model", "ur99"]) == 2
    assert sim_main(["--host", loopback(98), "--controller", "7.0"]) == 2
    assert "ur99" in capsys.readouterr().err


def test_shared_error_factor_is_the_configured_dh_error_of_the_model():
    import numpy as np

    from handeye.calib.robot_error import ur_dh_error_factor

    q = np.random.default_rng(2).uniform(-3, 3, size=(5, 6))
    assert URRobot(URRobotConfig(host="10.0.0.2", **BOX)).shared_error_factor(q) is None
    cfg = URRobotConfig(host="10.0.0.2", model="UR10", **BOX,
                        kinematic_error={"joint_offset_deg": 0.05, "link_length_m": 0.001, "twist_deg": 0.0})
    F = URRobot(cfg).shared_error_factor(q)
    # The driver's UR10 geometry is the published table calib's simulator also uses.
    np.testing.assert_allclose(F, ur_dh_error_factor(q, np.deg2rad(0.05), 0.001, 0.0), atol=1e-9)
    assert F.shape == (5, 6, 24) and not F[:, :, 18:].any()      # twists known exactly
    with pytest.raises(DeviceError, match="q"):
        URRobot(cfg).shared_error_factor(q[:, :4])
    with pytest.raises(ParameterError, match="link_length_m"):
        URRobotConfig(host="10.0.0.2", **BOX, kinematic_error={"link_length_m": -1.0})
