"""Fiducial detection: ArUco / AprilTag markers, ChArUco boards, chessboards.

Pure functions over images (numpy arrays); no device I/O. Every detector
returns subpixel image corners together with the matching 3D points in the
target's own frame (metres, target plane ``z = 0``), so that one PnP / depth
lifting path (`handeye.calib.vision.lift`) serves all target kinds.

Target frames follow OpenCV: a marker's origin is its center, x to the right,
y up on the printed bitmap, z out of the face towards the viewer; corners are
ordered top-left, top-right, bottom-right, bottom-left (the order of
``cv2.aruco`` and of ``SOLVEPNP_IPPE_SQUARE``). A ChArUco board / chessboard
has its origin at the first inner corner as OpenCV defines it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Annotated

import cv2
import numpy as np
from pydantic import ConfigDict, Field, model_validator

from handeye.calib.errors import MarkerNotFoundError, ParameterError
from handeye.calib.params import Int, NonNegativeFloat, Params, PositiveFloat, Str


@dataclass(frozen=True)
class Detection:
    """A detected target in one image.

    Attributes
    ----------
    kind : str
        ``"aruco"``, ``"charuco"`` or ``"chessboard"``.
    ids : ndarray, shape (N,), int
        Marker id (aruco, N = 1 per marker) or corner ids (charuco,
        chessboard: row-major index of the inner corner).
    image_points : ndarray, shape (N, 2)
        Subpixel image coordinates, px (distorted, as seen in the image).
    object_points : ndarray, shape (N, 3)
        The same points in the target frame, m (``z = 0``).
    """

    kind: str
    ids: np.ndarray
    image_points: np.ndarray
    object_points: np.ndarray


def check_gray(image, name: str = "image") -> np.ndarray:
    """Return a single-channel uint8 view of ``image`` (H, W) or (H, W, 3) BGR.

    Raises
    ------
    MarkerNotFoundError
        If the image is empty or of an unsupported shape / dtype (the frame is skipped).
    """
    image = np.asarray(image)
    if image.size == 0:
        raise MarkerNotFoundError(f"{name} is empty")
    if image.dtype != np.uint8:
        raise MarkerNotFoundError(f"{name} must be uint8, got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 2:
        return image
    raise MarkerNotFoundError(f"{name} must have shape (H, W) or (H, W, 3), got {image.shape}")


def get_dictionary(name: str) -> cv2.aruco.Dictionary:
    """OpenCV predefined dictionary by name, e.g. ``"DICT_4X4_50"``, ``"DICT_APRILTAG_36h11"``.

    Raises
    ------
    ParameterError
        Naming the unknown dictionary.
    """
    key = name if name.startswith("DICT_") else f"DICT_{name}"
    if not hasattr(cv2.aruco, key):
        known = sorted(k for k in dir(cv2.aruco) if k.startswith("DICT_"))
        raise ParameterError(f"unknown marker dictionary {name!r} (known: {', '.join(known)})")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, key))


@functools.lru_cache(maxsize=16)
def _aruco_detector(dictionary: str) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    # Subpixel corners: the 3D center is only as good as the corners that define its ray.
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementWinSize = 3
    return cv2.aruco.ArucoDetector(get_dictionary(dictionary), params)


def marker_object_points(size: float) -> np.ndarray:
    """Corners (4, 3) of a square marker of side ``size`` m in its own frame (IPPE_SQUARE order)."""
    h = size / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def detect_markers(image, dictionary: str = "DICT_4X4_50", size: float = 0.05) -> list[Detection]:
    """Detect every marker of ``dictionary`` in ``image``.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3), uint8
    dictionary : str
        OpenCV predefined dictionary name (ArUco or AprilTag families).
    size : float
        Marker side (black square), m; sets ``object_points``.

    Returns
    -------
    list of Detection
        One per marker (``kind="aruco"``, ``ids`` of length 1), sorted by id;
        empty if none is found.
    """
    gray = check_gray(image)
    corners, ids, _ = _aruco_detector(dictionary).detectMarkers(gray)
    if ids is None:
        return []
    obj = marker_object_points(size)
    dets = [
        Detection("aruco", np.array([int(i)]), c.reshape(4, 2).astype(float), obj)
        for c, i in zip(corners, ids.ravel())
    ]
    return sorted(dets, key=lambda d: int(d.ids[0]))


class BoardSpec(Params):
    """A ChArUco board or chessboard.

    ``squares = (columns, rows)`` as OpenCV's ``CharucoBoard((cols, rows), ...)``
    (e.g. ``(5, 7)`` for the industrial_calibration 7-row x 5-column board);
    a chessboard of ``squares`` has ``(cols - 1) x (rows - 1)`` inner corners.
    """

    model_config = ConfigDict(frozen=True)

    squares: tuple[Annotated[Int, Field(ge=2)], Annotated[Int, Field(ge=2)]]
    square_size: PositiveFloat
    marker_size: NonNegativeFloat = 0.0
    dictionary: Str = "DICT_6X6_250"

    @model_validator(mode="after")
    def _marker_in_square(self):
        if self.marker_size >= self.square_size:
            raise ValueError(f"marker_size must be in [0, square_size) m, got {self.marker_size!r}")
        return self

    def inner_corners(self, kind: str) -> np.ndarray:
        """All inner corners (N, 3) in the board frame of a ``"charuco"`` or ``"chessboard"`` target, m."""
        if kind == "charuco":
            return np.asarray(_charuco(self)[0].getChessboardCorners(), dtype=float)
        cols, rows = self.squares
        ij = np.stack(np.meshgrid(np.arange(cols - 1), np.arange(rows - 1)), -1).reshape(-1, 2)
        return np.column_stack([ij * self.square_size, np.zeros(len(ij))])

    def center(self, kind: str) -> np.ndarray:
        """Center (3,) of the inner-corner grid in the board frame, m: the board's "marker center"."""
        c = self.inner_corners(kind)
        return (c.min(axis=0) + c.max(axis=0)) / 2.0


