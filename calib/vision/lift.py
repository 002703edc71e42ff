"""Lift a detected planar target to 3D: PnP pose, depth plane fit, ray-plane center.

Pure functions over numpy / OpenCV, camera frame throughout (OpenCV optical
frame: x right, y down, z along the optical axis, metres).

The depth plane is fitted in *inverse depth*: a plane ``n . p = d`` seen
along the undistorted ray ``r = (x, y, 1)`` satisfies
``1 / z = (n_x x + n_y y + n_z) / d``, i.e. ``w = 1/z = a x + b y + c`` is
*linear* in the normalized coordinates. So the fit is a weighted linear least
squares with an exact parameter covariance, and a structured-light sensor's
noise (``sigma_z ~ z^2``, i.e. constant in disparity ~ ``1/z``) makes the
weights almost uniform. The center's ray then meets the plane at
``z_c = 1 / (a x_c + b y_c + c)``.

Covariance convention (as `handeye.calib.result`): a pose perturbation is the
6-vector ``[delta_rotvec (rad), delta_t (m)]`` with
``R_true = Exp(delta_rotvec) @ R_est`` and ``t_true = t_est + delta_t``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import cv2
import numpy as np
from pydantic import ConfigDict, Field, model_validator

from handeye.calib import transforms as tf
from handeye.calib.errors import DepthError, MarkerNotFoundError
from handeye.calib.params import Float, NonNegativeFloat, Params


def _rotvec_to_matrix(rv) -> np.ndarray:
    # cv2.Rodrigues instead of scipy's Rotation: far less call overhead, and this runs per frame.
    return cv2.Rodrigues(np.asarray(rv, dtype=np.float64).reshape(3, 1))[0]


class DepthNoiseModel(Params):
    """Per-pixel depth noise of a structured-light (Xtion / Kinect v1) sensor.

    ``sigma_z(z) = sqrt(sigma_0^2 + (k z^2)^2)`` per pixel, independent between
    pixels, plus a per-frame systematic error ``k_sys z^2`` along the ray that
    no amount of averaging removes (calibration drift of the projector-camera
    pair). Defaults: ``k = 1.7e-3 /m`` (Khoshelham & Oude Elberink 2012 report
    1.5e-3 /m random; the 1/8 px disparity quantisation of a 7.5 cm baseline,
    f = 570 px, adds ~0.8e-3 /m in quadrature), ``sigma_0`` the 1 mm output
    rounding (``1e-3 / sqrt(12)`` m), ``k_sys = 0.5e-3 /m``.

    Neighbouring pixels are not independent (quantisation steps run across a
    tilted plane, speckle spans pixels), so a plane fit is credited with at most
    ``max_independent_pixels`` pixels: its covariance is scaled by
    ``n / max_independent_pixels`` beyond that (200 makes the plane normal's
    NEES honest on rendered Xtion-like frames at 0.5-1 m).
    """

    model_config = ConfigDict(frozen=True)

    k: NonNegativeFloat = 1.7e-3
    sigma_0: NonNegativeFloat = 1e-3 / np.sqrt(12.0)
    k_sys: NonNegativeFloat = 0.5e-3
    max_independent_pixels: Annotated[Float, Field(ge=3)] = 200.0

    @model_validator(mode="after")
    def _some_noise(self):
        if self.k == 0 and self.sigma_0 == 0:
            raise ValueError("k and sigma_0 cannot both be 0")
        return self

    def sigma(self, z) -> np.ndarray:
        """Per-pixel depth standard deviation (m) at depth(s) ``z`` (m)."""
        z = np.asarray(z, dtype=float)
        return np.sqrt(self.sigma_0**2 + (self.k * z**2) ** 2)


def normalize_points(pixels, K: np.ndarray, dist) -> np.ndarray:
    """Undistorted normalized coordinates (N, 2) of pixel coordinates (N, 2)."""
    pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
    if not np.any(dist):
        return (pixels - K[:2, 2]) / np.array([K[0, 0], K[1, 1]])
    return cv2.undistortPoints(pixels.reshape(-1, 1, 2), K, np.asarray(dist, float)).reshape(-1, 2)


def pnp_covariance(T_cam_target, object_points, K: np.ndarray, sigma_px: float) -> np.ndarray:
    """6x6 covariance of a PnP pose from isotropic pixel noise (Gauss-Newton, first order).

    Parameters
    ----------
    T_cam_target : ndarray, shape (4, 4)
    object_points : ndarray, shape (N, 3)
        Target points in the target frame, m.
    K : ndarray, shape (3, 3)
    sigma_px : float
        Standard deviation of each image coordinate, px.

    Returns
    -------
    cov : ndarray, shape (6, 6)
        ``sigma_px^2 (J^T J)^-1`` over ``[delta_rotvec, delta_t]`` (left perturbation);
        lens distortion is neglected in the Jacobian (a few % effect).
    """
    Rp = object_points @ T_cam_target[:3, :3].T
    P = Rp + T_cam_target[:3, 3]
    X, Y, Z = P.T
    fx, fy = K[0, 0], K[1, 1]
    J = np.zeros((2 * len(P), 6))
    for i in range(len(P)):
        dpi = np.array([[fx / Z[i], 0.0, -fx * X[i] / Z[i] ** 2], [0.0, fy / Z[i], -fy * Y[i] / Z[i] ** 2]])
        # d(Exp(w) R p)/dw = -[R p]_x at w = 0.
        J[2 * i : 2 * i + 2, :3] = dpi @ -tf.skew(Rp[i])
        J[2 * i : 2 * i + 2, 3:] = dpi
    return sigma_px**2 * np.linalg.pinv(J.T @ J)


def solve_pnp(image_points, object_points, K: np.ndarray, dist, *, square: bool) -> list[tuple[np.ndarray, float]]:
    """Planar PnP candidates: the (up to two) IPPE solutions, best first.

    Parameters
    ----------
    image_points : ndarray, shape (N, 2), px
    object_points : ndarray, shape (N, 3), m, all with ``z = 0``
    K : ndarray, shape (3, 3)
    dist : array_like, OpenCV distortion coefficients
    square : bool
        Use ``SOLVEPNP_IPPE_SQUARE`` (a single marker, N = 4, IPPE order).

    Returns
    -------
    list of (T_cam_target (4, 4), reprojection RMS px)
        Both planar-ambiguity solutions: a small or fronto-parallel target
        makes them nearly equally good, which the depth normal resolves.

    Raises
    ------
    MarkerNotFoundError
        If PnP fails (degenerate corners).
    """
    flag = cv2.SOLVEPNP_IPPE_SQUARE if square else cv2.SOLVEPNP_IPPE
    obj = np.ascontiguousarray(object_points, dtype=np.float64)
    img = np.ascontiguousarray(image_points, dtype=np.float64).reshape(-1, 1, 2)
    dist = np.asarray(dist, dtype=np.float64)
    ok, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, K, dist, flags=flag)
    def run(method):
        try:
            ok, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, K, dist, flags=method)
        except cv2.error:  # collinear or too few points: a degenerate detection, not a bug
            return []
        if not ok:
            return []
        return [
            (rv, t, e) for rv, t, e in zip(rvecs, tvecs, np.ravel(errs))
            if np.isfinite(rv).all() and np.isfinite(t).all()
        ]

    sols = run(flag)
    if not sols:
        # IPPE returns NaN for an exactly fronto-parallel view; the iterative solver does not.
        sols = run(cv2.SOLVEPNP_ITERATIVE)
    if not sols:
        raise MarkerNotFoundError("PnP failed on the detected corners (degenerate geometry)")
    out = []
    for rv, t, e in sols:
        T = tf.make_transform(_rotvec_to_matrix(rv), t.ravel())
        if T[2, 3] > 0:
            out.append((T, float(e)))
    if not out:
        raise MarkerNotFoundError("PnP put the target behind the camera")
    return sorted(out, key=lambda c: c[1])


@dataclass(frozen=True)
class PlaneFit:
    """Inverse-depth plane ``1/z = a x + b y + c`` fitted to the target's depth pixels.

    Attributes
    ----------
    abc : ndarray, shape (3,)
        ``(a, b, c) = n / d`` for the plane ``n . p = d`` (``n`` unit, ``d > 0``).
    cov : ndarray, shape (3, 3)
        Covariance of ``abc``, inflated by ``chi2_ratio`` when the data are
        noisier than the noise model says, and for correlated pixels
        (`DepthNoiseModel.max_independent_pixels`).
    n_valid, n_inliers : int
        Pixels with a depth reading inside the ROI / kept by the robust fit.
    chi2_ratio : float
        Weighted residual sum of squares per degree of freedom (1 when the
        noise model is right).
    rms : float
        RMS depth residual of the inliers, m.
    """

    abc: np.ndarray
    cov: np.ndarray
    n_valid: int
    n_inliers: int
    chi2_ratio: float
    rms: float

    @property
    def normal(self) -> np.ndarray:
        """Unit plane normal (3,), pointing away from the camera."""
        return self.abc / np.linalg.norm(self.abc)

    @property
    def normal_cov(self) -> np.ndarray:
        """Covariance (3, 3) of `normal` (rank 2, tangent to the unit sphere)."""
        J = (np.eye(3) - np.outer(self.normal, self.normal)) / np.linalg.norm(self.abc)
        return J @ self.cov @ J.T


def polygon_pixels(polygon, shape: tuple[int, int], scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (rows, cols) inside ``polygon`` (M, 2) shrunk about its centroid by ``scale``."""
    polygon = np.asarray(polygon, dtype=float)
    c = polygon.mean(axis=0)
    poly = c + scale * (polygon - c)
    x0, y0 = np.floor(poly.min(axis=0)).astype(int)
    x1, y1 = np.ceil(poly.max(axis=0)).astype(int)
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x1, shape[1] - 1), min(y1, shape[0] - 1)
    if x1 < x0 or y1 < y0:
        return np.empty(0, int), np.empty(0, int)
    mask = np.zeros((y1 - y0 + 1, x1 - x0 + 1), np.uint8)
    hull = cv2.convexHull(np.round((poly - [x0, y0]) * 16).astype(np.int32))
    cv2.fillConvexPoly(mask, hull, 1, lineType=cv2.LINE_8, shift=4)
    rows, cols = np.nonzero(mask)
    return rows + y0, cols + x0


