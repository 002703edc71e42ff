"""Read-only monitoring of a simulated CB3 (PolyScope 3.15, 125 Hz) UR10:
the control interface is never opened."""

import time

import numpy as np
import pytest

from handeye.drivers.errors import DeviceError
from tests.simulated_ur import SIM_TCP, controller_stamps, connect_robot, robot_config, truth_flange



@pytest.fixture(scope="module")
def sim(sim_factory):
    return sim_factory(3, controller="3.15")


@pytest.fixture(scope="module")
def robot(sim):
    r = connect_robot(robot_config(sim.host, read_only=True, tcp_offset=SIM_TCP))
    yield r
    r.disconnect()


def test_read_only_never_opens_the_control_interface(robot, sim):
    state = sim.state()
    assert state["script_uploads"] == 0 and state["commands"] == [] and not state["script_running"]
    with pytest.raises(DeviceError, match="read-only"):
        robot.move_to(robot.read().T_base_flange)
    with pytest.raises(DeviceError, match="read-only"):
        robot.stop()
    assert sim.state()["script_uploads"] == 0


def test_cb3_streams_at_125_hz_and_pose_matches_truth(robot, sim):
    stamps = controller_stamps(robot, 1.0, poll=0.001)
    assert np.median(np.diff(stamps)) == pytest.approx(0.008, abs=1e-9)
    assert len(stamps) > 0.7 * 125
    np.testing.assert_allclose(robot.read().T_base_flange, truth_flange(sim), atol=1e-9)


def test_passive_monitoring_follows_motion_commanded_elsewhere(robot, sim):
    q = np.array(sim.state()["q"])
    q[0] += 0.2
    sim.set_q(q)
    time.sleep(0.1)
    np.testing.assert_allclose(robot.read().q, q, atol=1e-12)
    np.testing.assert_allclose(robot.read().T_base_flange, truth_flange(sim), atol=1e-9)


def test_a_configured_tcp_offset_that_is_not_the_controllers_is_named_as_such(sim, caplog):
    """Read-only with tcp_offset 0 while the controller uses SIM_TCP (15 cm out, turned): the warning names the
    TCP offset, the one the controller uses and the one configured (it asked 'wrong model?')."""
    with caplog.at_level("WARNING", logger="handeye.drivers.robot.ur"):
        r = connect_robot(robot_config(sim.host, read_only=True, tcp_offset=[0.0] * 6))
        r.disconnect()
    (line,) = [rec.getMessage() for rec in caplog.records if "kinematics" in rec.getMessage()]
    used = "[" + " ".join(f"{v:.4f}" for v in SIM_TCP) + "]"
    assert "wrong model" not in line and " mm from the nominal ur10 kinematics" in line, line
    assert (f"the controller's active TCP offset looks like {used} (x y z m, rx ry rz rad), robot.tcp_offset says "
            "[0.0000 0.0000 0.0000 0.0000 0.0000 0.0000]; set robot.tcp_offset to the controller's") in line, line
