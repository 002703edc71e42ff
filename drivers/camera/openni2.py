"""OpenNI2 RGB-D camera (Asus Xtion, PrimeSense Carmine and other PS1080 devices).

Needs the ``openni`` Python bindings (``pip install 'handeye[openni]'``) and the
system OpenNI2 library (Debian/Ubuntu: ``apt-get install libopenni2-0``). The
depth stream is registered to the color stream in hardware and the two are
paired by device timestamp; intrinsics come from a calibration file or, failing
that, from the field of view the device reports.

OpenNI2 ships a dummy device (URI ``"Dummy"``, 320x240 depth + RGB, no
registration, no field of view) that the tests use when the library is
installed.
"""

from __future__ import annotations

import ctypes.util
import logging
import math
import os
import tempfile
import time
from typing import Literal
from pathlib import Path

import numpy as np
from pydantic import field_validator

from handeye.calib.errors import ParameterError
from handeye.calib.params import Bool, Params, PositiveFloat, PositiveInt, Str
from handeye.drivers.errors import ConnectionLostError, DeviceError
from handeye.drivers.camera.base import Camera, CameraIntrinsics, RGBDFrame
from handeye.drivers.camera.depth import depth_from_mm
from handeye.drivers.camera.registry import CAMERAS
from handeye.drivers.camera.intrinsics import load_intrinsics

log = logging.getLogger(__name__)

INSTALL_HINT = (
    "install the Python bindings with pip install 'handeye[openni]' and the OpenNI2 "
    "library with apt-get install libopenni2-0"
)
_LIB = "libOpenNI2.so"


class OpenNI2CameraConfig(Params):
    """``[camera]`` table for ``backend = "openni2"``.

    Attributes
    ----------
    uri : str
        Device URI; ``""`` opens the first device, ``"Dummy"`` OpenNI2's dummy device.
    width, height, fps : int
        Video mode of both streams (depth 1 mm units, color RGB888).
    registration : bool
        Register depth to color in the device (required for marker lifting;
        set False only when the streams are aligned already, e.g. the dummy device).
    sync : bool
        Ask the device to synchronise depth and color frames.
    max_skew_ms : float
        Largest accepted device-timestamp difference between the paired frames.
    intrinsics_file : str
        YAML with the color intrinsics (`handeye.drivers.camera.intrinsics`); ``""``
        derives a distortion-free pinhole from the device's field of view.
    library_dir : str
        Directory of ``libOpenNI2.so`` (or ``.so.0``) with its ``OpenNI2/Drivers``;
        ``""`` searches ``$OPENNI2_REDIST64``, ``$OPENNI2_REDIST`` and the system library path.
    timeout_s : float
        A frame not delivered within this time means the connection is lost.
    """

    backend: Literal["openni2"] = "openni2"
    uri: Str = ""
    width: PositiveInt = 640
    height: PositiveInt = 480
    fps: PositiveInt = 30
    registration: Bool = True
    sync: Bool = True
    max_skew_ms: PositiveFloat = 20.0
    intrinsics_file: Str = ""
    library_dir: Str = ""
    timeout_s: PositiveFloat = 2.0

    @field_validator("intrinsics_file")
    @classmethod
    def _exists(cls, path: str) -> str:
        if path and not Path(path).is_file():
            raise ValueError(f"{path!r} does not exist")
        return path


def library_dirs(config: OpenNI2CameraConfig) -> list[Path]:
    """Where to look for the OpenNI2 library: ``library_dir``, else the OpenNI2 SDK's variables and the
    system library directories."""
    if config.library_dir:
        return [Path(config.library_dir)]
    dirs = [Path(os.environ[k]) for k in ("OPENNI2_REDIST64", "OPENNI2_REDIST") if k in os.environ]
    found = ctypes.util.find_library("OpenNI2")
    for base in ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib", "/usr/local/lib"):
        if found is None or (Path(base) / found).exists():
            dirs.append(Path(base))
    return dirs


def loadable_dir(d: Path) -> str | None:
    """A directory the bindings can load from: they want ``libOpenNI2.so`` next to ``OpenNI2/Drivers``.

    Debian's libopenni2-0 installs only ``libOpenNI2.so.0`` (the unversioned
    name comes with -dev), so we point a private directory of symlinks at it.
    """
    if (d / _LIB).is_file():
        return str(d)
    if (d / f"{_LIB}.0").is_file() and (d / "OpenNI2" / "Drivers").is_dir():
        shim = Path(tempfile.mkdtemp(prefix="handeye-openni2-"))
        (shim / _LIB).symlink_to(d / f"{_LIB}.0")
        (shim / "OpenNI2").symlink_to(d / "OpenNI2")
        return str(shim)
    return None


