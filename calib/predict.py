"""What a calibration predicts the camera sees at a flange pose.

``A = T_base_flange``; eye-to-hand ``X = T_flange_marker``, ``Y = T_base_cam``;
eye-in-hand ``X = T_flange_cam``, ``Y = T_base_marker`` (paper eq. 1).
"""

from __future__ import annotations

import numpy as np

from handeye.calib import transforms as tf
from handeye.calib.result import CalibrationResult
from handeye.calib.setup import Setup


def predicted_point(estimate: CalibrationResult, T_base_flange: np.ndarray) -> np.ndarray:
    """Marker center in the camera frame predicted for a flange pose, shape (3,), m.

    Eye-to-hand: ``Y^-1 A t_X`` (only X's translation is needed, which point-only
    methods recover). Eye-in-hand: ``(A X)^-1 t_Y``.
    """
    if estimate.setup == Setup.EYE_TO_HAND:
        return tf.transform_points(tf.invert(estimate.Y) @ T_base_flange, estimate.X[:3, 3])
    return tf.transform_points(tf.invert(T_base_flange @ estimate.X), estimate.Y[:3, 3])


def predicted_pixel(estimate: CalibrationResult, T_base_flange: np.ndarray, intrinsics,
                    margin_px: int = 0) -> tuple[float, float] | None:
    """Pixel of the marker center predicted for a flange pose, or None if it leaves the image.

    ``intrinsics`` has ``fx, fy, cx, cy, width, height`` (pinhole, distortion
    ignored). "Leaves" means closer than 5 cm or behind the camera, or within
    ``margin_px`` of the border.
    """
    p = predicted_point(estimate, T_base_flange)
    if p[2] <= 0.05:
        return None
    u = intrinsics.fx * p[0] / p[2] + intrinsics.cx
    v = intrinsics.fy * p[1] / p[2] + intrinsics.cy
    if not (margin_px <= u <= intrinsics.width - margin_px and margin_px <= v <= intrinsics.height - margin_px):
        return None
    return float(u), float(v)
