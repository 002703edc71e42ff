"""Detection of a circle grid with one large origin dot (the "modified circle grid").

The target of ros-industrial's industrial_calibration ``ModifiedCircleGridTargetFinder``:
``rows x cols`` dark dots on a light background, evenly spaced, one corner dot
larger than the rest. The large dot fixes the origin, so the grid's pose is
unambiguous although the dot pattern itself is symmetric.

Target frame (same orientation rule as `handeye.calib.vision.markers`): origin at the
center of the large dot, x along its row, y along its column, z out of the
printed face towards the viewer; dot ``(r, c)`` is at ``(c, r, 0) * spacing``.
Which of the two grid edges at the origin is "x" follows from that
right-handedness as seen by the camera, so the frame is the same in every
image. The result is a `handeye.calib.vision.markers.Detection` (``kind="circle_grid"``)
so that one PnP path serves all targets; it is valid for both setups (the
target is ``marker`` in ``T_cam_marker``).
"""

from __future__ import annotations

import functools
from typing import Annotated

import cv2
import numpy as np
from pydantic import ConfigDict, Field, model_validator

from handeye.calib.errors import MarkerNotFoundError
from handeye.calib.params import Fraction, Int, Params, PositiveFloat
from handeye.calib.vision.markers import Detection, check_gray

# A corner dot counts as the origin dot if its blob is this much larger than
# the next largest corner dot (industrial_calibration's big dot is 2x the
# diameter of the others).
ORIGIN_SIZE_RATIO = 1.3


class CircleGridSpec(Params):
    """Geometry of the modified circle grid and the blob-detector limits.

    Attributes
    ----------
    rows, cols : int
        Dots per column / per row (10 x 10 for the industrial_calibration target).
    spacing : float
        Distance between neighbouring dot centers, m.
    min_area, max_area : float
        Blob area limits, px^2.
    min_convexity : float
        Blobs less convex than this are rejected (print defects, glare).
    """

    model_config = ConfigDict(frozen=True)

    rows: Annotated[Int, Field(ge=2)] = 10
    cols: Annotated[Int, Field(ge=2)] = 10
    spacing: PositiveFloat = 0.0254
    min_area: PositiveFloat = 25.0
    max_area: PositiveFloat = 5000.0
    min_convexity: Fraction = 0.95

    @model_validator(mode="after")
    def _areas(self):
        if not self.min_area < self.max_area:
            raise ValueError(f"need min_area < max_area px^2, got {self.min_area!r}, {self.max_area!r}")
        return self

    def object_points(self) -> np.ndarray:
        """Dot centers (rows*cols, 3) in the target frame, row-major, m."""
        r, c = np.divmod(np.arange(self.rows * self.cols), self.cols)
        return np.column_stack([c * self.spacing, r * self.spacing, np.zeros(len(r))])

    def center(self) -> np.ndarray:
        """Center (3,) of the dot grid in the target frame, m."""
        return np.array([(self.cols - 1) * self.spacing / 2, (self.rows - 1) * self.spacing / 2, 0.0])


@functools.lru_cache(maxsize=8)
def _blob_detector(spec: CircleGridSpec) -> cv2.SimpleBlobDetector:
    p = cv2.SimpleBlobDetector_Params()
    p.minThreshold, p.maxThreshold, p.thresholdStep = 20, 220, 10
    p.minRepeatability = 3
    p.filterByColor, p.blobColor = True, 0
    p.filterByArea, p.minArea, p.maxArea = True, spec.min_area, spec.max_area
    p.filterByCircularity = False
    p.filterByInertia = False
    p.filterByConvexity, p.minConvexity = True, spec.min_convexity
    return cv2.SimpleBlobDetector_create(p)


def _orientations(grid: np.ndarray):
    """The 8 symmetries of a (rows, cols, 2) grid that keep its shape, as index arrays."""
    idx = np.arange(grid.shape[0] * grid.shape[1]).reshape(grid.shape[:2])
    cands = []
    for k in range(4):
        rot = np.rot90(idx, k)
        cands += [rot, rot.T]
    return [c for c in cands if c.shape == idx.shape]


def detect_circle_grid(image, spec: CircleGridSpec = CircleGridSpec()) -> Detection:
    """Find all dots of a modified circle grid and order them from the large origin dot.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3), uint8
    spec : CircleGridSpec

    Returns
    -------
    Detection
        ``kind="circle_grid"``, ``ids`` the row-major dot index
        (0 = origin dot), ``image_points`` (rows*cols, 2) px,
        ``object_points`` (rows*cols, 3) m in the target frame.

    Raises
    ------
    MarkerNotFoundError
        If the full grid is not found, or no corner dot is clearly the largest.
    """
    gray = check_gray(image)
    detector = _blob_detector(spec)
    pattern = (spec.cols, spec.rows)
    found, centers = cv2.findCirclesGrid(gray, pattern, flags=cv2.CALIB_CB_SYMMETRIC_GRID, blobDetector=detector)
    if not found:
        found, centers = cv2.findCirclesGrid(
            gray, pattern, flags=cv2.CALIB_CB_SYMMETRIC_GRID | cv2.CALIB_CB_CLUSTERING, blobDetector=detector
        )
    if not found:
        raise MarkerNotFoundError(f"{spec.rows}x{spec.cols} circle grid not found")
    pts = centers.reshape(spec.rows, spec.cols, 2).astype(float)

    keypoints = detector.detect(gray)
    kp_xy = np.array([k.pt for k in keypoints])
    kp_size = np.array([k.size for k in keypoints])
    corners = [(0, 0), (0, spec.cols - 1), (spec.rows - 1, 0), (spec.rows - 1, spec.cols - 1)]
    sizes = []
    for r, c in corners:
        d = np.linalg.norm(kp_xy - pts[r, c], axis=1)
        sizes.append(kp_size[np.argmin(d)])
    order = np.argsort(sizes)[::-1]
    if sizes[order[0]] < ORIGIN_SIZE_RATIO * sizes[order[1]]:
        raise MarkerNotFoundError(
            f"circle grid found but no corner dot is clearly the origin dot (corner blob sizes {np.round(sizes, 1)} px)"
        )
    origin = corners[order[0]]
    flat = pts.reshape(-1, 2)
    origin_flat = origin[0] * spec.cols + origin[1]
    for idx in _orientations(pts):
        if idx[0, 0] != origin_flat:
            continue
        p = flat[idx.ravel()].reshape(spec.rows, spec.cols, 2)
        ex, ey = p[0, 1] - p[0, 0], p[1, 0] - p[0, 0]
        # z towards the viewer: x, y appear clockwise-negative in the (u right, v down) image.
        if ex[0] * ey[1] - ex[1] * ey[0] < 0:
            ordered = p.reshape(-1, 2)
            break
    else:  # only reachable for a non-square grid seen with its axes swapped
        raise MarkerNotFoundError("circle grid origin dot found but the grid cannot be ordered from it")
    obj = spec.object_points()
    return Detection("circle_grid", np.arange(len(obj)), ordered.copy(), obj)