def fit_plane(
    depth: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    K: np.ndarray,
    dist,
    noise: DepthNoiseModel,
    *,
    min_pixels: int = 30,
    min_valid_fraction: float = 0.3,
    max_chi2_ratio: float = 9.0,
    min_inlier_fraction: float = 0.6,
) -> PlaneFit:
    """Robust weighted plane fit in inverse depth to ``depth[rows, cols]``.

    Three reweighting rounds reject pixels beyond 3.5 robust sigmas (holes
    filled with the background, flying pixels at the plate edge).

    Parameters
    ----------
    depth : ndarray, shape (H, W), float, m; 0 / NaN = no reading
    rows, cols : ndarray, shape (M,), int
        Candidate pixels (the target's polygon).
    K, dist : intrinsics of the (registered) depth image
    noise : DepthNoiseModel
    min_pixels, min_valid_fraction, max_chi2_ratio, min_inlier_fraction
        Rejection thresholds (see Raises).

    Raises
    ------
    DepthError
        Fewer than ``min_pixels`` valid pixels or less than
        ``min_valid_fraction`` of the polygon valid; fewer than
        ``min_inlier_fraction`` inliers; ``chi2_ratio > max_chi2_ratio``
        (not a plane, or much noisier than the model); a plane through or
        behind the camera.
    """
    m = len(rows)
    z = depth[rows, cols].astype(float) if m else np.empty(0)
    valid = np.isfinite(z) & (z > 0)
    n_valid = int(valid.sum())
    if n_valid < min_pixels or n_valid < min_valid_fraction * max(m, 1):
        raise DepthError(
            f"only {n_valid} of {m} target pixels have depth (need {min_pixels} and "
            f"{min_valid_fraction:.0%})"
        )
    z = z[valid]
    pix = np.column_stack([cols[valid], rows[valid]]).astype(float)
    xy = normalize_points(pix, K, dist)
    A = np.column_stack([xy, np.ones(n_valid)])
    w = 1.0 / z
    sw = noise.sigma(z) / z**2
    keep = np.ones(n_valid, bool)
    for _ in range(3):
        Aw = A[keep] / sw[keep, None]
        abc, *_ = np.linalg.lstsq(Aw, w[keep] / sw[keep], rcond=None)
        r = (w - A @ abc) / sw
        scale = max(1.0, 1.4826 * np.median(np.abs(r[keep])))
        new_keep = np.abs(r) < 3.5 * scale
        if new_keep.sum() < 3 or np.array_equal(new_keep, keep):
            keep = new_keep if new_keep.sum() >= 3 else keep
            break
        keep = new_keep
    n_in = int(keep.sum())
    if n_in < min_inlier_fraction * n_valid or n_in < min_pixels:
        raise DepthError(f"bad plane fit: only {n_in} of {n_valid} depth pixels agree with a plane")
    Aw = A[keep] / sw[keep, None]
    abc, *_ = np.linalg.lstsq(Aw, w[keep] / sw[keep], rcond=None)
    r = (w[keep] - A[keep] @ abc) / sw[keep]
    chi2_ratio = float(r @ r / max(n_in - 3, 1))
    if chi2_ratio > max_chi2_ratio:
        raise DepthError(
            f"bad plane fit: residuals are {np.sqrt(chi2_ratio):.1f}x the depth noise model "
            f"(limit {np.sqrt(max_chi2_ratio):.1f}x)"
        )
    cov = np.linalg.inv(Aw.T @ Aw) * max(1.0, chi2_ratio) * max(1.0, n_in / noise.max_independent_pixels)
    zr = 1.0 / (A[keep] @ abc)
    rms = float(np.sqrt(np.mean((z[keep] - zr) ** 2)))
    return PlaneFit(abc, cov, n_valid, n_in, chi2_ratio, rms)


