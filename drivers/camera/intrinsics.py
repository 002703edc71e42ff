"""Read and write `CameraIntrinsics` as a small YAML file.

Format (keys in pixels, ``dist`` = OpenCV ``k1 k2 p1 p2 k3``)::

    width: 640
    height: 480
    fx: 570.3
    fy: 570.3
    cx: 319.5
    cy: 239.5
    dist: [0.0, 0.0, 0.0, 0.0, 0.0]

A ROS ``camera_info`` YAML (``image_width``, ``camera_matrix``,
``distortion_coefficients``) is read too, so an existing
``camera_calibration`` result can be used unchanged.
"""

from __future__ import annotations

import math
from pathlib import Path

import yaml

from calib.errors import ParameterError
from drivers.camera.base import CameraIntrinsics


def check_intrinsics(intr: CameraIntrinsics, name: str = "intrinsics") -> CameraIntrinsics:
    """Raise ParameterError naming the field if ``intr`` is not a usable pinhole model."""
    for f in ("width", "height"):
        v = getattr(intr, f)
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise ParameterError(f"{name}.{f} must be a positive integer, got {v!r}")
    for f in ("fx", "fy", "cx", "cy"):
        v = getattr(intr, f)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ParameterError(f"{name}.{f} must be a finite number, got {v!r}")
    if intr.fx <= 0 or intr.fy <= 0:
        raise ParameterError(f"{name}.fx and {name}.fy must be > 0, got {intr.fx}, {intr.fy}")
    if len(intr.dist) not in (4, 5, 8, 12, 14) or not all(math.isfinite(float(d)) for d in intr.dist):
        raise ParameterError(f"{name}.dist must be 4, 5, 8, 12 or 14 finite OpenCV coefficients, got {intr.dist!r}")
    return intr


def intrinsics_from_dict(d: dict, name: str = "intrinsics") -> CameraIntrinsics:
    """`CameraIntrinsics` from this module's YAML keys or a ROS camera_info dict."""
    try:
        if "camera_matrix" in d:
            k = d["camera_matrix"]["data"]
            intr = CameraIntrinsics(
                int(d["image_width"]), int(d["image_height"]), float(k[0]), float(k[4]), float(k[2]), float(k[5]),
                tuple(float(x) for x in d.get("distortion_coefficients", {}).get("data", [0.0] * 5)),
            )
        else:
            intr = CameraIntrinsics(
                int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"]),
                tuple(float(x) for x in d.get("dist", (0.0,) * 5)),
            )
    except KeyError as e:
        raise ParameterError(f"{name}: missing key {e.args[0]!r}") from None
    except (TypeError, ValueError, IndexError) as e:
        raise ParameterError(f"{name}: {e}") from None
    return check_intrinsics(intr, name)


def load_intrinsics(path) -> CameraIntrinsics:
    """Read an intrinsics YAML file (see module docstring)."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise ParameterError(f"cannot read intrinsics file {path}: {e}") from None
    if not isinstance(data, dict):
        raise ParameterError(f"intrinsics file {path} must hold a mapping")
    return intrinsics_from_dict(data, str(path))


def save_intrinsics(path, intr: CameraIntrinsics) -> None:
    """Write ``intr`` in this module's YAML format."""
    check_intrinsics(intr)
    data = {"width": intr.width, "height": intr.height, "fx": float(intr.fx), "fy": float(intr.fy),
            "cx": float(intr.cx), "cy": float(intr.cy), "dist": [float(x) for x in intr.dist]}
    Path(path).write_text(yaml.safe_dump(data, sort_keys=False))
