"""``[production]``: the simulated robot's program from waypoints or a preset, run by the simulated controller."""

import time

import numpy as np
import pytest

from handeye.app.config import CalibrateConfig, ProductionConfig, config_from_dict
from handeye.app.errors import ConfigError
from handeye.app.production import program_from_config
from handeye.calib import transforms as tf
from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.ur import URKinematics
from handeye.mocks.ur_sim import launch

# The shipped simulated cell's start joints (config/sim.toml).
Q0 = np.array([0.367792, -3.559685, 1.448735, -1.704477, -0.767569, 0.521542])
T0 = kin.forward(Q0, "ur10")


def _program(table: dict, seed: int = 0) -> dict:
    return program_from_config(ProductionConfig.model_validate(table), T0, Q0, URKinematics("ur10"), CalibrateConfig(),
                               np.random.default_rng(seed))


def test_pick_and_place_stops_are_spread_around_the_start_within_the_tilt():
    prog = _program({"preset": "pick_and_place", "stops": 4, "max_tilt_deg": 10.0, "radius_m": 0.12})
    q = np.array([w["q"] for w in prog["waypoints"]])
    T = kin.forward(q, "ur10")
    assert len(q) == 4
    np.testing.assert_allclose(np.linalg.norm(T[:, :2, 3] - T0[:2, 3], axis=1), 0.12, atol=1e-6)
    np.testing.assert_allclose(T[:, 2, 3], T0[2, 3], atol=1e-6)
    tilt, _ = tf.pose_error(tf.make_transform(T[:, :3, :3], np.zeros(3)), tf.make_transform(T0[:3, :3], np.zeros(3)))
    assert np.all(np.rad2deg(tilt) <= 10.0 + 1e-6)
    # Non-collinear: the stops determine a rigid registration (issue 20's three-stop re-learning).
    centred = T[:, :3, 3] - T[:, :3, 3].mean(axis=0)
    assert np.linalg.svd(centred, compute_uv=False)[1] > 0.05


def test_the_default_is_the_previous_14_random_waypoints():
    prog = _program({})
    assert len(prog["waypoints"]) == 14 and prog["speed"] == 2.0
    assert {w["pause_s"] for w in prog["waypoints"]} == {0.6}


def test_explicit_waypoints_take_joints_or_flange_poses():
    q1 = (Q0 + [0.1, 0.05, -0.05, 0.0, 0.1, 0.2]).tolist()
    pose = tf.to_ur_pose(kin.forward(np.array(q1) + 0.05, "ur10")).tolist()
    prog = _program({"waypoints": [{"q": list(Q0), "tool": "pick"}, {"pose": pose, "pause_s": 2.0}, {"q": q1}],
                     "pause_s": 0.4})
    q = np.array([w["q"] for w in prog["waypoints"]])
    np.testing.assert_allclose(kin.forward(q[1], "ur10"), tf.from_ur_pose(pose), atol=1e-9)
    assert [w["pause_s"] for w in prog["waypoints"]] == [0.4, 2.0, 0.4]
    assert prog["waypoints"][0]["tool"] == "pick"


@pytest.mark.parametrize("table, field", [
    ({"waypoints": [{"q": [0.0] * 6}]}, "at least 2"),
    ({"waypoints": [{"q": [0.0] * 6}, {"q": [0.0] * 6, "pose": [0.5, 0, 0.5, 0, 0, 0]}]}, "production.waypoints.1"),
    ({"waypoints": [{"q": [0.0] * 6}, {"q": [0.1] * 6}], "preset": "pick_and_place"}, "preset"),
    ({"preset": "circle"}, "production.preset"),
    ({"stops": 1}, "production.stops"),
    ({"max_tilt_deg": 120}, "production.max_tilt_deg"),
])
def test_bad_production_tables_are_refused_by_name(table, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        config_from_dict({"production": table}, "cell.toml")


def test_an_unreachable_pose_is_a_config_error_naming_the_stop():
    with pytest.raises(ConfigError, match=r"production\.waypoints\[1\]\.pose"):
        _program({"waypoints": [{"q": list(Q0)}, {"pose": [5.0, 0.0, 0.5, 0.0, 0.0, 0.0]}]})


def test_a_three_stop_pick_and_place_loops_those_three_stops_on_the_simulated_controller(loopback):
    prog = _program({"preset": "pick_and_place", "stops": 3, "pause_s": 0.25, "speed": 3.0, "acceleration": 12.0})
    targets = np.array([w["q"] for w in prog["waypoints"]])
    with launch(loopback(44), "ur10", "3.15", initial_q=Q0) as sim:
        sim.start_program(prog)
        held = []
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            st = sim.state()
            if not st["moving"]:
                held.append(np.array(st["q"]))
            if st["program"]["cycles"] >= 2:
                break
            time.sleep(0.05)
        assert st["program"]["cycles"] >= 2, st["program"]
        stops = [c["name"] for c in st["commands"] if c["name"].startswith("program:stop")]
    # Two laps and more: the stops come in program order, and nothing but those three.
    order = [int(n.split()[1]) for n in stops]
    assert len(order) >= 6 and order == [i % 3 for i in range(len(order))]
    held = np.array(held)
    nearest = np.min(np.abs(held[:, None, :] - targets[None]).max(axis=2), axis=1)
    start = np.abs(held - Q0).max(axis=1) < 1e-9  # before the first motion
    assert np.all((nearest < 1e-6) | start)


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_the_demo_bump_moves_the_camera_by_exactly_its_mm_and_deg_through_the_mount_schedule(setup):
    from handeye.app.production import Bump
    from handeye.drivers.camera.registry import CAMERAS

    cam = CAMERAS.create({"backend": "rendered", "setup": setup})
    cam.follow(lambda: T0)
    cam.connect()
    before = cam.camera_transform()
    after = Bump(3, 4.0, 0.25).apply(cam, setup)
    rot, trans = tf.pose_error(after, before)
    assert trans * 1e3 == pytest.approx(4.0, abs=1e-9) and np.rad2deg(rot) == pytest.approx(0.25, abs=1e-9)
    np.testing.assert_allclose(cam.truth()[cam.config.setup.camera_name], after, atol=0)
    assert len(cam.config.mount.bumps) == 1
    with pytest.raises(ConfigError, match="setup"):
        Bump(3).apply(cam, "eye_in_hand" if setup == "eye_to_hand" else "eye_to_hand")


@pytest.mark.slow
def test_the_shift_config_monitors_a_four_stop_pick_and_place(tmp_path, loopback, capsys):
    from handeye.app.cli import main
    from handeye.app.session import read_session

    text = open("config/sim_shift.toml").read().replace('host = "127.0.0.2"', f'host = "{loopback(48)}"')
    config = tmp_path / "shift.toml"
    config.write_text(text)
    rc = main(["monitor", "-c", str(config), "--max-samples", "4", "--duration", "120", "--no-frames", "--no-viz",
               "--session-root", str(tmp_path / "s")])
    out = capsys.readouterr().out
    assert rc in (0, 3), out
    assert "(4 waypoints, pick-and-place, 1.0 s tool stops)" in out
    (session,) = (tmp_path / "s").iterdir()
    s = read_session(session)
    assert len(s.observations) == 4
    # Four distinct stops on a 0.15 m circle around the start pose.
    p = np.array([o.T_base_flange[:3, 3] for o in s.observations])
    np.testing.assert_allclose(np.linalg.norm(p[:, :2] - T0[:2, 3], axis=1), 0.15, atol=1e-3)
