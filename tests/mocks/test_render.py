"""The rendered RGB-D source behaves like the sensor it imitates, and survives a recording round trip."""

import cv2
import numpy as np
import pytest

from handeye.calib import transforms as tf
from handeye.calib.errors import ParameterError
from handeye.calib.vision.extract import TargetConfig, extract
from handeye.drivers.camera.base import CameraIntrinsics
from handeye.drivers.camera.registry import CAMERAS
from handeye.mocks.recorded import RecordingWriter
from handeye.mocks.render.camera import RenderedCameraConfig
from handeye.mocks.render.scene import MarkerSceneRenderer, RenderNoise

INTR = CameraIntrinsics(640, 480, 570.0, 570.0, 319.5, 239.5)
FACING = np.diag([1.0, -1.0, -1.0])


def _plate_depth_error(renderer, z, rng, background=None):
    T_cam_base = None if background is None else tf.make_transform(FACING, [0, 0, background])  # a wall
    color, depth, _ = renderer.render(tf.make_transform(FACING, [0, 0, z]), rng, T_cam_base=T_cam_base)
    patch = depth[230:250, 310:330]  # well inside the plate, which is fronto-parallel at z
    return patch, depth


def test_depth_noise_grows_with_z_squared_and_is_quantised():
    r = MarkerSceneRenderer(INTR, "DICT_4X4_50", 0, 0.05, 0.2, RenderNoise(depth_bias_k=0.0, dropout=0.0))
    rng = np.random.default_rng(0)
    near, _ = _plate_depth_error(r, 0.5, rng)
    far, depth = _plate_depth_error(r, 1.5, rng)
    np.testing.assert_allclose(depth[depth > 0] * 1000, np.round(depth[depth > 0] * 1000), atol=1e-3)  # whole mm
    assert abs(np.mean(near) - 0.5) < 1e-3 and abs(np.mean(far) - 1.5) < 3e-3
    ratio = np.std(far) / np.std(near)
    assert 5 < ratio < 13  # (1.5 / 0.5)^2 = 9
    # Nothing is read beyond the configured range; the plate's border is a ring of holes.
    r2 = MarkerSceneRenderer(INTR, "DICT_4X4_50", 0, 0.05, 0.2, RenderNoise(depth_range_m=(0.4, 1.0)))
    _, d2 = _plate_depth_error(r2, 1.2, rng)
    assert not (d2 > 0).any()
    _, d3 = _plate_depth_error(r, 0.8, rng, background=2.0)
    edge_col = int(round(319.5 + 570 * 0.1 / 0.8))  # plate edge at x = 0.1 m, a wall 1.2 m behind it
    assert (d3[200:280, edge_col - 1:edge_col + 2] == 0).any(axis=1).all()
    assert np.median(d3[200:280, edge_col + 5]) == pytest.approx(2.0, abs=0.02)


def test_color_lighting_changes_between_frames():
    r = MarkerSceneRenderer(INTR, "DICT_4X4_50", 0, 0.05, 0.08, RenderNoise())
    rng = np.random.default_rng(1)
    T = tf.make_transform(FACING, [0, 0, 0.6])
    means = [r.render(T, rng)[0].mean() for _ in range(4)]
    assert np.ptp(means) > 5


def test_renderer_rejects_distortion_and_tiny_plate():
    with pytest.raises(ParameterError, match="distortion"):
        MarkerSceneRenderer(CameraIntrinsics(640, 480, 570, 570, 320, 240, (0.1, 0, 0, 0, 0)), "DICT_4X4_50", 0,
                            0.05, 0.08, RenderNoise())
    with pytest.raises(ParameterError, match="plate_size"):
        MarkerSceneRenderer(INTR, "DICT_4X4_50", 0, 0.05, 0.05, RenderNoise())
    with pytest.raises(ParameterError, match="RenderNoise.gain"):
        RenderNoise(gain=(1.2, 0.7))


def test_recorded_rendered_frames_extract_the_same(tmp_path):
    # Face the marker to the default camera: flange z axis towards it, at the default cell's start point.
    Y = np.array(RenderedCameraConfig().T_base_cam)
    cam = CAMERAS.create({"backend": "rendered", "seed": 3},
                      lambda: tf.make_transform(Y[:3, :3] @ FACING, [0.9, 0.1, 0.5]))
    with cam, RecordingWriter(tmp_path / "rec", cam.intrinsics) as w:
        frames = [cam.read() for _ in range(2)]
        for f in frames:
            w.write(f)
    with CAMERAS.create({"backend": "recorded", "path": str(tmp_path / "rec")}) as rec:
        played = [rec.read() for _ in range(2)]
    for f, g in zip(frames, played):
        m1 = extract(f.color, f.depth, f.intrinsics, TargetConfig())
        m2 = extract(g.color, g.depth, g.intrinsics, TargetConfig())
        # Depth is stored in whole mm, which the renderer already produced: same answer.
        np.testing.assert_allclose(m2.point_cam, m1.point_cam, atol=1e-6)


def test_extract_chessboard_and_charuco_with_flat_depth():
    # A fronto-parallel board 0.57 m away: 1 px = 1 mm in the board plane.
    K = INTR
    z = 0.57
    sq_px = 40
    for kind in ("chessboard", "charuco"):
        if kind == "chessboard":
            board = np.full((5 * sq_px, 7 * sq_px), 255, np.uint8)
            for rr in range(5):
                for cc in range(7):
                    if (rr + cc) % 2 == 0:
                        board[rr * sq_px:(rr + 1) * sq_px, cc * sq_px:(cc + 1) * sq_px] = 0
            target = TargetConfig(kind="chessboard", squares=(7, 5), square_size=0.04)
        else:
            from handeye.calib.vision.markers import get_dictionary

            board = cv2.aruco.CharucoBoard((7, 5), 0.04, 0.03, get_dictionary("DICT_6X6_250")).generateImage(
                (7 * sq_px, 5 * sq_px))
            target = TargetConfig(kind="charuco", squares=(7, 5), square_size=0.04, marker_size=0.03,
                                  dictionary="DICT_6X6_250")
        img = np.full((480, 640), 255, np.uint8)
        y0, x0 = 240 - 100, 320 - 140
        img[y0:y0 + 5 * sq_px, x0:x0 + 7 * sq_px] = board
        img = cv2.GaussianBlur(img, (0, 0), 0.7)
        depth = np.full((480, 640), z, np.float32)
        m = extract(img, depth, K, target)
        # The grid center is the image center (319.5, 239.5) -> straight ahead at z.
        np.testing.assert_allclose(m.point_cam, [0.0, 0.0, z], atol=1.5e-3)
        np.testing.assert_allclose(m.center_px, [319.5, 239.5], atol=0.5)
        assert abs(abs(m.T_cam_marker[2, 2]) - 1) < 1e-3  # board normal along the optical axis
