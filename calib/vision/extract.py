"""One frame in, one marker measurement out: the entry the app calls per RGB-D frame.

`extract` detects the configured target, lifts its center to 3D from the
registered depth image (robust plane fit + ray intersection, with a 3x3
covariance from the depth noise model) and estimates the full target pose
(PnP, and its depth-refined variant, each with a 6x6 covariance).

The measurement is the same for both setups: eye-to-hand (static camera,
marker on the flange) uses ``point_cam`` / ``T_cam_marker`` as ``B_i``
directly; eye-in-hand (camera on the flange, static marker) does too —
``T_cam_marker`` is still the marker seen from the camera. Only the solver
interprets X and Y differently.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

import cv2
import numpy as np
from pydantic import ConfigDict, Field, model_validator

from handeye.calib.errors import DepthError, ExtractionError, MarkerNotFoundError
from handeye.calib.params import (
    Bool,
    Fraction,
    Int,
    NonNegativeFloat,
    NonNegativeInt,
    Params,
    PositiveFloat,
    PositiveInt,
    Str,
    Vector3,
)
from handeye.calib.transforms import skew
from handeye.calib.vision.lift import (
    DepthNoiseModel,
    fit_plane,
    intersect_ray,
    normalize_points,
    pnp_covariance,
    polygon_pixels,
    refine_pose_with_depth,
    solve_pnp,
)
from handeye.calib.vision.markers import (
    BoardSpec,
    check_gray,
    detect_charuco,
    detect_chessboard,
    detect_markers,
    get_dictionary,
)



class TargetConfig(Params):
    """What to look for and how to lift it (the ``[marker]`` table of the app config).

    Attributes
    ----------
    kind : str
        ``"aruco"`` (a single ArUco/AprilTag marker), ``"charuco"`` or ``"chessboard"``.
    dictionary : str
        OpenCV predefined dictionary (``"DICT_4X4_50"``, ``"DICT_APRILTAG_36h11"``, ...).
    marker_id : int
        The marker to use (aruco).
    marker_size : float
        Side of the marker's black square, m (aruco; ChArUco: the markers inside the squares).
    squares : tuple of int
        Board ``(columns, rows)`` of squares as ``cv2.aruco.CharucoBoard`` takes them.
    square_size : float
        Board square side, m (charuco, chessboard).
    use_depth : bool
        Lift with the depth image (True) or take the PnP translation (False,
        color-only cameras; much larger error along the ray).
    sigma_px : float
        Standard deviation of one corner coordinate, px (feeds both covariances).
    small_marker_px : float
        A marker whose side in the image is shorter than this (px) gets corner
        noise ``sigma_px * small_marker_px / side``: subpixel refinement degrades
        once the marker's cells span only a few pixels.
    border_margin_px : float
        A marker with a corner closer than this to the image border is rejected.
    depth_roi_scale : float
        The depth pixels used lie in the target polygon shrunk by this factor
        about its centroid (keeps off the plate edge's flying pixels).
    min_depth_pixels, min_valid_fraction, max_chi2_ratio, min_inlier_fraction
        Plane-fit rejection thresholds (see `handeye.calib.vision.lift.fit_plane`).
    depth_noise : DepthNoiseModel
        Per-pixel depth noise; a dict with its fields is accepted.
    offset_m : tuple of 3 float, optional
        Where the marker is, when known, m: eye-to-hand its centre in the
        flange frame (``t_flange_marker``, e.g. a measured TCP), eye-in-hand
        the static marker's centre in the base frame (``t_base_marker``).
        ``auto`` holds it (`handeye.calib.problem.CalibrationProblem.marker_offset`):
        it completes a recording whose tool never turned about two axes.
    offset_sigma_m : float
        Its 1-sigma per axis, m (0: held as given).
    """

    model_config = ConfigDict(frozen=True)

    kind: Literal["aruco", "charuco", "chessboard"] = "aruco"
    dictionary: Str = "DICT_4X4_50"
    marker_id: NonNegativeInt = 0
    marker_size: PositiveFloat = 0.05
    squares: tuple[PositiveInt, PositiveInt] = (5, 7)
    square_size: NonNegativeFloat = 0.0
    use_depth: Bool = True
    sigma_px: PositiveFloat = 0.25
    small_marker_px: PositiveFloat = 40.0
    border_margin_px: NonNegativeFloat = 2.0
    depth_roi_scale: Annotated[PositiveFloat, Field(le=1)] = 0.9
    min_depth_pixels: Annotated[Int, Field(ge=3)] = 30
    min_valid_fraction: Fraction = 0.3
    max_chi2_ratio: PositiveFloat = 9.0
    min_inlier_fraction: Fraction = 0.6
    depth_noise: DepthNoiseModel = Field(default_factory=DepthNoiseModel)
    offset_m: Vector3 | None = None
    offset_sigma_m: NonNegativeFloat = 0.0

    @model_validator(mode="after")
    def _target(self):
        if self.kind != "chessboard":
            get_dictionary(self.dictionary)
        if self.kind != "aruco":
            if self.square_size <= 0:
                raise ValueError(f"square_size must be > 0 for a {self.kind}, got {self.square_size!r}")
            self.board  # validates squares / sizes
        return self

    @property
    def board(self) -> BoardSpec:
        """The board of a charuco / chessboard target."""
        return BoardSpec(squares=self.squares, square_size=self.square_size,
                         marker_size=self.marker_size if self.kind == "charuco" else 0.0, dictionary=self.dictionary)


@dataclass(frozen=True)
class MarkerMeasurement:
    """What one frame says about the target, in the camera frame.

    Same for eye-to-hand and eye-in-hand (it is always the target seen from
    the camera: the paper's ``B_i = T_cam_marker`` in ``A_i X = Y B_i``
    (eq. 1), and its translation ``t_B``, all that the equation of translation
    ``R_Y t_B + t_Y - R_A t_X = t_A`` solved by YKronT' / YQuatT' needs).

    Attributes
    ----------
    point_cam : ndarray, shape (3,)
        Target center in the camera frame, m (marker center; board: center of
        its inner-corner grid). The input of YKronT' / YQuatT'.
    point_cov : ndarray, shape (3, 3)
        Its covariance, m^2.
    T_cam_marker : ndarray, shape (4, 4)
        Target pose; depth-refined when depth was used, else PnP.
    pose_cov : ndarray, shape (6, 6)
        Its covariance over ``[delta_rotvec (rad), delta_t (m)]`` (left perturbation).
    T_cam_marker_pnp : ndarray, shape (4, 4)
        The PnP pose (IPPE_SQUARE for a marker, IPPE for a board), the planar
        ambiguity resolved with the depth normal when available.
    pose_cov_pnp : ndarray, shape (6, 6)
    kind : str
    ids : ndarray
        Marker id (aruco) or the detected corner ids (boards).
    image_points : ndarray, shape (N, 2)
        Detected corners, px.
    center_px : ndarray, shape (2,)
        Target center in the image (distorted pixel coordinates).
    info : dict
        Diagnostics: ``n_depth_pixels``, ``n_inliers``, ``plane_rms_m``,
        ``chi2_ratio``, ``pnp_reproj_px``, ``pnp_depth_gap_m`` (distance between
        the PnP and depth centers; large = wrong ``marker_size`` or depth scale).
    """

    point_cam: np.ndarray
    point_cov: np.ndarray
    T_cam_marker: np.ndarray
    pose_cov: np.ndarray
    T_cam_marker_pnp: np.ndarray
    pose_cov_pnp: np.ndarray
    kind: str
    ids: np.ndarray
    image_points: np.ndarray
    center_px: np.ndarray
    info: dict


def _detect(gray: np.ndarray, target: TargetConfig):
    if target.kind == "aruco":
        dets = detect_markers(gray, target.dictionary, target.marker_size)
        match = [d for d in dets if int(d.ids[0]) == target.marker_id]
        if not match:
            seen = [int(d.ids[0]) for d in dets]
            raise MarkerNotFoundError(
                f"marker {target.marker_id} of {target.dictionary} not found"
                + (f" (seen ids {seen})" if seen else " (no marker in view)")
            )
        return match[0], np.zeros(3)
    if target.kind == "charuco":
        return detect_charuco(gray, target.board), target.board.center("charuco")
    return detect_chessboard(gray, target.board), target.board.center("chessboard")


def extract(color, depth, intrinsics, target: TargetConfig) -> MarkerMeasurement:
    """Detect the target in one RGB-D frame and measure it in 3D.

    Parameters
    ----------
    color : ndarray, shape (H, W, 3) BGR or (H, W), uint8
    depth : ndarray, shape (H, W), float, m, registered to ``color``; 0 / NaN
        where there is no reading. May be None when ``target.use_depth`` is False.
    intrinsics : object with ``K`` (3, 3) and ``dist`` (OpenCV coefficients)
        E.g. `handeye.drivers.camera.base.CameraIntrinsics`.
    target : TargetConfig

    Returns
    -------
    MarkerMeasurement

    Raises
    ------
    MarkerNotFoundError
        No (or not the configured) marker; a marker touching the image border;
        PnP failure.
    DepthError
        No / empty / wrongly shaped depth image, too few valid depth pixels on
        the target, a bad plane fit.
    """
    gray = check_gray(color, "color")
    K = np.asarray(intrinsics.K, dtype=float)
    dist = np.asarray(intrinsics.dist, dtype=float)
    det, center_obj = _detect(gray, target)
    h, w = gray.shape
    pts = det.image_points
    sigma_px = _corner_sigma_px(pts, target, (h, w))

    cands = solve_pnp(pts, det.object_points, K, dist, square=target.kind == "aruco")
    # Center ray: the target-plane homography maps the center exactly even under
    # perspective (for a marker it is the intersection of the diagonals).
    xy = normalize_points(pts, K, dist)
    H, _ = cv2.findHomography(det.object_points[:, :2], xy, 0)
    if H is None:
        raise MarkerNotFoundError("degenerate corners: no homography")
    c = H @ np.array([center_obj[0], center_obj[1], 1.0])
    xy_c = c[:2] / c[2]
    # Averaging N corners of noise sigma_px gives ~sigma_px^2 * 2/N per axis (N = 4: the diagonals).
    var_c = sigma_px**2 * 2.0 / len(pts)
    cov_xy = np.diag([var_c / K[0, 0] ** 2, var_c / K[1, 1] ** 2])
    center_px = cv2.projectPoints(
        np.array([[xy_c[0], xy_c[1], 1.0]]), np.zeros(3), np.zeros(3), K, dist
    )[0].reshape(2)
    info: dict = {"pnp_reproj_px": cands[0][1], "sigma_px": sigma_px}

    if not target.use_depth:
        T_pnp = cands[0][0]
        cov_pnp = pnp_covariance(T_pnp, det.object_points, K, sigma_px)
        # point = R c + t: the same lever arm as in refine_pose_with_depth.
        Sc = skew(T_pnp[:3, :3] @ center_obj)
        J = np.hstack([Sc, np.eye(3)])
        point = T_pnp[:3, :3] @ center_obj + T_pnp[:3, 3]
        return MarkerMeasurement(
            point, J @ cov_pnp @ J.T, T_pnp, cov_pnp, T_pnp, cov_pnp, det.kind, det.ids, pts, center_px, info
        )

    plane = _target_plane(depth, pts, K, dist, target, (h, w))
    point, point_cov = intersect_ray(plane, xy_c, cov_xy, target.depth_noise)
    # Planar ambiguity: keep the PnP solution whose plane agrees with the depth plane.
    T_pnp = max(cands, key=lambda cand: abs(cand[0][:3, 2] @ plane.normal))[0]
    cov_pnp = pnp_covariance(T_pnp, det.object_points, K, sigma_px)
    T, cov = refine_pose_with_depth(T_pnp, cov_pnp, plane, center_obj, point, point_cov)
    info.update(
        n_depth_pixels=plane.n_valid,
        n_inliers=plane.n_inliers,
        plane_rms_m=plane.rms,
        chi2_ratio=plane.chi2_ratio,
        pnp_depth_gap_m=float(np.linalg.norm(T_pnp[:3, :3] @ center_obj + T_pnp[:3, 3] - point)),
    )
    return MarkerMeasurement(point, point_cov, T, cov, T_pnp, cov_pnp, det.kind, det.ids, pts, center_px, info)




def _corner_sigma_px(pts, target: TargetConfig, shape) -> float:
    """Corner noise (px) of the detection ``pts``: the configured one, grown for a small ArUco marker; a marker
    touching the image border is refused."""
    sigma_px = target.sigma_px
    if target.kind == "aruco":
        h, w = shape
        m = target.border_margin_px
        if (pts.min(axis=0) < m).any() or (pts[:, 0] > w - 1 - m).any() or (pts[:, 1] > h - 1 - m).any():
            raise MarkerNotFoundError(f"marker {target.marker_id} touches the image border")
        d1, d2 = pts[2] - pts[0], pts[3] - pts[1]
        side = np.sqrt(abs(d1[0] * d2[1] - d1[1] * d2[0]) / 2.0)  # sqrt of the quad's area
        sigma_px *= max(1.0, target.small_marker_px / max(side, 1e-9))
    return sigma_px

def _target_plane(depth, pts, K, dist, target: TargetConfig, shape):
    """The depth plane fitted inside the target's corners ``pts`` (`fit_plane`), after checking the depth image."""
    if depth is None or np.asarray(depth).size == 0:
        raise DepthError("no depth image")
    depth = np.asarray(depth)
    if not np.issubdtype(depth.dtype, np.floating):
        raise DepthError(f"depth must be float metres, got dtype {depth.dtype}")
    if depth.shape != shape:
        raise DepthError(f"depth image shape {depth.shape} does not match color {shape}")
    hull = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2)
    rows, cols = polygon_pixels(hull, shape, target.depth_roi_scale)
    return fit_plane(
        depth, rows, cols, K, dist, target.depth_noise,
        min_pixels=target.min_depth_pixels,
        min_valid_fraction=target.min_valid_fraction,
        max_chi2_ratio=target.max_chi2_ratio,
        min_inlier_fraction=target.min_inlier_fraction,
    )

def try_extract(color, depth, intrinsics, target: TargetConfig) -> tuple[MarkerMeasurement | None, str]:
    """`extract`, but a bad frame gives ``(None, reason)`` instead of raising.

    Only `ExtractionError` (marker not found / at the border, depth problems)
    becomes a skip; anything else is a bug and propagates.
    """
    try:
        return extract(color, depth, intrinsics, target), ""
    except ExtractionError as e:
        return None, str(e)