@functools.lru_cache(maxsize=8)
def _charuco(board: BoardSpec):
    b = cv2.aruco.CharucoBoard(
        tuple(int(s) for s in board.squares), board.square_size, board.marker_size, get_dictionary(board.dictionary)
    )
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return b, cv2.aruco.CharucoDetector(b, cv2.aruco.CharucoParameters(), params)


def detect_charuco(image, board: BoardSpec, min_corners: int = 4) -> Detection:
    """Detect the inner chessboard corners of a ChArUco board (subpixel, interpolated from its markers).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3), uint8
    board : BoardSpec
        With ``marker_size > 0``.
    min_corners : int
        Fewer corners raise.

    Returns
    -------
    Detection
        ``kind="charuco"``, ``ids`` are OpenCV's corner ids, ``object_points``
        in the board frame.

    Raises
    ------
    MarkerNotFoundError
        Fewer than ``min_corners`` corners found.
    """
    if board.marker_size <= 0:
        raise ParameterError("a ChArUco board needs marker_size > 0")
    gray = check_gray(image)
    b, detector = _charuco(board)
    ch_corners, ch_ids, _, _ = detector.detectBoard(gray)
    n = 0 if ch_ids is None else len(ch_ids)
    if n < min_corners:
        raise MarkerNotFoundError(f"ChArUco board: {n} corners found, need {min_corners}")
    ids = ch_ids.ravel().astype(int)
    obj = np.asarray(b.getChessboardCorners(), dtype=float)[ids]
    return Detection("charuco", ids, ch_corners.reshape(-1, 2).astype(float), obj)


def detect_chessboard(image, board: BoardSpec) -> Detection:
    """Detect all inner corners of a chessboard (``board.squares`` squares), subpixel.

    Uses ``cv2.findChessboardCornersSB`` (sector-based, subpixel by design).

    Raises
    ------
    MarkerNotFoundError
        If the full grid is not found.
    """
    gray = check_gray(image)
    cols, rows = board.squares
    pattern = (cols - 1, rows - 1)
    found, corners = cv2.findChessboardCornersSB(gray, pattern, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        raise MarkerNotFoundError(f"chessboard with {pattern[0]}x{pattern[1]} inner corners not found")
    obj = board.inner_corners("chessboard")
    return Detection("chessboard", np.arange(len(obj)), corners.reshape(-1, 2).astype(float), obj)
