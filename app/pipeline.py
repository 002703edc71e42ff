"""Glue between the app and the calib library: measurement, solving, prediction.

Eye-to-hand: ``X = T_flange_marker``, ``Y = T_base_cam``. Eye-in-hand:
``X = T_flange_cam``, ``Y = T_base_marker``. ``A = T_base_flange``,
``B = T_cam_marker`` (paper eq. 1, ``A_i X = Y B_i``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib import transforms as tf
from calib.result import CalibrationResult
from calib.setup import Setup


@dataclass
class Measurement:
    """What the extraction step got from one frame (camera frame, metres).

    Attributes
    ----------
    point_cam : ndarray (3,)
        Marker center.
    point_cov : ndarray (3, 3) or None
    T_cam_marker : ndarray (4, 4) or None
    pose_cov : ndarray (6, 6) or None
    pixel : tuple(float, float) or None
        Marker center in the image (for display).
    meta : dict
        JSON-serialisable extras (marker id, corner count, ...).
    """

    point_cam: np.ndarray
    point_cov: np.ndarray | None = None
    T_cam_marker: np.ndarray | None = None
    pose_cov: np.ndarray | None = None
    pixel: tuple[float, float] | None = None
    meta: dict = field(default_factory=dict)


def sigma(cov: np.ndarray) -> tuple[float, float]:
    """Worst-axis 1-sigma of a 6x6 ``[rotvec, t]`` covariance (calib.result convention).

    Returns
    -------
    (deg, mm) : tuple of float
    """
    cov = np.asarray(cov, dtype=float)
    if cov.shape != (6, 6):
        raise ValueError(f"cov must have shape (6, 6), got {cov.shape}")
    s_rot = float(np.sqrt(max(np.linalg.eigvalsh(cov[:3, :3]).max(), 0.0)))
    s_t = float(np.sqrt(max(np.linalg.eigvalsh(cov[3:, 3:]).max(), 0.0)))
    return float(np.rad2deg(s_rot)), s_t * 1e3


def predicted_point(setup: Setup, estimate: CalibrationResult, T_base_flange: np.ndarray) -> np.ndarray:
    """Marker center in the camera frame predicted for a flange pose, shape (3,).

    Eye-to-hand: ``Y^-1 A t_X`` (only X's translation is needed, which point-only
    methods recover). Eye-in-hand: ``(A X)^-1 t_Y``.
    """
    if setup == Setup.EYE_TO_HAND:
        return tf.transform_points(tf.invert(estimate.Y) @ T_base_flange, estimate.X[:3, 3])
    return tf.transform_points(tf.invert(T_base_flange @ estimate.X), estimate.Y[:3, 3])


def predicted_pixel(setup: Setup, estimate: CalibrationResult, T_base_flange: np.ndarray,
                    intrinsics, margin_px: int = 0) -> tuple[float, float] | None:
    """Pixel of the marker center predicted for a flange pose, or None if it leaves the image.

    "Leaves" means behind the camera or within ``margin_px`` of the border.
    """
    p = predicted_point(setup, estimate, T_base_flange)
    if p[2] <= 0.05:
        return None
    u = intrinsics.fx * p[0] / p[2] + intrinsics.cx
    v = intrinsics.fy * p[1] / p[2] + intrinsics.cy
    if not (margin_px <= u <= intrinsics.width - margin_px and margin_px <= v <= intrinsics.height - margin_px):
        return None
    return float(u), float(v)



def solve_observations(method: str, observations, setup: Setup, *, refine: bool = False,
                       robust: bool = False, rng: np.random.Generator | None = None) -> CalibrationResult:
    """Solve ``A_i X = Y B_i`` (paper eq. 1) for a list of samples with a named solver.

    Point methods (YKronT') get the depth-lifted marker centers ``point_cam``
    with their covariances; the others the marker poses ``T_cam_marker``
    (``calib.api.METHODS[...].needs``). Samples lacking that measurement are
    left out.
    """
    from calib.api import observations_to_arrays, resolve_method, solve

    info = resolve_method(method)
    A, B, point_cov, _ = observations_to_arrays(observations, info.needs)
    return solve(info.name, A, B, setup=setup, refine=refine, robust=robust, point_cov=point_cov, rng=rng)
