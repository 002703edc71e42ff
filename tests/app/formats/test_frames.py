"""[frames]: the names every export uses; the camera frame is the optical frame, with a ROS camera_link beside it."""

import json

import numpy as np
import pytest
import yaml

from handeye.app import devices
from handeye.app.config import config_from_dict, load_config
from handeye.app.errors import ConfigError
from handeye.app.formats.export import T_LINK_OPTICAL
from handeye.calib import simulate
from handeye.calib import transforms as tf
from handeye.calib.api import solve

FRAMES = {"base": "base_link", "flange": "tool0", "camera": "cam_color_optical_frame", "marker": "aruco_0"}


def test_every_export_uses_the_configured_frames(tmp_path):
    data = simulate.realistic_cell(15, np.random.default_rng(3))
    res = solve("YKronT'", data.A, data.points)
    files = devices.write_result(res, tmp_path, list(devices.RESULT_FILES), FRAMES)
    for fmt, path in files.items():
        text = path.read_text()
        assert "base_link" in text and "cam_color_optical_frame" in text, fmt
        assert "child-frame-id camera " not in text and "\"camera\"," not in text, fmt
    doc = yaml.safe_load(files["yaml"].read_text())
    assert files["yaml"].read_text().splitlines()[1].startswith("# The camera frame is the OPTICAL frame")
    cam = doc["camera_frame"]
    assert cam["name"] == "cam_color_optical_frame" and "z forward" in cam["convention"]
    # camera_link at the camera's origin: its x axis is the optical z axis (viewing direction),
    # its z axis is the optical -y (up in the image).
    link = tf.from_xyz_quat(cam["camera_link_transform"]["translation_m"], cam["camera_link_transform"]["quaternion_xyzw"])
    np.testing.assert_allclose(link[:3, 0], res.camera_transform[:3, 2], atol=1e-9)
    np.testing.assert_allclose(link[:3, 2], -res.camera_transform[:3, 1], atol=1e-9)
    np.testing.assert_allclose(link[:3, 3], res.camera_transform[:3, 3], atol=1e-12)
    q = np.array(cam["camera_link_to_optical"]["quaternion_xyzw"])
    np.testing.assert_allclose(tf.from_xyz_quat(np.zeros(3), q), T_LINK_OPTICAL, atol=1e-12)
    assert json.loads(files["json"].read_text())["frames"] == FRAMES


def test_frames_table_is_validated():
    cfg = load_config(None)
    assert cfg.frames.model_dump() == {"base": "base", "flange": "flange", "camera": "camera", "marker": "marker"}
    assert config_from_dict({"frames": {"flange": "tool0"}}).frames.flange == "tool0"
    with pytest.raises(ConfigError, match="frames.camera_link"):
        config_from_dict({"frames": {"camera_link": "x"}})
    with pytest.raises(ConfigError, match="frames.camera"):
        config_from_dict({"frames": {"camera": "has space"}})
