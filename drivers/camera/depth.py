"""Depth images: 16-bit millimetres (OpenNI2 streams, recorded sequences, session frames) <-> float32 metres.

`handeye.drivers.camera.base.RGBDFrame.depth` is float32 metres with 0 where the
sensor has no reading; on the wire and on disk depth is a 16-bit
single-channel image with one count per millimetre (OpenNI2's
``PIXEL_FORMAT_DEPTH_1_MM``), 0 likewise meaning no reading, so at most
65.535 m.
"""

from __future__ import annotations

import numpy as np

#: Depth counts per metre in 16-bit depth images.
MM_PER_M = 1000.0


def depth_from_mm(depth_mm) -> np.ndarray:
    """Depth (H, W) float32 in m from a 16-bit image (H, W) in mm; 0 (no reading) stays 0."""
    return np.asarray(depth_mm).astype(np.float32) / MM_PER_M


def depth_to_mm(depth) -> np.ndarray:
    """Depth (H, W) uint16 in mm from depth (H, W) in m: rounded, NaN and negatives -> 0, clipped at 65.535 m."""
    max_mm = np.iinfo(np.uint16).max
    # Clip in metres first so that +inf cannot overflow the scaling.
    depth = np.clip(np.nan_to_num(np.asarray(depth, dtype=float), nan=0.0), 0.0, max_mm / MM_PER_M)
    return np.round(depth * MM_PER_M).astype(np.uint16)
