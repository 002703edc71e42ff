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

from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from handeye.calib.errors import ParameterError
from handeye.calib.params import Float, PinholeParams, PositiveInt, describe
from handeye.drivers.camera.base import CameraIntrinsics

#: Lengths of the OpenCV distortion vectors (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1..s4 [tx ty]]]]).
DIST_LENGTHS = (4, 5, 8, 12, 14)


def _dist_length(dist: tuple[float, ...]) -> tuple[float, ...]:
    if len(dist) not in DIST_LENGTHS:
        raise ValueError(f"must be 4, 5, 8, 12 or 14 OpenCV coefficients, got {len(dist)}")
    return dist


class IntrinsicsParams(PinholeParams):
    """This module's YAML keys (pixels): a usable pinhole model."""

    dist: tuple[Float, ...] = (0.0,) * 5

    _dist = field_validator("dist")(_dist_length)

    def intrinsics(self) -> CameraIntrinsics:
        return CameraIntrinsics(self.width, self.height, self.fx, self.fy, self.cx, self.cy, self.dist)


class _RosMatrix(BaseModel):
    # rows / cols are implied by the field; only the data are read.
    model_config = ConfigDict(extra="ignore")
    data: list[Float]


class RosCameraInfo(BaseModel):
    """A ROS ``camera_info`` YAML; its other keys (distortion model, R, P, name) are not used here."""

    model_config = ConfigDict(extra="ignore")
    image_width: PositiveInt
    image_height: PositiveInt
    camera_matrix: _RosMatrix
    distortion_coefficients: _RosMatrix = Field(default_factory=lambda: _RosMatrix(data=[0.0] * 5))

    @field_validator("camera_matrix")
    @classmethod
    def _three_by_three(cls, m: _RosMatrix) -> _RosMatrix:
        if len(m.data) != 9:
            raise ValueError(f"data must hold the 9 entries of K, got {len(m.data)}")
        return m

    def as_keys(self) -> dict:
        """This module's keys, to be validated as `IntrinsicsParams`."""
        k = self.camera_matrix.data
        return {"width": self.image_width, "height": self.image_height, "fx": k[0], "fy": k[4], "cx": k[2],
                "cy": k[5], "dist": tuple(self.distortion_coefficients.data)}


def check_intrinsics(intr: CameraIntrinsics, name: str = "intrinsics") -> CameraIntrinsics:
    """``intr`` if it is a usable pinhole model, else `ParameterError` naming the field."""
    intrinsics_from_dict({f: getattr(intr, f) for f in IntrinsicsParams.model_fields}, name)
    return intr


def intrinsics_from_dict(d: dict, name: str = "intrinsics") -> CameraIntrinsics:
    """`CameraIntrinsics` from this module's YAML keys or a ROS camera_info dict."""
    try:
        if "camera_matrix" in d:
            d = RosCameraInfo.model_validate(d).as_keys()
        return IntrinsicsParams.model_validate(d).intrinsics()
    except ValidationError as e:
        raise ParameterError(describe(e, name)) from None


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
