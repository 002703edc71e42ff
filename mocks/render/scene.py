"""Render synthetic RGB-D frames of a marker plate with known truth.

Color: the real marker bitmap (``cv2.aruco.generateImageMarker``) on a white
plate is warped into the image with the plane homography ``K [r1 r2 t]``,
composited over the raycast scene (floor, flange, plate sides), then lit with
a random gain / offset / gradient, blurred and given sensor noise.

Depth: open3d's ``RaycastingScene`` gives the exact depth of the plate, the
flange cylinder and a floor plane; an Xtion-like sensor model is applied:
Gaussian noise in *disparity* (so depth noise grows with z^2), quantisation
to 1/8 px disparity and to 1 mm, a per-frame systematic depth error
``eps z^2``, holes at depth discontinuities (the projector's shadow) and
random dropouts, and no reading outside the sensor range.

Camera frame: OpenCV optical (x right, y down, z forward). Distortion is not
rendered (the intrinsics must have zero ``dist``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

import cv2
import numpy as np
from pydantic import AfterValidator, Field, field_validator

from handeye.calib import transforms as tf
from handeye.calib.errors import ParameterError
from handeye.calib.params import Float, NonNegativeFloat, Params, PositiveFloat
from handeye.calib.vision.markers import get_dictionary

if TYPE_CHECKING:
    import open3d as o3d

_FLOOR, _FLANGE, _PLATE = 0, 1, 2


def _ordered(v):
    if v[0] > v[1]:
        raise ValueError(f"must be [min, max] with min <= max, got {list(v)}")
    return v


#: ``[min, max]`` with ``0 <= min <= max``.
Range = Annotated[tuple[NonNegativeFloat, NonNegativeFloat], AfterValidator(_ordered)]


class RenderNoise(Params):
    """Noise and appearance of rendered frames (all fields validated, named in errors).

    Attributes
    ----------
    disparity_sigma_px : float
        Random disparity noise, px (0.064 px ~ 1.5e-3 z^2 m with f = 570, b = 7.5 cm).
    disparity_step_px : float
        Disparity quantisation, px (PrimeSense: 1/8).
    baseline_m : float
        Projector-camera baseline, m.
    depth_bias_k : float
        Std of the per-frame systematic error coefficient ``eps`` in ``z += eps z^2``, 1/m.
    depth_scale, depth_offset_m : float
        Fixed systematic error of the sensor, ``z -> (1 + depth_scale) z + depth_offset_m``
        before the disparity (an uncorrected structured-light camera: 1-2%, a few mm;
        the ``realistic`` demo config, `handeye.calib.model.CameraCorrection`).
    edge_jump_m : float
        Depth jump between neighbours that leaves a hole, m.
    dropout : float
        Fraction of random missing depth pixels.
    depth_range_m : (float, float)
        Sensor range; no reading outside.
    image_noise : float
        Gray-level noise std.
    blur_sigma_px : (float, float)
        Gaussian blur sigma range, px.
    gain : (float, float)
        Illumination gain range.
    offset : (float, float)
        Illumination offset range, gray levels.
    gradient : float
        Max illumination change across the image, gray levels.
    """

    disparity_sigma_px: NonNegativeFloat = 0.064
    disparity_step_px: NonNegativeFloat = 0.125
    baseline_m: PositiveFloat = 0.075
    depth_bias_k: NonNegativeFloat = 0.5e-3
    depth_scale: Annotated[float, Field(gt=-0.5, lt=0.5)] = 0.0
    depth_offset_m: Annotated[float, Field(gt=-0.1, lt=0.1)] = 0.0
    edge_jump_m: PositiveFloat = 0.03
    dropout: Annotated[NonNegativeFloat, Field(lt=1)] = 0.002
    depth_range_m: Range = (0.4, 4.0)
    image_noise: NonNegativeFloat = 2.0
    blur_sigma_px: Range = (0.3, 0.9)
    gain: Range = (0.7, 1.2)
    offset: Annotated[tuple[Float, Float], AfterValidator(_ordered)] = (-15.0, 15.0)
    gradient: NonNegativeFloat = 30.0

    @field_validator("offset")
    @classmethod
    def _gray_levels(cls, v):
        if v[0] < -255.0:
            raise ValueError(f"must be [min, max] with -255 <= min <= max, got {v!r}")
        return v


def open3d():
    """The open3d module, imported on the first render: a command that never renders (every one on a real
    cell, which loads this backend's config model by name) does without its second of import."""
    import open3d as o3d
    return o3d


def _mesh_arrays(mesh: o3d.geometry.TriangleMesh) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.triangles, dtype=np.uint32)


