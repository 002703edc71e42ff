"""Build a `Camera` from its config: the one place that knows every camera backend.

``backend`` selects the implementation: ``"openni2"`` (real Xtion/PrimeSense,
`drivers.camera.openni2`), ``"rendered"`` (simulated frames with truth,
`mocks.render`) or ``"recorded"`` (a recorded directory, `mocks.recorded`).
Backend modules, and through them vendor SDKs, are imported only in their
branch, so a machine without ``openni`` can still run the simulator.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from calib.errors import ParameterError
from drivers.camera.base import Camera

BACKENDS = ("openni2", "rendered", "recorded")


def _config_class(backend: str):
    if backend == "openni2":
        from drivers.camera.openni2 import OpenNI2CameraConfig

        return OpenNI2CameraConfig
    if backend == "rendered":
        from mocks.render.camera import RenderedCameraConfig

        return RenderedCameraConfig
    if backend == "recorded":
        from mocks.recorded import RecordedCameraConfig

        return RecordedCameraConfig
    raise ParameterError(f"camera.backend must be one of {list(BACKENDS)}, got {backend!r}")


def camera_config_from_dict(data: dict):
    """Validate a ``[camera]`` TOML table into its backend's config dataclass.

    Raises
    ------
    ParameterError
        Unknown backend, unknown key (named) or a bad field (named).
    """
    if not isinstance(data, dict):
        raise ParameterError(f"[camera] must be a table, got {data!r}")
    cls = _config_class(data.get("backend"))
    known = {f.name for f in dataclasses.fields(cls)}
    for key in data:
        if key not in known:
            raise ParameterError(
                f"unknown key camera.{key} for backend {data['backend']!r} (known: {', '.join(sorted(known))})"
            )
    return cls(**data)


def make_camera(config, flange_pose_source: Callable[[], np.ndarray] | None = None) -> Camera:
    """Create (not connect) the camera a config describes.

    Parameters
    ----------
    config : dict or a backend config dataclass
        A ``[camera]`` table (with ``backend``) or an already built config.
    flange_pose_source : callable () -> ndarray (4, 4), optional
        Current ``T_base_flange``; required by the rendered camera only.
    """
    if isinstance(config, dict):
        config = camera_config_from_dict(config)
    backend = getattr(config, "backend", None)
    _config_class(backend)  # rejects unknown backends before any import of their modules
    if backend == "openni2":
        from drivers.camera.openni2 import OpenNI2Camera

        return OpenNI2Camera(config)
    if backend == "rendered":
        from mocks.render.camera import RenderedCamera

        if flange_pose_source is None:
            raise ParameterError("camera.backend 'rendered' needs a flange_pose_source (the robot's T_base_flange)")
        return RenderedCamera(config, flange_pose_source)
    from mocks.recorded import RecordedCamera

    return RecordedCamera(config)