def intersect_ray(plane: PlaneFit, xy_c, cov_xy: np.ndarray, noise: DepthNoiseModel) -> tuple[np.ndarray, np.ndarray]:
    """Point where the undistorted ray ``(x_c, y_c, 1)`` meets the plane, with covariance.

    Parameters
    ----------
    plane : PlaneFit
    xy_c : array_like, shape (2,)
        Normalized undistorted coordinates of the target center.
    cov_xy : ndarray, shape (2, 2)
        Their covariance (from the corner noise).
    noise : DepthNoiseModel
        Its ``k_sys`` adds the per-frame systematic depth error along the ray.

    Returns
    -------
    p : ndarray, shape (3,), m
    cov : ndarray, shape (3, 3), m^2
        First-order propagation of the plane and center covariances, plus
        ``(k_sys z^2)^2 r r^T``.

    Raises
    ------
    DepthError
        If the ray misses the plane in front of the camera.
    """
    a, b, _ = plane.abc
    r = np.array([xy_c[0], xy_c[1], 1.0])
    inv_z = float(plane.abc @ r)
    if not inv_z > 1e-6:
        raise DepthError("bad plane fit: the center ray does not meet the plane in front of the camera")
    z = 1.0 / inv_z
    p = z * r
    J_abc = -z**2 * np.outer(r, r)
    J_xy = np.column_stack([z * np.array([1.0, 0, 0]) - z**2 * a * r, z * np.array([0, 1.0, 0]) - z**2 * b * r])
    cov = J_abc @ plane.cov @ J_abc.T + J_xy @ cov_xy @ J_xy.T + (noise.k_sys * z**2) ** 2 * np.outer(r, r)
    return p, cov


