"""extract() on rendered RGB-D frames: accuracy, honest covariance, and bad frames skipped with a reason."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from handeye.calib import transforms as tf
from handeye.calib.errors import DepthError, MarkerNotFoundError, ParameterError
from handeye.calib.vision.extract import TargetConfig, extract, try_extract
from handeye.drivers.camera.base import CameraIntrinsics
from handeye.mocks.render.scene import MarkerSceneRenderer, RenderNoise

INTR = CameraIntrinsics(640, 480, 570.0, 570.0, 319.5, 239.5)
FACING = np.diag([1.0, -1.0, -1.0])  # marker z axis back at the camera


@pytest.fixture(scope="module")
def renderer():
    return MarkerSceneRenderer(INTR, "DICT_4X4_50", 0, 0.05, 0.08, RenderNoise())


def random_pose(rng, z_range=(0.5, 1.0), max_tilt_deg=40.0):
    z = rng.uniform(*z_range)
    R = Rotation.from_rotvec(rng.normal(size=3) / np.sqrt(3) * np.deg2rad(max_tilt_deg) * 0.8).as_matrix() @ FACING
    t = np.array([rng.uniform(-0.2, 0.2) * z, rng.uniform(-0.15, 0.15) * z, z])
    return tf.make_transform(R, t)


@pytest.fixture(scope="module")
def rendered_results(renderer):
    rng = np.random.default_rng(7)
    out = []
    for _ in range(40):
        T = random_pose(rng)
        color, depth, truth = renderer.render(T, rng, T_cam_flange=T @ tf.make_transform(np.eye(3), [0, 0, -0.012]))
        m, reason = try_extract(color, depth, INTR, TargetConfig())
        out.append((T, truth, m, reason))
    return out


def test_center_accuracy_and_nees_on_rendered_frames(rendered_results):
    ok = [(T, truth, m) for T, truth, m, _ in rendered_results if m is not None]
    assert len(ok) >= 36, [r for *_, r in rendered_results if r]
    err = np.array([m.point_cam - truth["point_cam"] for _, truth, m in ok])
    nees = np.array([e @ np.linalg.solve(m.point_cov, e) for e, (_, _, m) in zip(err, ok)])
    assert np.median(np.linalg.norm(err, axis=1)) < 2e-3
    # chi2(3) has mean 3; allow the spread of 40 samples and model mismatch, not an order of magnitude.
    assert 1.5 < nees.mean() < 6.0, nees


def test_depth_refined_pose_beats_pnp_rotation(rendered_results):
    rot_d, rot_p, pose_nees = [], [], []
    for T, _, m, _ in rendered_results:
        if m is None:
            continue
        rot_d.append(tf.pose_error(m.T_cam_marker, T)[0])
        rot_p.append(tf.pose_error(m.T_cam_marker_pnp, T)[0])
        assert m.pose_cov.shape == (6, 6) and m.pose_cov_pnp.shape == (6, 6)
        assert np.all(np.linalg.eigvalsh(m.pose_cov) > 0)
        # Covariance convention of handeye.calib.result: R_true = Exp(d) R_est, t_true = t_est + dt.
        d = cv2.Rodrigues(T[:3, :3] @ m.T_cam_marker[:3, :3].T)[0].ravel()
        e = np.r_[d, T[:3, 3] - m.T_cam_marker[:3, 3]]
        pose_nees.append(e @ np.linalg.solve(m.pose_cov, e))
    assert 3.0 < np.mean(pose_nees) < 12.0, pose_nees  # chi2(6): mean 6
    assert np.median(rot_d) < np.median(rot_p)
    assert np.median(rot_d) < np.deg2rad(1.5)


def test_pnp_only_mode(renderer):
    rng = np.random.default_rng(3)
    T = random_pose(rng, (0.6, 0.6), 20)
    color, depth, truth = renderer.render(T, rng)
    m = extract(color, None, INTR, TargetConfig(use_depth=False))
    e = m.point_cam - truth["point_cam"]
    assert np.linalg.norm(e) < 0.02
    assert e @ np.linalg.solve(m.point_cov, e) < 30
    assert "n_depth_pixels" not in m.info


def test_no_marker_and_wrong_id(renderer):
    rng = np.random.default_rng(4)
    T_away = tf.make_transform(np.eye(3), [0, 0, 0.7])  # marker back faces the camera: nothing printed
    color, depth, _ = renderer.render(T_away, rng)
    m, reason = try_extract(color, depth, INTR, TargetConfig())
    assert m is None and "no marker in view" in reason
    T = random_pose(rng, (0.6, 0.6), 10)
    color, depth, _ = renderer.render(T, rng)
    with pytest.raises(MarkerNotFoundError, match=r"marker 3 of DICT_4X4_50 not found \(seen ids \[0\]\)"):
        extract(color, depth, INTR, TargetConfig(marker_id=3))


def test_marker_at_border_is_rejected(renderer):
    rng = np.random.default_rng(5)
    # Marker center 0.29 m right at 0.6 m: its right corners ~ 20 px from the right edge.
    T = tf.make_transform(FACING, [0.29, 0.0, 0.6])
    color, depth, _ = renderer.render(T, rng)
    assert try_extract(color, depth, INTR, TargetConfig())[0] is not None
    m, reason = try_extract(color, depth, INTR, TargetConfig(border_margin_px=25))
    assert m is None and "touches the image border" in reason


def test_depth_problems_are_depth_errors(renderer):
    rng = np.random.default_rng(6)
    T = random_pose(rng, (0.7, 0.7), 10)
    color, depth, _ = renderer.render(T, rng)
    cfg = TargetConfig()
    cases = {
        "no depth image": None,
        "have depth": np.zeros_like(depth),  # empty depth
        "float metres": (depth * 1000).astype(np.uint16),
        "does not match": depth[:240],
    }
    for msg, d in cases.items():
        with pytest.raises(DepthError, match=msg):
            extract(color, d, INTR, cfg)
        assert msg in try_extract(color, d, INTR, cfg)[1]
    # Depth of something else (random clutter) over the marker: a bad plane fit.
    clutter = depth.copy()
    clutter[depth > 0] = rng.uniform(0.5, 2.0, size=int((depth > 0).sum()))
    with pytest.raises(DepthError, match="bad plane fit"):
        extract(color, clutter, INTR, cfg)


def test_target_config_validation_names_the_field():
    with pytest.raises(ParameterError, match="TargetConfig.kind"):
        TargetConfig(kind="qr")
    with pytest.raises(ParameterError, match="TargetConfig.marker_size"):
        TargetConfig(marker_size=-0.05)
    with pytest.raises(ParameterError, match="TargetConfig.size: unknown key"):
        TargetConfig(size=0.05)
    with pytest.raises(ParameterError, match="TargetConfig.use_depth"):
        TargetConfig(use_depth=1)  # no number for a boolean
    with pytest.raises(ParameterError, match="square_size"):
        TargetConfig(kind="charuco")
    with pytest.raises(ParameterError, match="depth_noise"):
        TargetConfig(depth_noise={"k": -1.0})
    cfg = TargetConfig(dictionary="DICT_APRILTAG_36h11", depth_noise={"k": 2e-3})
    assert cfg.depth_noise.k == 2e-3
