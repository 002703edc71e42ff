"""industrial_calibration importer: layout, skips and errors (real images from tests/data/circle_grid)."""

import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from handeye.app.formats import detect_format, load
from handeye.app.errors import ConfigError, SessionError

SRC = Path(__file__).parents[2] / "data" / "circle_grid"


@pytest.fixture
def small_set(tmp_path):
    """Three views of the circle-grid set, plus a blank image the detector cannot use."""
    cal = yaml.safe_load((SRC / "cal_data.yaml").read_text())
    (tmp_path / "images").mkdir()
    (tmp_path / "poses").mkdir()
    for i in range(3):
        shutil.copy(SRC / f"images/{i}.png", tmp_path / f"images/{i}.png")
        shutil.copy(SRC / f"poses/{i}.yaml", tmp_path / f"poses/{i}.yaml")
    cv2.imwrite(str(tmp_path / "images/blank.png"), np.full((480, 640), 128, np.uint8))
    cal["data"] = [{"pose": f"poses/{i}.yaml", "image": f"images/{i}.png"} for i in range(3)]
    cal["data"].insert(1, {"pose": "poses/0.yaml", "image": "images/blank.png"})
    return tmp_path, cal


def _write(root, cal):
    (root / "cal_data.yaml").write_text(yaml.safe_dump(cal))
    return root / "cal_data.yaml"


def test_blank_view_is_skipped_with_its_reason(small_set):
    root, cal = small_set
    path = _write(root, cal)
    assert detect_format(path) == detect_format(root) == "industrial_calibration"
    imp = load(root)
    assert imp.setup == "eye_in_hand"            # static_camera: false
    assert [o.meta["image"] for o in imp.observations] == ["images/0.png", "images/1.png", "images/2.png"]
    assert imp.meta["skipped"][0]["image"] == "images/blank.png"
    assert "not found" in imp.meta["skipped"][0]["reason"]
    o = imp.observations[0]
    # The point the point-only solvers use is the target origin, with the PnP covariance's translation block.
    np.testing.assert_allclose(o.point_cam, o.T_cam_marker[:3, 3])
    np.testing.assert_allclose(o.point_cov, o.pose_cov[3:, 3:])
    assert 0 < np.sqrt(np.trace(o.point_cov)) < 0.01


def test_static_camera_means_eye_to_hand(small_set):
    root, cal = small_set
    cal["static_camera"] = True
    assert load(_write(root, cal)).setup == "eye_to_hand"


def test_errors_name_the_field_or_file(small_set):
    root, cal = small_set
    bad = dict(cal, target_finder={"type": "DotGridTargetFinder"})
    with pytest.raises(ConfigError, match="DotGridTargetFinder"):
        load(_write(root, bad))
    bad = dict(cal, target_finder={k: v for k, v in cal["target_finder"].items() if k != "spacing"})
    with pytest.raises(ConfigError, match="'spacing'"):
        load(_write(root, bad))
    bad = dict(cal, intrinsics={"fx": 550.0})
    with pytest.raises(ConfigError, match="fx, fy, cx, cy"):
        load(_write(root, bad))
    bad = dict(cal, data=cal["data"] + [{"pose": "poses/0.yaml", "image": "images/missing.png"}])
    with pytest.raises(SessionError, match="missing.png"):
        load(_write(root, bad))
    (root / "poses/1.yaml").write_text("x: 0.1\ny: 0.2\n")
    with pytest.raises(SessionError, match=r"1.yaml: missing field 'z'"):
        load(_write(root, cal))
    only_blank = dict(cal, data=[{"pose": "poses/0.yaml", "image": "images/blank.png"}])
    with pytest.raises(SessionError, match="found in none"):
        load(_write(root, only_blank))


def test_formats_import_neither_rerun_nor_drivers():
    code = ("import sys, handeye.app.formats, handeye.app.formats.industrial, handeye.app.formats.pose_csv, "
            "handeye.app.formats.easy_handeye; "
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'rerun'} "
            "| {m.split('.')[1] for m in sys.modules if m.startswith('handeye.')} & {'drivers', 'mocks'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
