"""Marker detection and 3D lifting from RGB-D frames (image processing only, no device I/O).

The per-frame entry is `extract(color, depth, intrinsics, target) -> MarkerMeasurement`
(`try_extract` returns ``(None, reason)`` for a bad frame instead of raising).
"""

from handeye.calib.vision.extract import MarkerMeasurement, TargetConfig, extract, try_extract
from handeye.calib.vision.lift import DepthNoiseModel
from handeye.calib.vision.markers import BoardSpec, Detection, detect_charuco, detect_chessboard, detect_markers

__all__ = [
    "BoardSpec",
    "DepthNoiseModel",
    "Detection",
    "MarkerMeasurement",
    "TargetConfig",
    "detect_charuco",
    "detect_chessboard",
    "detect_markers",
    "extract",
    "try_extract",
]
