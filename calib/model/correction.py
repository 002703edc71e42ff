"""The RGB-D camera's systematic error (`CameraCorrection`) and the measurement function ``h(p; theta)``
of the module docstring of `handeye.calib.model`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from handeye.calib import transforms as tf


#: Names of the camera nuisance parameters, in parameter-vector order.
CAMERA_PARAMS = ("depth_scale", "depth_offset", "focal_scale")


@dataclass(frozen=True)
class CameraCorrection:
    """Systematic error of the RGB-D camera: what it measures for a true point.

    ``depth_scale`` s and ``depth_offset`` d (m): measured depth
    ``(1 + s) z + d``, along the pixel ray; ``focal_scale`` f: lateral
    coordinates scaled by ``1 + f`` (the focal length used to back-project is
    ``1 / (1 + f)`` of the true one). All zero = a perfect camera.
    """

    depth_scale: float = 0.0
    depth_offset: float = 0.0
    focal_scale: float = 0.0

    def as_array(self) -> np.ndarray:
        return np.array([self.depth_scale, self.depth_offset, self.focal_scale])

    def measure(self, points) -> np.ndarray:
        """What the camera reports (N, 3) for true camera-frame points (N, 3), m."""
        return measure(points, self.as_array())[0]

    def correct(self, measured) -> np.ndarray:
        """True camera-frame points (N, 3) from measured ones (N, 3): the inverse of `measure`."""
        m = np.asarray(measured, dtype=float)
        s, d, f = self.as_array()
        z = (m[:, 2] - d) / (1.0 + s)
        out = m * (z / m[:, 2])[:, None]
        out[:, :2] /= 1.0 + f
        return out

    def rigid_stand_in(self, measured) -> tuple[np.ndarray, float]:
        """Rigid transform ``G`` (4, 4) of the camera frame closest to `correct` on ``measured`` (N, 3), and its misfit.

        ``G p ~ correct(p)`` in least squares over the points (Kabsch, via
        scipy's ``Rotation.align_vectors``). A camera transform ``T`` that
        pairs with this correction becomes ``T @ G`` for consumers that take
        the camera's points uncorrected and only a rigid transform (a URDF, a
        tf): exact where the correction is rigid, and over the points'
        region otherwise. Returns ``G`` and the RMS misfit (m) of
        ``G p - correct(p)`` over the points.
        """
        m = tf.check_points(measured, "measured")
        target = self.correct(m)
        mc, tc = m.mean(axis=0), target.mean(axis=0)
        m0, t0 = m - mc, target - tc
        R = Rotation.align_vectors(t0, m0)[0].as_matrix() if len(m) >= 3 else np.eye(3)
        misfit = float(np.sqrt(np.mean(np.square(m0 @ R.T - t0)) * 3))
        return tf.make_transform(R, tc - R @ mc), misfit


def measure(p, theta):
    """``h(p; theta)`` (N, 3) and its Jacobians w.r.t. ``p`` (N, 3, 3) and ``theta`` (N, 3, 3).

    See the module docstring: ``h(p) = diag(1 + f, 1 + f, 1) p (1 + s + d / z)``.
    """
    s, d, f = theta
    z = p[:, 2]
    g = 1.0 + s + d / z
    D = np.array([1.0 + f, 1.0 + f, 1.0])
    h = p * g[:, None] * D
    J_p = g[:, None, None] * np.diag(D)[None].repeat(len(p), axis=0)
    J_p[:, :, 2] += -(D * p) * (d / z**2)[:, None]
    J_theta = np.empty((len(p), 3, 3))
    J_theta[:, :, 0] = D * p
    J_theta[:, :, 1] = D * p / z[:, None]
    J_theta[:, :, 2] = p * g[:, None] * np.array([1.0, 1.0, 0.0])
    return h, J_p, J_theta


def measured_points(p, theta) -> np.ndarray:
    """``h(p; theta)`` (N, 3) alone (`measure` without its Jacobians, for cost evaluations)."""
    s, d, f = theta
    return p * ((1.0 + s + d / p[:, 2])[:, None] * np.array([1.0 + f, 1.0 + f, 1.0]))
