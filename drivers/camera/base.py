"""Abstract RGB-D camera: color + registered depth + intrinsics + timestamp."""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from handeye.drivers.device import Device


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics of the color image (depth is registered to it).

    ``dist`` holds OpenCV distortion coefficients ``(k1, k2, p1, p2, k3)``.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class RGBDFrame:
    """One synchronised color + depth frame.

    Attributes
    ----------
    color : ndarray, shape (H, W, 3), uint8, BGR (OpenCV order)
    depth : ndarray, shape (H, W), float32, metres along the optical axis;
        0 where the sensor has no reading. Registered to ``color``.
    t : float
        Host time of the exposure, seconds (``time.time()`` clock).
    intrinsics : CameraIntrinsics
    index : int
        Frame counter from the source.
    truth : dict
        Ground truth from simulated sources (e.g. ``T_cam_marker``); empty
        for real cameras.
    meta : dict
        Source details worth logging (device timestamps, file names).
    """

    color: np.ndarray
    depth: np.ndarray
    t: float
    intrinsics: CameraIntrinsics
    index: int = 0
    truth: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)


class Camera(Device):
    """An RGB-D source. Use as a context manager: ``with CAMERAS.create(cfg) as cam: ...``."""

    def follow(self, flange_pose_source: Callable[[], np.ndarray]) -> None:
        """Give the camera the robot's current ``T_base_flange`` (a callable).

        Real cameras ignore it; a simulated one renders what it would see there.
        """

    def truth(self) -> dict | None:
        """The true ``X``/``Y`` transforms by frame name (e.g. ``T_base_cam``, ``T_flange_marker``)
        of a simulated camera; None for a real one."""
        return None

    @property
    @abc.abstractmethod
    def intrinsics(self) -> CameraIntrinsics: ...

    @abc.abstractmethod
    def read(self) -> RGBDFrame:
        """Next frame; raises ConnectionLostError when the source stops delivering."""