def refine_pose_with_depth(
    T_pnp: np.ndarray,
    cov_pnp: np.ndarray,
    plane: PlaneFit,
    center_target: np.ndarray,
    p_center: np.ndarray,
    cov_center: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Marker pose with its plane and position from depth and only the in-plane angle from PnP.

    The PnP rotation is turned (minimally) so its z axis lies along the depth
    plane normal (the sign closest to the PnP z axis is kept), then
    translated so that ``center_target`` maps to ``p_center``.

    Parameters
    ----------
    T_pnp : ndarray, shape (4, 4)
    cov_pnp : ndarray, shape (6, 6)
    plane : PlaneFit
    center_target : ndarray, shape (3,)
        The center in the target frame (0 for a marker).
    p_center, cov_center : ndarray, shapes (3,), (3, 3)
        The lifted center and its covariance (`intersect_ray`).

    Returns
    -------
    T : ndarray, shape (4, 4)
    cov : ndarray, shape (6, 6)
        Tilt from the normal covariance, in-plane angle from PnP, translation
        from ``cov_center`` (rotation-translation cross terms neglected).
    """
    z_pnp = T_pnp[:3, 2]
    n = plane.normal if plane.normal @ z_pnp > 0 else -plane.normal
    axis = np.cross(z_pnp, n)
    s, c = np.linalg.norm(axis), float(z_pnp @ n)
    R_align = np.eye(3) if s < 1e-12 else _rotvec_to_matrix(axis / s * np.arctan2(s, c))
    R = R_align @ T_pnp[:3, :3]
    t = p_center - R @ center_target
    S = tf.skew(n)
    cov_rot = S @ plane.normal_cov @ S.T + np.outer(n, n) * float(n @ cov_pnp[:3, :3] @ n)
    cov = np.zeros((6, 6))
    cov[:3, :3] = cov_rot
    # t = p - R c: a rotation error moves t by [R c]_x delta when the center is off the target origin.
    Sc = tf.skew(R @ center_target)
    cov[3:, 3:] = cov_center + Sc @ cov_rot @ Sc.T
    cov[:3, 3:] = cov_rot @ Sc.T
    cov[3:, :3] = cov[:3, 3:].T
    return tf.make_transform(R, t), cov
