"""Intel RealSense D400 RGB-D camera through librealsense's Python bindings (``pyrealsense2``).

``pip install 'handeye[realsense]'`` (the wheel carries librealsense; on Linux
the device needs the udev rules of librealsense's ``scripts/`` to be opened
without root). What the backend does with the device:

- depth aligned to colour by the SDK (``rs.align(rs.stream.color)``), so the
  frame's depth is registered to its colour image as the marker lifting needs;
- the colour intrinsics (pinhole + Brown-Conrady / none) and the depth scale
  (``depth_units``) read from the device, never configured;
- the device chosen by serial number (``serial``; empty: the only one
  attached), its streams by ``width``/``height``/``fps`` (colour ``rgb8``,
  depth ``z16``), its depth preset (``depth_preset``, e.g. ``high_accuracy``);
- the frame time is the colour frame's hardware timestamp in librealsense's
  global time domain (the device clock mapped to the host clock,
  ``global_time_enabled``), the clock `Robot.pose_at` takes; a frame in
  another domain gets the host time at arrival (``meta["timestamp_domain"]``).

Typed errors (`handeye.drivers.errors`): no device attached, no device with the
serial (the ones attached are listed), a USB 2 link (D400 depth + colour at
640x480@30 needs USB 3; ``allow_usb2`` accepts it), a frame that does not
arrive within ``timeout_s`` (`ConnectionLostError`: an outage).

``playback_file`` plays a recording of the SDK's recorder (RealSense Viewer,
``rs.recorder``; librealsense 2.59 writes ROS 2 ``.db3``, older versions ROS 1
``.bag``) through ``rs.config.enable_device_from_file`` instead of a device,
frame by frame (not in real time). A caller holding an ``rs.device`` (e.g. an
``rs.software_device``, which librealsense 2.59's pipeline does not list)
passes it as ``device=``: its depth and colour sensors are opened directly
into an ``rs.syncer``.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import field_validator

from handeye.calib.params import Bool, Params, PositiveFloat, PositiveInt, Str
from handeye.drivers.camera.base import Camera, CameraIntrinsics, RGBDFrame
from handeye.drivers.camera.registry import CAMERAS
from handeye.drivers.errors import ConnectionLostError, DeviceError

log = logging.getLogger(__name__)

INSTALL_HINT = "install librealsense's Python bindings with pip install 'handeye[realsense]'"
#: ``rs.rs400_visual_preset`` names; "" leaves the device's current preset.
PRESETS = ("", "custom", "default", "hand", "high_accuracy", "high_density", "medium_density")


class RealSenseCameraConfig(Params):
    """``[camera]`` table for ``backend = "realsense"``.

    Attributes
    ----------
    serial : str
        Serial number of the device; ``""``: the only RealSense attached.
    width, height, fps : int
        Mode of both streams (colour rgb8, depth z16); depth is aligned to colour.
    depth_preset : str
        One of `PRESETS` (``rs.rs400_visual_preset``); ``""`` keeps the device's.
    playback_file : str
        A recording (``.bag`` / ``.db3``) to play instead of a device.
    timeout_s : float
        A frame not delivered within this time is an outage (`ConnectionLostError`).
    allow_usb2 : bool
        Accept a device on a USB 2 link (lower modes only; refused by default).
    """

    backend: Literal["realsense"] = "realsense"
    serial: Str = ""
    width: PositiveInt = 640
    height: PositiveInt = 480
    fps: PositiveInt = 30
    depth_preset: Literal[PRESETS] = "high_accuracy"
    playback_file: Str = ""
    timeout_s: PositiveFloat = 2.0
    allow_usb2: Bool = False

    @field_validator("playback_file")
    @classmethod
    def _exists(cls, path: str) -> str:
        if path and not Path(path).is_file():
            raise ValueError(f"{path!r} does not exist")
        return path


def _rs():
    try:
        import pyrealsense2 as rs
    except ImportError as e:
        raise DeviceError(f"RealSense camera: cannot import pyrealsense2 ({e}); {INSTALL_HINT}") from None
    return rs


def _info(dev, rs, key) -> str:
    return dev.get_info(key) if dev.supports(key) else ""


def select_device(devices, serial: str, rs):
    """The device of ``serial`` (or the only one) among ``devices``; `DeviceError` naming what is attached."""
    found = [(d, _info(d, rs, rs.camera_info.serial_number)) for d in devices]
    if not found:
        raise DeviceError("RealSense camera: no RealSense device connected" + (f" (camera.serial {serial})" if serial
                                                                               else "") + "; plug it into a USB 3 port")
    names = ", ".join(f"{_info(d, rs, rs.camera_info.name) or 'RealSense'} {s}" for d, s in found)
    if serial:
        hit = [d for d, s in found if s == serial]
        if not hit:
            raise DeviceError(f"RealSense camera: no device with serial {serial} (camera.serial); attached: {names}")
        return hit[0]
    if len(found) > 1:
        raise DeviceError(f"RealSense camera: {len(found)} devices attached ({names}); choose one with camera.serial")
    return found[0][0]


def check_link(dev, rs, allow_usb2: bool) -> None:
    """`DeviceError` for a device on a USB 2 link (the descriptor reads ``2.x``) unless allowed."""
    usb = _info(dev, rs, rs.camera_info.usb_type_descriptor)
    if usb.startswith("2") and not allow_usb2:
        raise DeviceError(f"RealSense camera {_info(dev, rs, rs.camera_info.serial_number)}: connected over USB {usb}; "
                          "depth + colour at full rate need USB 3: use a USB 3 port and cable "
                          "(or camera.allow_usb2 = true with a lower width/height/fps)")


@CAMERAS.register("realsense", RealSenseCameraConfig)
class RealSenseCamera(Camera):
    """Depth aligned to colour from a RealSense D400 device, a recording, or a given ``rs.device``.

    Parameters
    ----------
    config : RealSenseCameraConfig
    device : pyrealsense2.device, optional
        Stream from this device's sensors (e.g. an ``rs.software_device``) instead of finding one.
    """

    def __init__(self, config: RealSenseCameraConfig, device=None):
        self.config = config
        self._given = device
        self._rs = None
        self._pipe = None
        self._sensors: list = []
        self._syncer = None
        self._align = None
        self._depth_scale = 0.0
        self._intr: CameraIntrinsics | None = None
        self._index = 0
        self.device_info: dict = {}

    def connect(self) -> None:
        rs = self._rs = _rs()
        c = self.config
        try:
            if self._given is not None:
                dev = self._given
                self._prepare(dev)
                self._start_sensors(dev)
            elif c.playback_file:
                dev = self._start_pipeline(lambda cfg: cfg.enable_device_from_file(c.playback_file,
                                                                                   repeat_playback=False))
                dev.as_playback().set_real_time(False)  # every frame, as fast as read() asks
                self._prepare(dev)
            else:
                dev = select_device(list(rs.context().query_devices()), c.serial, rs)
                self._prepare(dev)
                serial = _info(dev, rs, rs.camera_info.serial_number)
                self._start_pipeline(lambda cfg: cfg.enable_device(serial))
        except DeviceError:
            self.disconnect()
            raise
        except RuntimeError as e:  # librealsense's own errors (rs.error is a RuntimeError)
            self.disconnect()
            raise DeviceError(f"RealSense camera: {e}") from None
        self._align = rs.align(rs.stream.color)
        self._index = 0

    def identity(self) -> dict:
        """Model, serial number and firmware of the connected device (`device_info`)."""
        info = self.device_info
        return {k: str(info[f]) for k, f in (("model", "name"), ("serial", "serial_number"),
                                             ("firmware", "firmware_version")) if info.get(f)}

    def _prepare(self, dev) -> None:
        """Link check, depth scale, preset and global time on ``dev`` (before its streams start)."""
        rs, c = self._rs, self.config
        check_link(dev, rs, c.allow_usb2)
        self.device_info = {k: _info(dev, rs, getattr(rs.camera_info, k))
                            for k in ("name", "serial_number", "firmware_version", "usb_type_descriptor")}
        # The depth sensor is the one with depth units (a recorder's sensors do not say they are depth sensors).
        depth = next((s for s in dev.query_sensors() if s.supports(rs.option.depth_units)), None)
        if depth is None:
            raise DeviceError(f"RealSense camera {self.device_info['serial_number']}: no depth sensor")
        self._depth_scale = float(depth.get_option(rs.option.depth_units))
        if not 0 < self._depth_scale < 1:
            raise DeviceError(f"RealSense camera: the device reports a depth scale of {self._depth_scale} m")
        if c.depth_preset and not dev.is_playback():  # a recording keeps the preset it was made with
            if not depth.supports(rs.option.visual_preset):
                raise DeviceError(f"RealSense camera: the depth sensor has no presets (camera.depth_preset "
                                  f"{c.depth_preset!r}; use \"\")")
            depth.set_option(rs.option.visual_preset, float(int(getattr(rs.rs400_visual_preset, c.depth_preset))))
        for s in dev.query_sensors():
            if s.supports(rs.option.global_time_enabled) and not s.is_option_read_only(rs.option.global_time_enabled):
                s.set_option(rs.option.global_time_enabled, 1.0)

    def _profiles(self, dev) -> list:
        """The depth z16 and colour rgb8 profiles of the configured mode, one per sensor."""
        rs, c = self._rs, self.config
        out = []
        for stream, fmt in ((rs.stream.depth, rs.format.z16), (rs.stream.color, rs.format.rgb8)):
            hits, have = [], set()
            for s in dev.query_sensors():
                for p in s.get_stream_profiles():
                    if p.stream_type() != stream or not p.is_video_stream_profile():
                        continue
                    v = p.as_video_stream_profile()
                    have.add(f"{v.width()}x{v.height()}@{v.fps()}")
                    if (v.width(), v.height(), v.fps(), p.format()) == (c.width, c.height, c.fps, fmt):
                        hits.append((s, p))
            if not hits:
                raise DeviceError(f"RealSense camera: no {stream.name} {c.width}x{c.height}@{c.fps} {fmt.name} mode "
                                  f"(camera.width/height/fps); has {', '.join(sorted(have)) or 'none'}")
            out.append(hits[0])
        return out

    def _start_sensors(self, dev) -> None:
        rs = self._rs
        (ds, dp), (cs, cp) = self._profiles(dev)
        self._syncer = rs.syncer()
        for s, p in ((ds, dp), (cs, cp)):
            s.open(p)
            self._sensors.append(s)
            s.start(self._syncer)
        self._intr = intrinsics_from_rs(cp.as_video_stream_profile().get_intrinsics(), rs)

    def _start_pipeline(self, choose):
        rs, c = self._rs, self.config
        cfg = rs.config()
        choose(cfg)
        cfg.enable_stream(rs.stream.depth, c.width, c.height, rs.format.z16, c.fps)
        cfg.enable_stream(rs.stream.color, c.width, c.height, rs.format.rgb8, c.fps)
        self._pipe = rs.pipeline()
        profile = self._pipe.start(cfg)
        color = profile.get_stream(rs.stream.color).as_video_stream_profile()
        self._intr = intrinsics_from_rs(color.get_intrinsics(), rs)
        return profile.get_device()

    def disconnect(self) -> None:
        for s in self._sensors:
            try:
                s.stop()
                s.close()
            except RuntimeError as e:  # a device gone mid-run must not prevent cleanup
                log.warning("RealSense camera: closing a sensor failed: %s", e)
        if self._pipe is not None:
            try:
                self._pipe.stop()
            except RuntimeError as e:
                log.warning("RealSense camera: stopping the pipeline failed: %s", e)
        self._sensors, self._pipe, self._syncer, self._align = [], None, None, None

    @property
    def is_connected(self) -> bool:
        return self._align is not None

    @property
    def depth_scale(self) -> float:
        """Metres per depth count, as the device reports it."""
        return self._depth_scale

    @property
    def intrinsics(self) -> CameraIntrinsics:
        if self._intr is None:
            raise DeviceError("RealSense camera is not connected")
        return self._intr

    def _frameset(self):
        """The next frameset holding both depth and colour (the syncer passes a frame it could not match alone)."""
        rs = self._rs
        source = self._pipe if self._pipe is not None else self._syncer
        deadline = time.monotonic() + self.config.timeout_s
        while True:
            ms = max(int((deadline - time.monotonic()) * 1000), 1)
            try:
                ok, frames = source.try_wait_for_frames(ms)
            except RuntimeError as e:
                raise ConnectionLostError(f"RealSense camera: {e}") from None
            if not ok or time.monotonic() > deadline:
                what = f"the recording {self.config.playback_file} ended or" if self.config.playback_file \
                    else "no depth + colour"
                raise ConnectionLostError(f"RealSense camera: {what} frame within {self.config.timeout_s} s")
            if frames.first_or_default(rs.stream.depth) and frames.first_or_default(rs.stream.color):
                return frames

    def read(self) -> RGBDFrame:
        """Next depth + colour pair, depth aligned to colour by the SDK; ``t`` in the global time domain."""
        if self._align is None:
            raise DeviceError("RealSense camera is not connected")
        rs = self._rs
        frames = self._frameset()
        try:
            aligned = self._align.process(frames)
            d, g = aligned.get_depth_frame(), aligned.get_color_frame()
        except RuntimeError as e:
            raise ConnectionLostError(f"RealSense camera: alignment failed: {e}") from None
        if not d or not g:
            raise ConnectionLostError("RealSense camera: a frameset without both depth and colour")
        domain = g.get_frame_timestamp_domain()
        global_time = domain in (rs.timestamp_domain.global_time, rs.timestamp_domain.system_time)
        t = g.get_timestamp() * 1e-3 if global_time else time.time()
        depth = np.asanyarray(d.get_data()).astype(np.float32) * np.float32(self._depth_scale)
        rgb = np.asanyarray(g.get_data())
        frame = RGBDFrame(color=np.ascontiguousarray(rgb[..., ::-1]), depth=depth, t=t, intrinsics=self._intr,
                          index=self._index,
                          meta={"timestamp_domain": domain.name, "device_timestamp_ms": float(g.get_timestamp()),
                                "color_frame": int(g.get_frame_number()), "depth_frame": int(d.get_frame_number())})
        self._index += 1
        return frame


def intrinsics_from_rs(i, rs) -> CameraIntrinsics:
    """`CameraIntrinsics` of an ``rs.intrinsics``: pinhole plus OpenCV's (k1 k2 p1 p2 k3).

    Brown-Conrady is OpenCV's model; any other model is accepted only with zero coefficients
    (D400 colour streams report inverse Brown-Conrady with zeros), since its coefficients would
    mean something else to OpenCV.
    """
    coeffs = tuple(float(v) for v in i.coeffs[:5])
    if i.model != rs.distortion.brown_conrady and any(coeffs):
        raise DeviceError(f"RealSense camera: colour distortion {i.model.name} {list(coeffs)} is not OpenCV's "
                          "model; calibrate the colour camera and use its intrinsics")
    return CameraIntrinsics(int(i.width), int(i.height), float(i.fx), float(i.fy), float(i.ppx), float(i.ppy), coeffs)
