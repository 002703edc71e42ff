"""Depth-dependent noise model of a marker center measured by a structured-light RGB-D camera.

Used when the caller gives no ``point_cov``. The shape follows the
Kinect v1 / Xtion (PrimeSense) error studies:

- lateral (across the viewing ray): ``sigma_lat = z * SIGMA_PX / FOCAL_PX``,
  a fraction of a pixel back-projected at depth ``z``
  (Nguyen, Izadi, Lovell, "Modeling Kinect sensor noise for improved 3D
  reconstruction and tracking", 3DIMPVT 2012: about 0.8 px);
- along the ray: ``sigma_depth = DEPTH_K * z**2``, the quadratic growth of
  triangulation error with range (Khoshelham & Oude Elberink, "Accuracy and
  resolution of Kinect depth data", Sensors 12(2), 2012). Their per-pixel
  random error is about 1.6e-3 /m (4 cm at 5 m); a marker center, though,
  inherits the low-frequency depth distortion ("wiggling", several mm at
  1 m in the same study) that averaging over the marker does not remove, so
  we use 6e-3 /m: 3 mm at 0.7 m, the along-ray figure of
  `handeye.calib.simulate.realistic_cell` (1 mm lateral at 0.7 m matches the lateral
  term).

The absolute level of a real camera's noise varies, so `handeye.calib.refine` treats
the model as the *shape* of the covariance and, when no covariance is given,
estimates its overall scale from the residuals (a posteriori variance factor).
"""

from __future__ import annotations

import numpy as np

from handeye.calib.errors import CalibrationError
from handeye.calib.transforms import check_points

#: Lateral noise of one pixel measurement, px (Nguyen et al. 2012).
SIGMA_PX = 0.8
#: Focal length of a VGA Xtion / Kinect v1 depth camera, px.
FOCAL_PX = 570.0
#: Quadratic depth-noise coefficient of a marker center, 1/m (see module docstring).
DEPTH_K = 6.0e-3

#: Row, column and identity of the entries of a 3x3 matrix in row-major order.
_ROW, _COL = np.divmod(np.arange(9), 3)
_EYE_ROW = np.eye(3).reshape(9)


def ray_covariance(points, sigma_lateral, sigma_depth) -> np.ndarray:
    """Covariances of points seen from the camera origin, aligned with the viewing ray.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        Points in the camera frame, m.
    sigma_lateral, sigma_depth : float or array_like, shape (N,)
        Standard deviations across and along the ray, m.

    Returns
    -------
    cov : ndarray, shape (N, 3, 3)
        ``sigma_depth^2 r r^T + sigma_lateral^2 (I - r r^T)`` with ``r`` the unit ray.
    """
    return _ray_covariance(check_points(points, "points"), sigma_lateral, sigma_depth)


def _ray_covariance(p, sigma_lateral, sigma_depth) -> np.ndarray:
    """`ray_covariance` of points (N, 3) already checked."""
    norm = np.linalg.norm(p, axis=1, keepdims=True)
    if not (norm > 0).all():
        raise CalibrationError(f"points[{int(np.argmin(norm[:, 0]))}] is the camera origin: its viewing ray is undefined")
    r = p / norm
    # Entries as rows (N, 9), cheaper than broadcasting over (N, 3, 3): every solve("auto") without
    # point_cov comes here.
    outer = r[:, _ROW] * r[:, _COL]
    sl = np.broadcast_to(np.asarray(sigma_lateral, dtype=float), (len(p),))[:, None]
    sd = np.broadcast_to(np.asarray(sigma_depth, dtype=float), (len(p),))[:, None]
    return (sd**2 * outer + sl**2 * (_EYE_ROW - outer)).reshape(-1, 3, 3)


def default_point_cov(points) -> np.ndarray:
    """The default depth-dependent covariance (N, 3, 3) of marker centers ``points`` (N, 3), m^2.

    ``z`` is the depth (camera z coordinate); points at or behind the camera
    get the covariance of a point at 0.1 m so the model stays positive definite.
    """
    p = check_points(points, "points")
    z = np.maximum(p[:, 2], 0.1)
    return _ray_covariance(p, z * SIGMA_PX / FOCAL_PX, DEPTH_K * z**2)


def anchored_point_cov(point, cov):
    """``point_cov(points (N, 3)) -> (N, 3, 3)``: the default model's growth with depth, at the levels of one
    measured covariance.

    The lateral and along-ray standard deviations of ``cov`` (3, 3) at ``point``
    (3,) (depth ``z0``) are scaled like the default model: lateral by ``z / z0``,
    along the ray by ``(z / z0)^2``. Predicts what a particular camera will
    measure elsewhere from what it measured once (e.g. at the start pose of a
    plan), where the default model would assume a structured-light camera's level.
    """
    p0 = check_points(np.asarray(point, dtype=float)[None], "point")[0]
    S = np.asarray(cov, dtype=float)
    if S.shape != (3, 3) or not np.isfinite(S).all() or p0[2] <= 0:
        raise CalibrationError(f"need a point in front of the camera and its (3, 3) covariance, got {point!r}, {S.shape}")
    r = p0 / np.linalg.norm(p0)
    var_depth = float(r @ S @ r)
    var_lat = 0.5 * (float(np.trace(S)) - var_depth)
    if not (var_depth > 0 and var_lat > 0):
        raise CalibrationError("the measured covariance must be positive definite")
    z0 = float(p0[2])

    def point_cov(points) -> np.ndarray:
        p = check_points(points, "points")
        z = np.maximum(p[:, 2], 0.1) / z0
        return ray_covariance(p, np.sqrt(var_lat) * z, np.sqrt(var_depth) * z**2)

    return point_cov
