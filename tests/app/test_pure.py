"""App helpers that need no devices: pose sampling, diversity, marker prediction, config validation."""

import dataclasses

import numpy as np
import pytest

from handeye.app.planning import random_pose
from handeye.app.config import CalibrateConfig, Config, config_from_dict
from handeye.app.runs.monitor import is_diverse
from handeye.calib import transforms as tf
from handeye.app.errors import ConfigError
from handeye.calib.predict import predicted_pixel, predicted_point
from handeye.calib.result import CalibrationResult, Residuals
from handeye.calib.simulate import realistic_cell
from handeye.drivers.camera.base import CameraIntrinsics


def test_random_pose_within_box_and_tilt():
    cfg = CalibrateConfig(translation_range_m=0.1, tilt_deg=20.0)
    rng = np.random.default_rng(3)
    start = tf.make_transform(tf.random_rotations(1, np.pi, rng)[0], [0.5, 0.2, 0.4])
    poses = np.array([random_pose(start, cfg, rng) for _ in range(200)])
    assert np.all(np.abs(poses[:, :3, 3] - start[:3, 3]) <= 0.1)
    rot, _ = tf.pose_error(poses, np.broadcast_to(start, poses.shape))
    assert np.rad2deg(rot).max() <= 20.0 + 1e-9
    assert np.rad2deg(rot).max() > 15.0  # the range is actually used
    # seeded: same rng seed, same poses
    a = random_pose(start, cfg, np.random.default_rng(7))
    b = random_pose(start, cfg, np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)


def test_is_diverse():
    T = np.eye(4)
    near = tf.make_transform(np.eye(3), [0.01, 0, 0])
    far = tf.make_transform(np.eye(3), [0.05, 0, 0])
    tilted = tf.from_rotvec_translation([0, np.deg2rad(8), 0], [0.0, 0, 0])
    assert is_diverse(T, [], 0.03, 5.0)
    assert not is_diverse(near, [T], 0.03, 5.0)
    assert is_diverse(far, [T], 0.03, 5.0)
    assert is_diverse(tilted, [T], 0.03, 5.0)


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_predicted_point_matches_truth(setup):
    d = realistic_cell(5, np.random.default_rng(0), setup=setup, sigma_lateral=1e-12, sigma_depth=1e-12,
                       pose_noise=(0.0, 0.0))
    res = CalibrationResult("YKronT'", setup, d.X, d.Y, 5, Residuals(np.zeros(5)))
    for A, B in zip(d.A_true, d.B_true):
        np.testing.assert_allclose(predicted_point(res, A), B[:3, 3], atol=1e-9)
    K = CameraIntrinsics(640, 480, 525.0, 525.0, 320.0, 240.0)
    px = predicted_pixel(res, d.A_true[0], K)
    p = d.B_true[0][:3, 3]
    assert px == pytest.approx((525 * p[0] / p[2] + 320, 525 * p[1] / p[2] + 240))
    # far off to the side: the marker leaves the image
    away = d.A_true[0].copy()
    away[:3, 3] += 5.0 * (d.Y[:3, 0] if setup == "eye_to_hand" else -away[:3, 0])
    assert predicted_pixel(res, away, K) is None


def test_sigma_worst_axis():
    cov = np.diag([np.deg2rad(0.1) ** 2, 0, 0, 1e-6, 4e-6, 0])
    res = CalibrationResult("YKronT'", "eye_to_hand", np.eye(4), np.eye(4), 3, Residuals(np.zeros(3)), cov=cov)
    s_rot, s_t = res.sigma
    assert np.rad2deg(s_rot) == pytest.approx(0.1) and s_t == pytest.approx(2e-3)
    assert dataclasses.replace(res, cov=None).sigma is None


@pytest.mark.parametrize("data, match", [
    ({"setup": "sideways"}, "setup"),
    ({"camera": {"setup": "eye_to_hand"}}, "camera: backend must be one of"),
    ({"robot": {"type": "kuka"}}, "robot: type must be one of"),
    ({"setup": "eye_in_hand", "camera": {"backend": "rendered", "setup": "eye_to_hand"}}, "camera.setup"),
    ({"robot": {"type": "ur_sim", "host": "h", "speed": True}}, "robot.speed"),
    ({"marker": {"marker_size": 0}}, "marker.marker_size"),
    ({"monitor": {"engine": {"tolerance_mm": -2}}}, "monitor.engine.tolerance_mm"),
    ({"calibrate": {"samples": 2}}, "calibrate.samples"),
    ({"calibrate": {"min_samples": 40}}, "calibrate: min_samples"),
    ({"calibrate": {"refine": "yes"}}, "calibrate.refine"),
    ({"monitor": {"poll_s": 0}}, "monitor.poll_s"),
    ({"viz": {"enabled": 1}}, "viz.enabled"),
    ({"session": {"root": ""}}, "session.root"),
    ({"bogus": 1}, "bogus: unknown key"),
    ({"viz": {"colour": True}}, "viz.colour"),
])
def test_config_errors_name_the_field(data, match):
    with pytest.raises(ConfigError, match=match):
        config_from_dict(data)