#: What to check when no OpenNI2 device answers.
PLUG_HINT = ("plug the camera (Xtion, Astra) into a USB port, check that lsusb lists it and that this user may open "
             "it (the OpenNI2 package's udev rules, then replug)")


def open_device(openni2, uri: str):
    """The OpenNI2 device at ``uri`` (the first one attached when empty); `DeviceError` in one line naming what
    was tried, what is attached and what to do, instead of the bindings' ``(OniStatus..., b'...', None)``."""
    attached = [u.decode(errors="replace") if isinstance(u, bytes) else str(u) for u in openni2.Device.enumerate_uris()]
    if not attached and not uri:    # (a uri may name what is never listed: the dummy device, a recording)
        raise DeviceError(f"OpenNI2 camera: no device found (tried the first one attached); {PLUG_HINT}")
    try:
        return openni2.Device.open_any() if not uri else openni2.Device(uri.encode())
    except Exception as e:  # the bindings' OpenNIError: (status, message bytes, log file)
        why = e.args[1] if len(e.args) > 1 else e
        why = why.decode(errors="replace") if isinstance(why, bytes) else str(why)
        tried = f"camera.uri {uri}" if uri else f"the first one attached, {attached[0]}"
        fix = (f"attached: {', '.join(attached)}; set camera.uri to one of them, or close the program that holds it"
               if attached else PLUG_HINT)
        raise DeviceError(f"OpenNI2 camera: cannot open {tried} ({why}); {fix}") from None


