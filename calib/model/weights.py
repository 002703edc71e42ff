"""Noise of the point residual: the camera's covariance shape, the noise levels (variance components),
whitening."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError
from handeye.calib.model.residuals import predict_points
from handeye.calib.noise import default_point_cov


def check_point_cov(point_cov, n: int) -> np.ndarray | None:
    """Validate a point covariance (3, 3) or (N, 3, 3) and broadcast it to (N, 3, 3); None passes."""
    if point_cov is None:
        return None
    # Variances in m^2: the same bound as coordinates keeps their products finite.
    cov = tf.as_real_array(point_cov, "point_cov")
    if cov.shape == (3, 3):
        cov = np.broadcast_to(cov, (n, 3, 3))
    if cov.shape != (n, 3, 3):
        raise CalibrationError(f"point_cov must have shape (3, 3) or ({n}, 3, 3), got {cov.shape}")
    if not np.isfinite(cov).all():
        raise CalibrationError("point_cov contains NaN or inf")
    if np.abs(cov - np.swapaxes(cov, 1, 2)).max() > 1e-9 * max(np.abs(cov).max(), 1e-30):
        raise CalibrationError("point_cov is not symmetric")
    return cov


def whitener(cov) -> np.ndarray:
    """Inverse Cholesky factors ``W`` (N, 3, 3) so that ``W r`` has unit covariance (``W^T W = cov^-1``).

    Written out for 3x3 (cheaper than a batched LAPACK call per sample), on
    the entries as contiguous rows (9, N) (strided columns of (N, 3, 3) are slower).
    """
    a = np.asarray(cov, dtype=float)
    n = len(a)
    a00, _, _, a10, a11, _, a20, a21, a22 = np.ascontiguousarray(a.reshape(n, 9).T)
    with np.errstate(invalid="ignore", divide="ignore"):
        l00 = np.sqrt(a00)
        l10, l20 = a10 / l00, a20 / l00
        l11 = np.sqrt(a11 - l10**2)
        l21 = (a21 - l20 * l10) / l11
        l22 = np.sqrt(a22 - l20**2 - l21**2)
        ok = bool(np.all((l00 > 0) & (l11 > 0) & (l22 > 0) & (l22 < np.inf)))     # NaN fails every comparison
    if not ok:
        raise CalibrationError("point_cov is not positive definite")
    W = np.zeros((9, n))
    W[0], W[4], W[8] = 1.0 / l00, 1.0 / l11, 1.0 / l22
    W[3] = -l10 * W[0] / l11
    W[7] = -l21 * W[4] / l22
    W[6] = -(l20 * W[0] + l21 * W[3]) / l22
    return np.ascontiguousarray(W.T).reshape(n, 3, 3)


def point_shape(B, point_cov) -> tuple[np.ndarray, bool]:
    """Camera point covariance shape ``S_i`` (N, 3, 3) and whether ``point_cov`` was given."""
    p = B if B.ndim == 2 else B[:, :3, 3]
    cov = check_point_cov(point_cov, len(p))
    if cov is None:
        return default_point_cov(p), False
    return np.array(cov), True


def point_weights(B, point_cov) -> tuple[np.ndarray, bool]:
    """Whitening matrices (N, 3, 3) of the point residual and whether ``point_cov`` was given."""
    cov, given = point_shape(B, point_cov)
    return whitener(cov), given


@dataclass(frozen=True)
class NoiseLevels:
    """Variance components of the model (module docstring).

    Attributes
    ----------
    point_scale : float
        ``s_p``: factor on the camera point covariance shape (1 = as given / as the depth model says).
    robot : float
        ``sigma_R``: flange translation error, m (rotation ``ROBOT_ROTATION_PER_M`` times it, rad).
    rotation : float or None
        ``sigma_rot``: marker orientation noise, rad (pose data).
    """

    point_scale: float = 1.0
    robot: float = 0.0
    rotation: float | None = None

    def point_cov(self, shape, robot_cof) -> np.ndarray:
        """``Sigma_i`` (N, 3, 3) = ``s_p S_i + sigma_R^2 T_i``."""
        return self.point_scale * shape + self.robot**2 * robot_cof


#: Floors of the variance components: they keep the weights finite when a component vanishes.
MIN_POINT_SCALE = 1e-4


MIN_ROBOT_SIGMA = 1e-6


MIN_ROTATION_SIGMA = 1e-6


def point_d2(C, K, M, p, W_shape) -> np.ndarray:
    """Squared point residuals (N,) at ``(C, K)`` (no camera error) whitened by the camera's shape ``W_shape``."""
    return whitened_squares(W_shape, p - predict_points(C, K[:3, 3], M))


def whitened_squares(W, r) -> np.ndarray:
    """``|W_i r_i|^2`` (N,) for whitening matrices (N, 3, 3) and residuals (N, 3)."""
    wr = np.einsum("nij,nj->ni", W, r)
    return np.sum(wr * wr, axis=1)