def test_config_sections_roundtrip():
    cfg = config_from_dict({"setup": "eye_in_hand", "camera": {"backend": "rendered", "setup": "eye_in_hand"},
                            "calibrate": {"samples": 5, "min_samples": 4}})
    assert cfg.setup == "eye_in_hand" and cfg.calibrate.samples == 5
    assert config_from_dict(cfg.to_dict()) == cfg
    # one setup: the rendered camera takes the config's
    assert cfg.camera.setup == "eye_in_hand"
    assert config_from_dict({"setup": "eye_in_hand"}).camera.setup == "eye_in_hand"
    assert Config().calibrate.method == "auto" and Config().monitor.engine.tolerance_mm == 2.0


def test_stop_on_predicted_uncertainty():
    from handeye.app.runs.calibrate import precise_enough

    cov = np.diag([np.deg2rad(0.03) ** 2] * 3 + [(0.4e-3) ** 2] * 3)
    res = CalibrationResult("YKronT'", "eye_to_hand", np.eye(4), np.eye(4), 10, Residuals(np.zeros(10)), cov=cov)
    assert precise_enough(res, CalibrateConfig(target_sigma_mm=0.5, target_sigma_deg=0.05))
    assert not precise_enough(res, CalibrateConfig(target_sigma_mm=0.3, target_sigma_deg=0.05))
    assert not precise_enough(res, CalibrateConfig(target_sigma_mm=0.5, target_sigma_deg=0.02))
    assert not precise_enough(res, CalibrateConfig(target_sigma_mm=0.0, target_sigma_deg=0.0))  # 0 = off


def test_realistic_demo_config_has_the_camera_depth_error():
    """config/sim_realistic.toml: the simulated cell with a 1.5% / 3 mm depth error in the rendered camera."""
    from handeye.app.config import load_config

    cfg = load_config("config/sim_realistic.toml")
    assert cfg.camera.noise.depth_scale == 0.015 and cfg.camera.noise.depth_offset_m == 0.003
    assert cfg.calibrate.method == "auto"


@pytest.mark.parametrize("bad", ["abc", [1, 2], [0, 0, 0, 0, 0, float("nan")], [[1] * 6], {"a": 1}])
def test_recorded_joints_are_checked_before_the_robot_model_uses_them(tmp_path, bad):
    """The joints travel as `Observation.joints`; a session file's are checked where it is read, naming the
    sample, and the robot model gets them for auto only, when every sample has them."""
    import json

    from handeye.app import devices
    from handeye.app.errors import SessionError
    from handeye.app.session import SessionWriter, read_session
    from handeye.calib.observation import Observation
    from handeye.calib.simulate import realistic_profile

    real = realistic_profile(12, np.random.default_rng(0))
    d = real.data
    obs = [Observation(i, 0.0, d.A[i], d.points[i], d.point_cov[i], joints=real.q[i]) for i in range(12)]
    factor = devices.robot_shared_error("auto", obs, lambda q: np.zeros((len(q), 6, 1)))
    assert factor.shape == (12, 6, 1)
    assert devices.robot_shared_error("YKronT'", obs, lambda q: np.zeros((len(q), 6, 1))) is None
    obs[3].joints = None
    assert devices.robot_shared_error("auto", obs, lambda q: np.zeros((len(q), 6, 1))) is None
    with SessionWriter.create(tmp_path, "eye_to_hand", name="s", source="test") as w:
        for o in obs[:5]:
            w.add_sample(o)
    lines = (w.path / "samples.jsonl").read_text().splitlines()
    np.testing.assert_allclose(read_session(w.path).observations[4].joints, real.q[4])
    rec = json.loads(lines[4])
    rec["joints"] = bad
    (w.path / "samples.jsonl").write_text("\n".join(lines[:4] + [json.dumps(rec)]) + "\n")
    with pytest.raises(SessionError, match="joints"):
        read_session(w.path)


def test_the_configured_marker_offset_reaches_auto():
    """``[marker] offset_m`` is what calibrate's solve (`handeye.app.devices.make_solve`) holds with ``auto``: a grid
    (the tool never turned) is then complete; another method is not given it (it would refuse it)."""
    from handeye.app import devices
    from handeye.calib.observation import Observation

    d = realistic_cell(30, np.random.default_rng(11), angle_range=0.0)
    obs = [Observation(i, float(i), d.A[i], d.points[i], d.point_cov[i]) for i in range(30)]
    cfg = config_from_dict({"marker": {"offset_m": d.X[:3, 3].tolist(), "offset_sigma_m": 0.0005}}, "test")
    rng = np.random.default_rng(0)
    held = devices.make_solve(cfg.calibrate, "eye_to_hand", rng, marker=cfg.marker)(obs, final=True)
    assert held.undetermined == () and np.allclose(held.X[:3, 3], d.X[:3, 3], atol=2e-3)
    assert devices.make_solve(cfg.calibrate, "eye_to_hand", rng)(obs, final=True).undetermined
    turning = realistic_cell(30, np.random.default_rng(12))
    obs = [Observation(i, float(i), turning.A[i], turning.points[i], turning.point_cov[i]) for i in range(30)]
    paper = cfg.calibrate.model_copy(update={"method": "YKronT'", "refine": False})
    assert devices.make_solve(paper, "eye_to_hand", rng, marker=cfg.marker)(obs, final=True).method == "YKronT'"
