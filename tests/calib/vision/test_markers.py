"""Detection of ArUco / AprilTag markers, ChArUco boards and chessboards on synthetic images."""

import cv2
import numpy as np
import pytest

from handeye.calib.errors import MarkerNotFoundError, ParameterError
from handeye.calib.vision.markers import BoardSpec, detect_charuco, detect_chessboard, detect_markers, get_dictionary


def _marker_image(dictionary: str, marker_id: int, side: int = 120, pad: int = 60) -> np.ndarray:
    bmp = cv2.aruco.generateImageMarker(get_dictionary(dictionary), marker_id, side, borderBits=1)
    return cv2.copyMakeBorder(bmp, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)


@pytest.mark.parametrize("dictionary, marker_id", [("DICT_4X4_50", 0), ("DICT_6X6_250", 17), ("DICT_APRILTAG_36h11", 5)])
def test_detects_marker_with_subpixel_corners(dictionary, marker_id):
    img = _marker_image(dictionary, marker_id)
    dets = detect_markers(img, dictionary, size=0.05)
    assert [int(d.ids[0]) for d in dets] == [marker_id]
    # The black square spans pixels 60 .. 179, i.e. its outer edges lie at 59.5 and 179.5.
    expected = np.array([[59.5, 59.5], [179.5, 59.5], [179.5, 179.5], [59.5, 179.5]])
    np.testing.assert_allclose(dets[0].image_points, expected, atol=0.3)
    np.testing.assert_allclose(dets[0].object_points[0], [-0.025, 0.025, 0.0])


def test_no_marker_gives_empty_list_and_bad_images_raise():
    assert detect_markers(np.full((100, 100), 128, np.uint8)) == []
    with pytest.raises(MarkerNotFoundError, match="empty"):
        detect_markers(np.zeros((0, 0), np.uint8))
    with pytest.raises(MarkerNotFoundError, match="uint8"):
        detect_markers(np.zeros((10, 10), np.float32))


def test_unknown_dictionary_is_named():
    with pytest.raises(ParameterError, match="DICT_9X9_1"):
        get_dictionary("DICT_9X9_1")


def test_charuco_board_all_corners():
    board = BoardSpec(squares=(5, 7), square_size=0.04, marker_size=0.02, dictionary="DICT_6X6_250")
    cv_board = cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02, get_dictionary("DICT_6X6_250"))
    img = cv_board.generateImage((480, 640), marginSize=40)
    det = detect_charuco(img, board)
    assert len(det.ids) == 4 * 6
    # 80 px per 4 cm square: pixel = 40 px margin + object point * 2000 px/m (pixel centers at .0).
    np.testing.assert_allclose(det.image_points, 40 + det.object_points[:, :2] * 2000 - 0.5, atol=0.3)
    np.testing.assert_allclose(board.center("charuco"), [0.1, 0.14, 0.0])


def test_charuco_too_few_corners_raises():
    board = BoardSpec(squares=(5, 7), square_size=0.04, marker_size=0.02, dictionary="DICT_6X6_250")
    with pytest.raises(MarkerNotFoundError, match="0 corners"):
        detect_charuco(np.full((300, 300), 200, np.uint8), board)


def test_chessboard():
    board = BoardSpec(squares=(7, 5), square_size=0.03)
    sq = 40
    img = np.full((5 * sq + 80, 7 * sq + 80), 255, np.uint8)
    for r in range(5):
        for c in range(7):
            if (r + c) % 2 == 0:
                img[40 + r * sq:40 + (r + 1) * sq, 40 + c * sq:40 + (c + 1) * sq] = 0
    det = detect_chessboard(img, board)
    assert len(det.ids) == 6 * 4
    # Inner corners are at multiples of 40 px from the first one, along rows or columns.
    d = np.diff(det.image_points[:6], axis=0)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), sq, atol=0.3)
    with pytest.raises(MarkerNotFoundError, match="6x4"):
        detect_chessboard(np.full((200, 200), 255, np.uint8), board)


def test_board_spec_validation_names_field():
    with pytest.raises(ParameterError, match="marker_size"):
        BoardSpec(squares=(5, 7), square_size=0.03, marker_size=0.04)
    with pytest.raises(ParameterError, match="square_size"):
        BoardSpec(squares=(5, 7), square_size=0.0)
