"""handeye.app.planning without devices: the optimal pose source's stages, and plan files."""

import json

import numpy as np
import pytest

from handeye.app import planning
from handeye.app.config import load_config
from handeye.app.errors import SessionError
from handeye.calib import transforms as tf
from handeye.calib.observation import Observation
from handeye.calib.planner import PlannerConfig, PosePlanner
from handeye.drivers.camera.base import CameraIntrinsics
from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.base import RobotState

INTR = CameraIntrinsics(640, 480, 570.0, 570.0, 319.5, 239.5)


def _cell():
    from handeye.mocks.render.camera import RenderedCameraConfig

    cfg = load_config(None)
    cam = RenderedCameraConfig(setup="eye_to_hand")
    T0 = kin.forward(np.array(cfg.robot.initial_q), "ur10")
    return cfg, cam.X, cam.Y, T0


def _observe(X, Y, T, i):
    B = tf.invert(Y) @ T @ X
    return Observation(i, 0.0, T, B[:3, 3], np.eye(3) * 1e-7, B)


def _state(T):
    return RobotState(0.0, 0.0, T, np.zeros(6), np.zeros(6), 7, 1)


def test_optimal_source_samples_the_start_then_bootstraps_then_plans():
    cfg, X, Y, T0 = _cell()
    view = planning.camera_view(cfg.calibrate, INTR, cfg.marker)
    source = planning.OptimalPoses(cfg, T0, view, None, np.random.default_rng(0))
    obs, kinds, state = [], [], _state(T0)
    truth = PosePlanner(cfg.setup, X, Y, view, PlannerConfig(uncertainty_k=0))
    for i in range(8):
        target = source.next(state, None, obs)
        kinds.append(target.kind)
        assert truth.screen(target.T_base_flange[None])[0][0]  # in view under the truth
        obs.append(_observe(X, Y, target.T_base_flange, i))
        state = _state(target.T_base_flange)
    # the early estimate (YQuatT' + ML, noise-free here) takes over after 3 samples
    assert kinds[:3] == ["start", "bootstrap", "bootstrap"] and set(kinds[3:]) == {"optimal"}


def test_optimal_source_asks_for_the_start_until_the_marker_is_seen_there():
    """No motion away from the start before a sample there (calibrate.max_missed_frames ends a blind run)."""
    cfg, X, Y, T0 = _cell()
    source = planning.OptimalPoses(cfg, T0, planning.camera_view(cfg.calibrate, INTR, cfg.marker), None,
                                   np.random.default_rng(0))
    targets = [source.next(_state(T0), None, []) for _ in range(5)]
    assert all(t.kind == "start" and np.allclose(t.T_base_flange, T0) for t in targets)


def test_resumed_session_without_a_start_sample_goes_back_to_the_start_first():
    cfg, X, Y, T0 = _cell()
    elsewhere = T0.copy()
    elsewhere[:3, 3] += [0.05, 0.0, 0.0]
    source = planning.OptimalPoses(cfg, T0, planning.camera_view(cfg.calibrate, INTR, cfg.marker), None,
                                   np.random.default_rng(0))
    target = source.next(_state(elsewhere), None, [_observe(X, Y, elsewhere, 0)])
    assert target.kind == "start" and np.allclose(target.T_base_flange, T0)


def test_view_angle_bound_covers_the_error_of_the_measured_orientation():
    """Regression (bench validity run, seed 0): the first sample measured the marker at 28.6 deg, 0.9 deg below
    its true 29.5 deg; the bootstrap relied on the measured figure. The bound adds k sigma of the orientation."""
    B_true = tf.make_transform(tf.so3_exp([0.0, np.radians(29.5), 0.0]), [0.0, 0.0, 0.84])
    B_true[:3, :3] = B_true[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # the marker faces the camera, turned 29.5 deg
    B_meas = B_true.copy()
    B_meas[:3, :3] = tf.so3_exp([0.0, np.radians(-0.9), 0.0]) @ B_true[:3, :3]
    pose_cov = np.diag([np.radians(1.0) ** 2] * 3 + [1e-6] * 3)
    measured = planning.view_angle_bound(Observation(0, 0.0, np.eye(4), B_meas[:3, 3], None, B_meas), 0.0)
    assert measured == pytest.approx(28.6, abs=1e-6)
    bound = planning.view_angle_bound(Observation(0, 0.0, np.eye(4), B_meas[:3, 3], None, B_meas, pose_cov), 3.0)
    assert bound == pytest.approx(31.6, abs=1e-6) and bound > 29.5
    no_cov = planning.view_angle_bound(Observation(0, 0.0, np.eye(4), B_meas[:3, 3], None, B_meas), 3.0)
    assert no_cov == pytest.approx(28.6 + 3 * planning.MARKER_ANGLE_SIGMA_DEG, abs=1e-6)


def test_auto_runs_plan_for_the_camera_corrections_auto_estimates_or_considers():
    from types import SimpleNamespace

    from handeye.calib.auto import CONSIDER_SIGMA
    from handeye.calib.result import CameraParameter

    assert planning.camera_correction("YKronT'", None) is None
    theta, free, sigma = planning.camera_correction("auto", None)
    assert free == (True, True, True) and np.all(theta == 0)
    assert list(sigma) == [CONSIDER_SIGMA[n] for n in ("depth_scale", "depth_offset", "focal_scale")]
    est = SimpleNamespace(auto=SimpleNamespace(camera_correction={
        "depth_scale": CameraParameter(0.01, 0.001, True), "depth_offset": CameraParameter(0.0, 0.0, False),
        "focal_scale": CameraParameter(0.0, 0.0, False)}))
    theta, free, sigma = planning.camera_correction("auto", est)
    assert theta[0] == 0.01 and sigma[0] == 1.0 and sigma[1] == CONSIDER_SIGMA["depth_offset"]


def test_plan_file_round_trip_and_named_errors(tmp_path):
    cfg, X, Y, T0 = _cell()
    doc, poses, _ = planning.make_plan(cfg, X, Y, T0, None, INTR, None, np.random.default_rng(0), prior="test", n=6)
    path = planning.write_plan(doc, tmp_path / "plan.json")
    back = planning.read_plan(path)
    assert [p["kind"] for p in back["poses"]] == ["start"] + ["optimal"] * 5 and back["camera_transform"] == "T_base_cam"
    assert np.allclose(back["poses"][3]["T_base_flange"], poses[3].T_base_flange)
    bad = json.loads(path.read_text())
    bad["version"] = 99
    (tmp_path / "v.json").write_text(json.dumps(bad))
    with pytest.raises(SessionError, match="version"):
        planning.read_plan(tmp_path / "v.json")
