"""handeye.calib.vision.circle_grid on a real 10x10 image (tests/data/circle_grid) and on doctored copies."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from handeye.calib.errors import MarkerNotFoundError, ParameterError
from handeye.calib.vision.circle_grid import CircleGridSpec, detect_circle_grid

IMAGE = Path(__file__).parents[2] / "data" / "circle_grid" / "images" / "0.png"
K = np.array([[550.0, 0, 320], [0, 550.0, 240], [0, 0, 1]])


@pytest.fixture(scope="module")
def gray():
    return cv2.imread(str(IMAGE), cv2.IMREAD_GRAYSCALE)


def _pose(det):
    ok, rv, tv = cv2.solvePnP(det.object_points, det.image_points, K, None)
    return cv2.Rodrigues(rv)[0], tv.ravel()


def test_finds_all_dots_from_the_large_one(gray):
    det = detect_circle_grid(gray)
    assert det.kind == "circle_grid" and det.image_points.shape == (100, 2)
    # In 0.png the large dot is the bottom-left dot of the grid (seen by eye).
    u, v = det.image_points[:, 0], det.image_points[:, 1]
    assert det.image_points[0] == pytest.approx([u.min(), v.max()], abs=15)
    R, t = _pose(det)
    assert R[2, 2] < 0        # target z points back at the camera
    assert 0.6 < t[2] < 0.9   # the board is ~0.77 m away (PnP with nominal intrinsics)
    proj = cv2.projectPoints(det.object_points, cv2.Rodrigues(R)[0], t, K, None)[0].reshape(-1, 2)
    assert np.sqrt(np.mean(np.sum((proj - det.image_points) ** 2, axis=1))) < 0.5   # 0.24 px measured


@pytest.mark.parametrize("k", [1, 2, 3])
def test_frame_follows_the_large_dot_when_the_image_is_rotated(gray, k):
    """The target frame is a property of the board: rotating the camera must not change it."""
    ref = detect_circle_grid(gray)
    rot = np.ascontiguousarray(np.rot90(gray, k))
    det = detect_circle_grid(rot)
    h, w = gray.shape
    # Where each original dot lands in the rotated image (np.rot90 turns counter-clockwise).
    u, v = ref.image_points[:, 0], ref.image_points[:, 1]
    for _ in range(k):
        u, v = v, w - 1 - u
        h, w = w, h
    np.testing.assert_allclose(det.image_points, np.column_stack([u, v]), atol=0.05)


def test_missing_grid_and_missing_origin_dot(gray):
    with pytest.raises(MarkerNotFoundError, match="circle grid not found"):
        detect_circle_grid(np.full_like(gray, 200))
    det = detect_circle_grid(gray)
    doctored = gray.copy()
    # Repaint the large dot as a small one: the grid is still there but has no origin.
    x, y = det.image_points[0].round().astype(int)
    cv2.circle(doctored, (x, y), 14, int(np.median(gray[y - 20:y + 20, x + 25:x + 40])), -1)
    r = int(round(np.linalg.norm(det.image_points[1] - det.image_points[0]) * 0.25))
    cv2.circle(doctored, (x, y), r, int(gray.min()), -1)
    with pytest.raises(MarkerNotFoundError, match="origin dot"):
        detect_circle_grid(doctored)


def test_spec_is_validated():
    with pytest.raises(ParameterError, match="spacing"):
        CircleGridSpec(spacing=0.0)
    with pytest.raises(ParameterError, match="rows"):
        CircleGridSpec(rows=1)