class MarkerSceneRenderer:
    """Renders a marker plate (and optionally the flange and a floor) at given poses.

    Parameters
    ----------
    intrinsics : object with ``width, height, fx, fy, cx, cy, dist``
    dictionary : str
        OpenCV predefined dictionary name.
    marker_id : int
    marker_size : float
        Marker side (black square), m.
    plate_size : float
        Side of the square white plate the marker is printed on, m.
    noise : RenderNoise
    """

    def __init__(self, intrinsics, dictionary: str, marker_id: int, marker_size: float, plate_size: float,
                 noise: RenderNoise):
        if any(intrinsics.dist):
            raise ParameterError("the rendered camera does not model lens distortion: intrinsics.dist must be zeros")
        if plate_size < marker_size * 1.2:
            raise ParameterError(
                f"plate_size must leave a white margin around the marker (>= 1.2 x marker_size), got {plate_size}"
            )
        self.intr = intrinsics
        self.K = np.array([[intrinsics.fx, 0, intrinsics.cx], [0, intrinsics.fy, intrinsics.cy], [0, 0, 1.0]])
        self.noise = noise
        self.marker_size = marker_size
        self.plate_size = plate_size
        self._dict = get_dictionary(dictionary)
        self.marker_id = marker_id
        self._textures: dict[int, np.ndarray] = {}
        w, h = intrinsics.width, intrinsics.height
        u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
        d = np.stack([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, np.ones_like(u)], -1)
        self._ray_z = (1.0 / np.linalg.norm(d, axis=-1)).astype(np.float32)  # z of a unit ray
        rays = np.zeros((h, w, 6), np.float32)
        rays[..., 3:] = d / np.linalg.norm(d, axis=-1, keepdims=True)
        o3d = open3d()
        self._rays = o3d.core.Tensor(rays)
        # Plate: marker face at z = 0 of the marker frame, 4 mm thick behind it.
        plate = o3d.geometry.TriangleMesh.create_box(plate_size, plate_size, 0.004)
        plate.translate((-plate_size / 2, -plate_size / 2, -0.004))
        # Flange: a UR-sized disc (63 mm) 40 mm deep behind the flange origin.
        flange = o3d.geometry.TriangleMesh.create_cylinder(radius=0.0315, height=0.04, resolution=24)
        flange.translate((0, 0, -0.02))
        floor = o3d.geometry.TriangleMesh.create_box(6.0, 6.0, 0.01)
        floor.translate((-3.0, -3.0, -0.01))
        self._meshes = {_PLATE: _mesh_arrays(plate), _FLANGE: _mesh_arrays(flange), _FLOOR: _mesh_arrays(floor)}
        # A fixed smooth random floor texture (seeded: the scene is part of the config, not per-frame noise).
        tex_rng = np.random.default_rng(12345)
        small = tex_rng.uniform(60, 160, size=(h // 16 + 1, w // 16 + 1)).astype(np.float32)
        self._floor_tex = cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)

    def _texture(self, n: int) -> np.ndarray:
        """Plate texture n x n px: white plate, marker centered; cached per size."""
        if n not in self._textures:
            tex = np.full((n, n), 235, np.uint8)
            m = int(round(n * self.marker_size / self.plate_size))
            # Marker bitmap rendered at 2x and area-averaged: exact edges at the texture's resolution.
            bmp = cv2.aruco.generateImageMarker(self._dict, self.marker_id, 2 * m, borderBits=1)
            bmp = cv2.resize(bmp, (m, m), interpolation=cv2.INTER_AREA)
            o = (n - m) // 2
            tex[o:o + m, o:o + m] = np.maximum(bmp, 20)
            self._textures[n] = tex
        return self._textures[n]

    def render(self, T_cam_marker: np.ndarray, rng: np.random.Generator, *, T_cam_flange: np.ndarray | None = None,
               T_cam_base: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
        """Render one frame.

        Parameters
        ----------
        T_cam_marker : ndarray, shape (4, 4)
            Marker pose in the camera frame (marker face plane ``z = 0``).
        rng : numpy.random.Generator
        T_cam_flange : ndarray, shape (4, 4), optional
            Draw the flange cylinder there (eye-to-hand: the marker's carrier).
        T_cam_base : ndarray, shape (4, 4), optional
            Draw a floor plane at the base's ``z = 0``.

        Returns
        -------
        color : ndarray, shape (H, W, 3), uint8 BGR
        depth : ndarray, shape (H, W), float32, m (0 = no reading)
        truth : dict
            ``T_cam_marker``, ``point_cam`` (the exact marker center) and
            ``depth_bias_eps`` (this frame's systematic error coefficient, 1/m).
        """
        T_cam_marker = tf.check_transform(T_cam_marker, "T_cam_marker")
        o3d = open3d()
        scene = o3d.t.geometry.RaycastingScene()
        poses = {_PLATE: T_cam_marker}
        if T_cam_flange is not None:
            poses[_FLANGE] = T_cam_flange
        if T_cam_base is not None:
            poses[_FLOOR] = T_cam_base
        gid_to_kind = {}
        for kind, T in poses.items():
            verts, tris = self._meshes[kind]
            gid = scene.add_triangles(
                o3d.core.Tensor(tf.transform_points(T, verts).astype(np.float32)), o3d.core.Tensor(tris)
            )
            gid_to_kind[gid] = kind
        hit = scene.cast_rays(self._rays, nthreads=1)
        t_hit = hit["t_hit"].numpy()
        gids = hit["geometry_ids"].numpy()
        kind_img = np.full(gids.shape, -1, np.int8)
        for gid, kind in gid_to_kind.items():
            kind_img[gids == gid] = kind
        z_true = np.where(np.isfinite(t_hit), t_hit * self._ray_z, 0.0).astype(np.float32)

        color = self._render_color(T_cam_marker, kind_img, rng)
        depth, eps = self._sensor_depth(z_true, rng)
        truth = {"T_cam_marker": T_cam_marker.copy(), "point_cam": T_cam_marker[:3, 3].copy(),
                 "depth_bias_eps": eps}
        return color, depth, truth

    def _render_color(self, T_cam_marker, kind_img, rng) -> np.ndarray:
        w, h = self.intr.width, self.intr.height
        img = np.full((h, w), 200.0, np.float32)  # nothing hit: a bright far wall
        img[kind_img == _FLOOR] = self._floor_tex[kind_img == _FLOOR]
        img[kind_img == _FLANGE] = 70.0
        img[kind_img == _PLATE] = 180.0  # plate edges / back
        R, t = T_cam_marker[:3, :3], T_cam_marker[:3, 3]
        facing = float(R[:, 2] @ t) < 0  # marker z axis points back at the camera
        if facing:
            proj_px = self.intr.fx * self.plate_size / t[2]
            n = int(np.clip(2 ** np.ceil(np.log2(max(proj_px, 1.0))), 64, 2048))
            tex = self._texture(n)
            s = self.plate_size / n
            # Texture pixel centers (i, j) -> marker plane (x right, y up), then into the image.
            S = np.array([[s, 0, s * 0.5 - self.plate_size / 2], [0, -s, self.plate_size / 2 - s * 0.5], [0, 0, 1]])
            H = self.K @ np.column_stack([R[:, 0], R[:, 1], t]) @ S
            alpha_tex = np.full((n, n), 255, np.uint8)
            warped = cv2.warpPerspective(tex, H, (w, h), flags=cv2.INTER_LINEAR, borderValue=0)
            alpha = cv2.warpPerspective(alpha_tex, H, (w, h), flags=cv2.INTER_LINEAR, borderValue=0)
            a = alpha.astype(np.float32) / 255.0
            # Only where the raycast sees the plate (another object may occlude it).
            a[kind_img != _PLATE] = 0.0
            img = (1 - a) * img + a * warped.astype(np.float32)
        nz = self.noise
        gain = rng.uniform(*nz.gain)
        ramp = np.linspace(-0.5, 0.5, w, dtype=np.float32)[None, :] * rng.uniform(-nz.gradient, nz.gradient)
        img = img * gain + rng.uniform(*nz.offset) + ramp
        sigma = rng.uniform(*nz.blur_sigma_px)
        if sigma > 0:
            img = cv2.GaussianBlur(img, (0, 0), sigma)
        img += rng.normal(0.0, nz.image_noise, size=img.shape).astype(np.float32)
        gray = np.clip(np.round(img), 0, 255).astype(np.uint8)
        return cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)

    def _sensor_depth(self, z_true: np.ndarray, rng) -> tuple[np.ndarray, float]:
        nz = self.noise
        valid = z_true > 0
        # Holes where neighbours jump (projector shadow / flying pixels at the plate edge).
        zmax = cv2.dilate(z_true, np.ones((3, 3), np.uint8))
        zmin = cv2.erode(np.where(valid, z_true, np.inf).astype(np.float32), np.ones((3, 3), np.uint8))
        valid &= (zmax - zmin) < nz.edge_jump_m
        valid &= rng.random(z_true.shape) >= nz.dropout
        eps = float(rng.normal(0.0, nz.depth_bias_k)) if nz.depth_bias_k > 0 else 0.0
        z = np.where(valid, z_true, 1.0).astype(float)
        z = (1.0 + nz.depth_scale) * z + nz.depth_offset_m + eps * z**2
        fb = self.intr.fx * nz.baseline_m
        disp = fb / z + rng.normal(0.0, nz.disparity_sigma_px, size=z.shape) if nz.disparity_sigma_px > 0 else fb / z
        if nz.disparity_step_px > 0:
            disp = np.round(disp / nz.disparity_step_px) * nz.disparity_step_px
        z = np.round(fb / disp * 1000.0) / 1000.0
        lo, hi = nz.depth_range_m
        valid &= (z >= lo) & (z <= hi)
        return np.where(valid, z, 0.0).astype(np.float32), eps
