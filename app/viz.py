"""All rerun logging of handeye (the only module that imports ``rerun``).

Entity tree (base frame = ``world``, metres, z up)::

    world/base                   robot base axes
    world/flange                 robot flange pose (axes)
    world/camera                 estimated camera pose: T_base_cam (eye-to-hand)
    world/flange/camera          ... or T_flange_cam (eye-in-hand)
      .../image                  pinhole frustum, color image, depth image
      .../image/marker           detected marker center (2D)
    world/camera_truth           true camera pose (simulated cells only)
    world/samples/measured       marker centers seen by the camera, in the base frame
    world/samples/predicted      marker centers predicted by the estimate (A_i X)
    residuals/translation_mm     per-sample residual of the latest estimate
    uncertainty/{sigma_mm,sigma_deg}   1-sigma of the camera transform over time
    drift/{translation_mm,rotation_deg} online estimate vs. the reference
    events                       alarms, skips, stops (text log)
    plan/flange                  planned flange poses (``handeye plan``; timeline ``plan_pose``)
    plan/camera/image            camera frustum and the predicted marker outline per planned pose
    plan/path                    the flange path through the planned poses
    plan/sigma_{mm,deg}          expected 1-sigma after each planned pose

A disabled `Viz` (``--no-viz``) logs nothing and never touches rerun.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from app.pipeline import sigma
from calib import transforms as tf

log = logging.getLogger(__name__)


class Viz:
    """rerun recording of a calibration or monitoring run.

    Parameters
    ----------
    setup : {"eye_to_hand", "eye_in_hand"}
    rrd_path : Path or None
        Where to save the recording (``.rrd`` beside the session).
    viewer : bool
        Also spawn a live viewer.
    enabled : bool
        False makes every method a no-op (rerun is not even imported).
    log_images : bool
        Log color and depth images (large recordings; off for long monitors).
    """

    def __init__(self, setup: str, rrd_path: Path | None = None, *, viewer: bool = False,
                 enabled: bool = True, log_images: bool = True):
        self.setup = setup
        self.enabled = enabled
        self.log_images = log_images
        self._rec = None
        if not enabled:
            return
        import rerun as rr

        self._rr = rr
        self._rec = rr.RecordingStream("handeye")
        if viewer:
            self._rec.spawn()
        if rrd_path is not None:
            # save() replaces any viewer sink, so with both use set_sinks.
            if viewer:
                self._rec.set_sinks(rr.GrpcSink(), rr.FileSink(str(rrd_path)))
            else:
                self._rec.save(str(rrd_path))
        self._rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._rec.log("world/base", rr.TransformAxes3D(0.2), static=True)
        self._rec.log("events", rr.TextLog(f"setup: {setup}"), static=True)
        self._cam_path = "world/camera" if setup == "eye_to_hand" else "world/flange/camera"
        self._measured: list[np.ndarray] = []

    def _time(self, t: float, index: int | None = None) -> None:
        self._rec.set_time("time", timestamp=t)
        if index is not None:
            self._rec.set_time("sample", sequence=index)

    def _transform(self, path: str, T: np.ndarray, *, static: bool = False) -> None:
        rr = self._rr
        self._rec.log(path, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=static)
        self._rec.log(path, rr.TransformAxes3D(0.1), static=static)

    def truth(self, T_camera_true: np.ndarray) -> None:
        """True camera transform of a simulated cell (static)."""
        if not self.enabled:
            return
        path = "world/camera_truth" if self.setup == "eye_to_hand" else "world/flange/camera_truth"
        self._transform(path, T_camera_true, static=True)

    def robot(self, t: float, T_base_flange: np.ndarray) -> None:
        """Flange pose at host time ``t``."""
        if not self.enabled:
            return
        self._time(t)
        self._transform("world/flange", T_base_flange)

    def frame(self, t: float, color, depth, intrinsics, marker_px=None) -> None:
        """Color/depth image with its pinhole, and the detected marker center (pixels) if any."""
        if not self.enabled:
            return
        rr = self._rr
        self._time(t)
        img = f"{self._cam_path}/image"
        self._rec.log(img, rr.Pinhole(image_from_camera=intrinsics.K, width=intrinsics.width,
                                      height=intrinsics.height, camera_xyz=rr.ViewCoordinates.RDF))
        if self.log_images and color is not None:
            self._rec.log(img, rr.Image(color, color_model="BGR"))
        if self.log_images and depth is not None:
            self._rec.log(f"{img}/depth", rr.DepthImage(depth, meter=1.0))
        if marker_px is not None:
            self._rec.log(f"{img}/marker", rr.Points2D([marker_px], radii=4.0, colors=[255, 0, 0]))

    def sample(self, obs, T_camera: np.ndarray | None) -> None:
        """An accepted sample: its flange pose and, given a camera estimate, the marker point in the base frame."""
        if not self.enabled:
            return
        self._time(obs.t, obs.index)
        self._transform("world/flange", obs.T_base_flange)
        if T_camera is not None and obs.point_cam is not None:
            T_base_cam = T_camera if self.setup == "eye_to_hand" else obs.T_base_flange @ T_camera
            self._measured.append(tf.transform_points(T_base_cam, obs.point_cam))
            self._rec.log("world/samples/measured",
                          self._rr.Points3D(np.array(self._measured), radii=0.004, colors=[0, 160, 255]))

    def estimate(self, t: float, result, observations) -> None:
        """Latest estimate: camera pose, predicted marker points, residuals, 1-sigma."""
        if not self.enabled:
            return
        rr = self._rr
        self._time(t, result.n_samples)
        self._transform(self._cam_path, result.camera_transform)
        A = np.array([o.T_base_flange for o in observations])
        if self.setup == "eye_to_hand":
            predicted = tf.transform_points(A @ result.X, np.zeros(3))
            T_base_cams = np.broadcast_to(result.Y, A.shape)
        else:
            predicted = np.broadcast_to(result.Y[:3, 3], (len(A), 3))
            T_base_cams = A @ result.X
        measured = np.array([tf.transform_points(T, o.point_cam if o.point_cam is not None else o.T_cam_marker[:3, 3])
                             for T, o in zip(T_base_cams, observations)])
        self._measured = list(measured)
        self._rec.log("world/samples/measured", rr.Points3D(measured, radii=0.004, colors=[0, 160, 255]))
        self._rec.log("world/samples/predicted", rr.Points3D(predicted, radii=0.003, colors=[255, 160, 0]))
        self._rec.log("residuals/translation_mm", rr.Scalars(result.residuals.rms_translation * 1e3))
        if result.cov is not None:
            s_deg, s_mm = sigma(result.cov)
            self._rec.log("uncertainty/sigma_mm", rr.Scalars(s_mm))
            self._rec.log("uncertainty/sigma_deg", rr.Scalars(s_deg))

    def drift(self, t: float, translation_mm: float, rotation_deg: float) -> None:
        """Online estimate vs. the reference calibration."""
        if not self.enabled:
            return
        self._time(t)
        self._rec.log("drift/translation_mm", self._rr.Scalars(translation_mm))
        self._rec.log("drift/rotation_deg", self._rr.Scalars(rotation_deg))

    def event(self, t: float, text: str, level: str = "INFO") -> None:
        """An alarm, skip or stop, as a text log line."""
        if not self.enabled:
            return
        self._time(t)
        self._rec.log("events", self._rr.TextLog(text, level=level))

    def plan(self, poses, X: np.ndarray, Y: np.ndarray, intrinsics, marker_size_m: float) -> None:
        """Planned poses (`calib.planner.PlannedPose`) of a dry run, one step of the ``plan_pose`` timeline each:
        flange axes, the camera frustum and what the camera would see (predicted marker outline and center).

        Eye-to-hand: ``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand:
        ``X = T_flange_cam``, ``Y = T_base_marker``.
        """
        if not self.enabled:
            return
        rr = self._rr
        A = np.array([p.T_base_flange for p in poses])
        self._rec.log("plan/path", rr.LineStrips3D([A[:, :3, 3]], colors=[200, 200, 200]), static=True)
        h = marker_size_m / 2
        corners = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0], [-h, -h, 0]])
        for i, p in enumerate(poses):
            self._rec.set_time("plan_pose", sequence=i)
            T_base_cam = Y if self.setup == "eye_to_hand" else p.T_base_flange @ X
            T_cam_marker = tf.invert(T_base_cam) @ (p.T_base_flange @ X if self.setup == "eye_to_hand" else Y)
            self._transform("plan/flange", p.T_base_flange)
            self._transform("plan/camera", T_base_cam)
            img = "plan/camera/image"
            self._rec.log(img, rr.Pinhole(image_from_camera=intrinsics.K, width=intrinsics.width,
                                          height=intrinsics.height, camera_xyz=rr.ViewCoordinates.RDF))
            pc = tf.transform_points(T_cam_marker, corners)
            uv = np.stack([intrinsics.fx * pc[:, 0] / pc[:, 2] + intrinsics.cx,
                           intrinsics.fy * pc[:, 1] / pc[:, 2] + intrinsics.cy], -1)
            self._rec.log(f"{img}/marker", rr.LineStrips2D([uv], colors=[255, 0, 0]))
            self._rec.log(f"{img}/center", rr.Points2D([p.pixel], radii=4.0, colors=[255, 0, 0]))
            s_deg, s_mm = sigma(p.cov)
            self._rec.log("plan/sigma_mm", rr.Scalars(s_mm))
            self._rec.log("plan/sigma_deg", rr.Scalars(s_deg))

    def close(self) -> None:
        if self._rec is not None:
            self._rec.flush()
            self._rec.disconnect()
            self._rec = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

