"""A RealSense D435 made of librealsense's own ``rs.software_device``, looking at the rendered cell.

The SDK's software device has the sensors, stream profiles, intrinsics, extrinsics, options and
device info of a real one; its frames are the ones we push. `SoftwareRealSense` gives it:

- a "Stereo Module" sensor: ``z16`` depth in the depth camera's own pixels and intrinsics,
  ``depth_units`` 1 mm (read-only, as on a D400), a writable ``visual_preset``;
- an "RGB Camera" sensor: ``rgb8`` colour with the rendered camera's intrinsics;
- the extrinsics depth -> colour (``baseline_m`` along x, as a D435's left imager sits beside its
  colour camera) registered between the two profiles, which ``rs.align`` uses;
- name, serial number, USB type, product line and firmware version.

`SoftwareRealSense.push` renders one frame at a flange pose: the colour image and, from the depth
camera's pose, its depth (`handeye.mocks.render.scene.MarkerSceneRenderer`), pushes both with a timestamp
in the global time domain, and returns the rendered camera's own frame (depth registered to colour
by the renderer) to compare the RealSense path with. With ``baseline_m = 0`` and the depth
intrinsics equal to the colour ones, the depth pushed is that frame's depth, pixel for pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from handeye.calib import transforms as tf
from handeye.calib.setup import Setup
from handeye.drivers.camera.base import CameraIntrinsics, RGBDFrame
from handeye.drivers.camera.depth import depth_to_mm
from handeye.mocks.render.camera import RenderedCamera, RenderedCameraConfig
from handeye.mocks.render.scene import MarkerSceneRenderer

SERIAL = "000011112222"


@dataclass(frozen=True)
class DepthModel:
    """The depth camera of the software device: its intrinsics and where it sits relative to colour.

    ``baseline_m``: depth camera origin at ``-baseline_m`` along the colour camera's x (D435: ~15 mm).
    ``intrinsics``: None takes the colour camera's.
    """

    baseline_m: float = 0.015
    intrinsics: CameraIntrinsics | None = CameraIntrinsics(640, 480, 385.0, 385.0, 320.0, 240.0)


class SoftwareRealSense:
    """An ``rs.software_device`` D435 showing `handeye.mocks.render.camera.RenderedCamera`'s cell (eye-to-hand or
    -in-hand).

    Parameters
    ----------
    camera : RenderedCameraConfig
        The cell and the colour camera (its intrinsics are the colour stream's).
    depth : DepthModel
    fps : int
    usb : str
        The USB type descriptor the device reports (``"3.2"``; ``"2.1"`` for a USB 2 link).
    """

    def __init__(self, camera: RenderedCameraConfig | None = None, depth: DepthModel = DepthModel(), *,
                 fps: int = 30, usb: str = "3.2"):
        import pyrealsense2 as rs

        self.rs = rs
        self.camera = camera or RenderedCameraConfig()
        self.depth_model = depth
        c = self.camera
        self.color_intr = c.intrinsics
        self.depth_intr = depth.intrinsics or self.color_intr
        # T_color_depth: pose of the depth camera in the colour camera's frame.
        self.T_color_depth = tf.make_transform(np.eye(3), [-depth.baseline_m, 0.0, 0.0])
        self._flange = np.eye(4)
        self._rendered = RenderedCamera(c, lambda: self._flange)
        self._rendered.connect()
        self._depth_renderer = None if self._registered else MarkerSceneRenderer(
            self.depth_intr, c.dictionary, c.marker_id, c.marker_size, c.plate_size, c.noise)
        self._rng = np.random.default_rng(c.seed + 1)
        self._keep = []  # the pixel buffers of pushed frames: the SDK reads them after on_video_frame returns

        sd = self.device = rs.software_device()
        for key, value in ((rs.camera_info.name, "Intel RealSense D435 (software device)"),
                           (rs.camera_info.serial_number, SERIAL), (rs.camera_info.usb_type_descriptor, usb),
                           (rs.camera_info.product_line, "D400"), (rs.camera_info.firmware_version, "5.16.0.1")):
            sd.register_info(key, value)
        self.depth_sensor = sd.add_sensor("Stereo Module")
        self.color_sensor = sd.add_sensor("RGB Camera")
        self.depth_profile = self.depth_sensor.add_video_stream(
            self._stream(rs.stream.depth, 0, self.depth_intr, rs.format.z16, 2, fps)).as_video_stream_profile()
        self.color_profile = self.color_sensor.add_video_stream(
            self._stream(rs.stream.color, 1, self.color_intr, rs.format.rgb8, 3, fps)).as_video_stream_profile()
        self.depth_sensor.add_read_only_option(rs.option.depth_units, 0.001)
        self.depth_sensor.add_option(rs.option.visual_preset, rs.option_range(0, 5, 1, 1), True)
        ext = rs.extrinsics()
        ext.rotation = list(self.T_color_depth[:3, :3].reshape(-1))  # column-major; identity either way
        ext.translation = list(self.T_color_depth[:3, 3])
        self.depth_profile.register_extrinsics_to(self.color_profile, ext)
        inv = rs.extrinsics()
        inv.rotation = list(self.T_color_depth[:3, :3].T.reshape(-1))
        inv.translation = list(-self.T_color_depth[:3, 3])
        self.color_profile.register_extrinsics_to(self.depth_profile, inv)
        sd.create_matcher(rs.matchers.dlr_c)
        self._frame = 0

    @property
    def _registered(self) -> bool:
        return self.depth_model.baseline_m == 0 and self.depth_intr == self.color_intr

    def _stream(self, kind, uid: int, intr: CameraIntrinsics, fmt, bpp: int, fps: int):
        rs = self.rs
        i = rs.intrinsics()
        i.width, i.height, i.fx, i.fy, i.ppx, i.ppy = intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy
        i.model, i.coeffs = rs.distortion.none, [0.0] * 5
        s = rs.video_stream()
        s.type, s.index, s.uid, s.width, s.height, s.fps, s.bpp, s.fmt, s.intrinsics = \
            kind, 0, uid, intr.width, intr.height, fps, bpp, fmt, i
        return s

    def _push(self, sensor, profile, pixels: np.ndarray, bpp: int, t_ms: float) -> None:
        rs = self.rs
        f = rs.software_video_frame()
        pixels = np.ascontiguousarray(pixels)
        self._keep = (self._keep + [pixels])[-8:]
        f.pixels, f.stride, f.bpp = pixels, pixels.shape[1] * bpp, bpp
        f.timestamp, f.domain, f.frame_number, f.profile = t_ms, rs.timestamp_domain.global_time, self._frame, profile
        sensor.on_video_frame(f)

    def push(self, T_base_flange: np.ndarray, t: float) -> RGBDFrame:
        """Render at ``T_base_flange`` and push depth + colour stamped ``t`` (s, host clock).

        Returns the rendered camera's frame (colour, depth registered to it, truth) at that pose.
        """
        self._flange = np.asarray(T_base_flange, float)
        frame = self._rendered.read()
        if self._registered:
            depth = frame.depth
        else:
            c, tr = self.camera, frame.truth
            T_depth_color = tf.invert(self.T_color_depth)
            T_cam_base = (tf.invert(tr["Y"]) if c.setup == Setup.EYE_TO_HAND
                          else tf.invert(self._flange @ tr["X"]))
            _, depth, _ = self._depth_renderer.render(
                T_depth_color @ tr["T_cam_marker"], self._rng,
                T_cam_flange=(T_depth_color @ T_cam_base @ self._flange) if c.setup == Setup.EYE_TO_HAND
                and c.draw_flange else None,
                T_cam_base=T_depth_color @ T_cam_base if c.draw_floor else None)
        t_ms = t * 1e3
        self._push(self.depth_sensor, self.depth_profile, depth_to_mm(depth), 2, t_ms)
        self._push(self.color_sensor, self.color_profile, frame.color[..., ::-1], 3, t_ms)
        self._frame += 1
        return frame

    def close(self) -> None:
        self._rendered.disconnect()