@CAMERAS.register("openni2", OpenNI2CameraConfig)
class OpenNI2Camera(Camera):
    """Registered, synchronised depth + color from an OpenNI2 device."""

    def __init__(self, config: OpenNI2CameraConfig):
        self.config = config
        self._openni2 = None
        self._device = None
        self._depth = None
        self._color = None
        self._intr: CameraIntrinsics | None = None
        self._index = 0

    def connect(self) -> None:
        try:
            from openni import openni2
        except ImportError as e:
            raise DeviceError(f"OpenNI2 camera: cannot import openni ({e}); {INSTALL_HINT}") from None
        c = self.config
        if not openni2.is_initialized():
            dirs = [x for x in (loadable_dir(d) for d in library_dirs(c)) if x]
            if not dirs:
                raise DeviceError(f"OpenNI2 camera: {_LIB} not found (camera.library_dir); {INSTALL_HINT}")
            try:
                openni2.initialize(dirs)
            except Exception as e:  # the bindings raise their own InitializationError
                raise DeviceError(f"OpenNI2 camera: cannot load OpenNI2 ({e}); {INSTALL_HINT}") from None
        self._openni2 = openni2
        self._device = open_device(openni2, c.uri)
        try:
            self._setup_streams()
        except Exception:
            self.disconnect()
            raise
        self._index = 0

    def _video_mode(self, stream, pixel_format):
        modes = list(stream.get_sensor_info().videoModes)
        c = self.config
        for m in modes:
            if (m.resolutionX, m.resolutionY, m.fps, m.pixelFormat) == (c.width, c.height, c.fps, pixel_format):
                return m
        have = ", ".join(f"{m.resolutionX}x{m.resolutionY}@{m.fps}" for m in modes if m.pixelFormat == pixel_format)
        raise DeviceError(f"OpenNI2 camera: no {c.width}x{c.height}@{c.fps} mode (camera.width/height/fps); has {have}")

    def _setup_streams(self) -> None:
        ni, dev, c = self._openni2, self._device, self.config
        if c.registration:
            if not dev.is_image_registration_mode_supported(ni.IMAGE_REGISTRATION_DEPTH_TO_COLOR):
                raise DeviceError(
                    "OpenNI2 camera: the device cannot register depth to color; set camera.registration = false "
                    "only if its streams are aligned already"
                )
            dev.set_image_registration_mode(ni.IMAGE_REGISTRATION_DEPTH_TO_COLOR)
        if c.sync:
            try:
                dev.set_depth_color_sync_enabled(True)
            except Exception as e:
                log.warning("OpenNI2 camera: frame sync not available (%s); pairing by timestamp only", e)
        self._depth = dev.create_depth_stream()
        self._color = dev.create_color_stream()
        for stream, fmt in ((self._depth, ni.PIXEL_FORMAT_DEPTH_1_MM), (self._color, ni.PIXEL_FORMAT_RGB888)):
            mode = self._video_mode(stream, fmt)
            cur = stream.get_video_mode()
            # Some drivers (e.g. the dummy device) cannot set a mode; fine if it is the one we want already.
            if (cur.resolutionX, cur.resolutionY, cur.fps, cur.pixelFormat) != (
                mode.resolutionX, mode.resolutionY, mode.fps, mode.pixelFormat
            ):
                try:
                    stream.set_video_mode(mode)
                except Exception as e:
                    raise DeviceError(f"OpenNI2 camera: cannot set video mode {mode}: {e}") from None
        self._intr = self._load_intrinsics()
        self._depth.start()
        self._color.start()

    def _load_intrinsics(self) -> CameraIntrinsics:
        c = self.config
        if c.intrinsics_file:
            intr = load_intrinsics(c.intrinsics_file)
            if (intr.width, intr.height) != (c.width, c.height):
                raise ParameterError(
                    f"camera.intrinsics_file is for {intr.width}x{intr.height}, the stream is {c.width}x{c.height}"
                )
            return intr
        try:
            hfov = self._color.get_horizontal_fov()
            vfov = self._color.get_vertical_fov()
        except Exception as e:
            raise DeviceError(
                f"OpenNI2 camera: the device reports no field of view ({e}); give camera.intrinsics_file"
            ) from None
        fx = c.width / (2.0 * math.tan(hfov / 2.0))
        fy = c.height / (2.0 * math.tan(vfov / 2.0))
        log.info("OpenNI2 camera: intrinsics from the device's field of view (no distortion): fx=%.1f fy=%.1f", fx, fy)
        return CameraIntrinsics(c.width, c.height, fx, fy, (c.width - 1) / 2.0, (c.height - 1) / 2.0)

    def identity(self) -> dict:
        """Vendor, name and URI of the opened device, as OpenNI2 reports them."""
        if self._device is None:
            return {}
        try:
            info = self._device.get_device_info()
        except Exception as e:  # the bindings raise their own OpenNIError
            log.info("OpenNI2 camera: no device info (%s)", e)
            return {}
        text = {k: (v.decode(errors="replace") if isinstance(v, bytes) else str(v)).strip()
                for k, v in (("vendor", info.vendor), ("name", info.name), ("uri", info.uri))}
        return {"model": f"{text['vendor']} {text['name']}".strip(), "uri": text["uri"]}

    def disconnect(self) -> None:
        for s in (self._depth, self._color):
            if s is not None:
                try:
                    s.stop()
                    s.close()
                except Exception as e:  # a dead device must not prevent cleanup
                    log.warning("OpenNI2 camera: closing a stream failed: %s", e)
        if self._device is not None:
            try:
                self._device.close()
            except Exception as e:
                log.warning("OpenNI2 camera: closing the device failed: %s", e)
        self._depth = self._color = self._device = None

    @property
    def is_connected(self) -> bool:
        return self._device is not None

    @property
    def intrinsics(self) -> CameraIntrinsics:
        if self._intr is None:
            raise DeviceError("OpenNI2 camera is not connected")
        return self._intr

    def _next(self, stream):
        ready = self._openni2.wait_for_any_stream([stream], self.config.timeout_s)
        if ready is None:
            raise ConnectionLostError(f"OpenNI2 camera: no frame within {self.config.timeout_s} s")
        return stream.read_frame()

    def read(self) -> RGBDFrame:
        """Next depth + color pair whose device timestamps differ by at most ``max_skew_ms``.

        ``RGBDFrame.t`` is the host time at which the pair was received (the
        exposure is a roughly constant latency earlier, left to the time-offset
        estimation); the device timestamps (us) are in ``meta``.
        """
        if self._device is None:
            raise DeviceError("OpenNI2 camera is not connected")
        c = self.config
        try:
            d = self._next(self._depth)
            g = self._next(self._color)
            deadline = time.monotonic() + c.timeout_s
            # Advance whichever stream lags until the pair is within max_skew.
            while abs(d.timestamp - g.timestamp) > c.max_skew_ms * 1e3:
                if time.monotonic() > deadline:
                    raise ConnectionLostError(
                        f"OpenNI2 camera: depth and color stay {abs(d.timestamp - g.timestamp) / 1e3:.1f} ms apart"
                    )
                if d.timestamp < g.timestamp:
                    d = self._next(self._depth)
                else:
                    g = self._next(self._color)
            t = time.time()
            depth_mm = np.frombuffer(d.get_buffer_as_uint16(), np.uint16).reshape(d.height, d.width)
            rgb = np.frombuffer(g.get_buffer_as_uint8(), np.uint8).reshape(g.height, g.width, 3)
        except ConnectionLostError:
            raise
        except Exception as e:  # the bindings raise OpenNIError on a dropped device
            raise ConnectionLostError(f"OpenNI2 camera: {e}") from None
        frame = RGBDFrame(
            color=np.ascontiguousarray(rgb[..., ::-1]),
            depth=depth_from_mm(depth_mm),
            t=t,
            intrinsics=self._intr,
            index=self._index,
            meta={"depth_timestamp_us": int(d.timestamp), "color_timestamp_us": int(g.timestamp),
                  "depth_frame": int(d.frameIndex), "color_frame": int(g.frameIndex)},
        )
        self._index += 1
        return frame
