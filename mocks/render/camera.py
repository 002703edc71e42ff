"""A simulated RGB-D camera that renders the marker at the robot's current pose.

Selected by ``[camera] backend = "rendered"``. The config holds the *true*
mounting the calibration should recover:

- eye-to-hand (static camera, marker on the flange): ``T_base_cam`` (= Y) and
  ``T_flange_marker`` (= X);
- eye-in-hand (camera on the flange, static marker): ``T_flange_cam`` (= X)
  and ``T_base_marker`` (= Y).

Every ``read()`` asks ``flange_pose_source()`` for the current
``T_base_flange`` (the app wires it to the robot driver), renders there with
`handeye.mocks.render.scene.MarkerSceneRenderer`, and puts the truth
(``T_cam_marker``, ``point_cam``, ``T_base_flange``, ``X``, ``Y``, ``setup``)
in ``RGBDFrame.truth``.

``[camera.mount]`` (`CameraMount`, off by default) moves the true camera over
the run: a drift at mm/h and deg/h and knocks at given times, on a mount
clock that starts at `RenderedCamera.connect` (``time_scale`` speeds it up).
`RenderedCamera.truth` and each frame's truth are the camera of that moment.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Literal

import numpy as np
from pydantic import Field, field_validator, model_validator
from scipy.spatial.transform import Rotation

from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError, ParameterError
from handeye.drivers.errors import DeviceError
from handeye.calib.params import (Bool, Float, Int, NonNegativeFloat, NonNegativeInt, Params, PositiveFloat,
                                  PositiveInt, Str, Transform, Vector3)
from handeye.calib.setup import Setup
from handeye.calib.vision.markers import get_dictionary
from handeye.drivers.camera.registry import CAMERAS
from handeye.drivers.camera.base import Camera, CameraIntrinsics, RGBDFrame
from handeye.mocks.render.scene import MarkerSceneRenderer, RenderNoise


def _look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_base_cam`` of an optical frame (z forward, y down) at ``eye`` looking at ``target``."""
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    return tf.make_transform(np.column_stack([x, np.cross(z, x), z]), eye)


# Default cell = handeye.calib.simulate.realistic_cell: flange start 0.9 m in front of the
# base, camera 0.7 m to the side and above, looking at it.
_P0 = np.array([0.9, 0.1, 0.5])
_DEFAULT_T_BASE_CAM = _look_at(_P0 + [-0.2, -0.7, 0.35], _P0)
# The marker plate sits 12 mm in front of the flange face, shifted and turned so X is not trivial.
_DEFAULT_T_FLANGE_MARKER = tf.make_transform(
    Rotation.from_euler("z", 30, degrees=True).as_matrix(), [0.02, -0.01, 0.012]
)
# Eye-in-hand: camera 5 cm off the flange axis looking along it; the 4 mm plate lies
# on the floor (base z = 0) below the start pose, face up.
_DEFAULT_T_FLANGE_CAM = tf.make_transform(np.eye(3), [0.0, 0.05, 0.02])
_DEFAULT_T_BASE_MARKER = tf.make_transform(np.eye(3), [0.9, 0.1, 0.004])


def _unit(v, name: str):
    if v is not None and not np.linalg.norm(v) > 0:
        raise ValueError(f"{name} must be a non-zero vector, got {list(v)}")
    return v


class MountBump(Params):
    """A knock of the camera mount at ``at_s`` (mount time, s): ``translation_mm`` along ``direction``, then
    ``rotation_deg`` about ``axis`` through the camera's centre (base frame eye-to-hand, camera frame eye-in-hand)."""

    at_s: NonNegativeFloat
    translation_mm: Float = 5.0
    rotation_deg: Float = 0.3
    direction: Vector3 = (1.0, 0.0, 0.0)
    axis: Vector3 = (0.0, 1.0, 0.0)

    @model_validator(mode="after")
    def _nonzero(self):
        _unit(self.direction, "direction")
        _unit(self.axis, "axis")
        return self

    def transform(self) -> tuple[np.ndarray, np.ndarray]:
        """(rotation (3, 3), translation (3,) m) of the knock."""
        axis, direction = np.asarray(self.axis, float), np.asarray(self.direction, float)
        return (tf.so3_exp(np.deg2rad(self.rotation_deg) * axis / np.linalg.norm(axis)),
                self.translation_mm * 1e-3 * direction / np.linalg.norm(direction))


class CameraMount(Params):
    """``[camera.mount]``: how the true camera moves over a run (a thermally drifting mount, knocks).

    Off by default (no drift, no bumps). Eye-to-hand the camera centre moves in
    the base frame and turns about a base-frame axis through itself; eye-in-hand
    the same in the camera frame (``T_flange_cam @ motion``: the camera slips on
    its mount). Either way it moves by exactly the configured mm and deg.

    Attributes
    ----------
    drift_mm_per_h, drift_deg_per_h : float
        Constant drift rates of the mount (mm/h along ``drift_direction``,
        deg/h about ``drift_axis``).
    drift_direction, drift_axis : 3 floats or None
        Directions of the drift (normalised); None: a random unit vector drawn from ``seed``.
    bumps : list of MountBump
        Knocks at given mount times; each stays (the mount does not spring back).
    time_scale : float
        Mount seconds per wall-clock second since `RenderedCamera.connect`
        (e.g. 60: an hour of drift and the bump schedule pass in a minute).
    seed : int
        Seed of the random drift directions.
    """

    drift_mm_per_h: NonNegativeFloat = 0.0
    drift_deg_per_h: NonNegativeFloat = 0.0
    drift_direction: Vector3 | None = None
    drift_axis: Vector3 | None = None
    bumps: list[MountBump] = Field(default_factory=list)
    time_scale: PositiveFloat = 1.0
    seed: Int = 0

    @model_validator(mode="after")
    def _nonzero(self):
        _unit(self.drift_direction, "drift_direction")
        _unit(self.drift_axis, "drift_axis")
        return self

    @property
    def moves(self) -> bool:
        return bool(self.drift_mm_per_h or self.drift_deg_per_h or self.bumps)

    def directions(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit drift direction and drift axis (3,) each: the configured ones or drawn from ``seed``."""
        rng = np.random.default_rng(self.seed)
        drawn = rng.normal(size=(2, 3))
        out = []
        for given, v in zip((self.drift_direction, self.drift_axis), drawn):
            v = np.asarray(given if given is not None else v, float)
            out.append(v / np.linalg.norm(v))
        return out[0], out[1]

    def motion(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(rotation (3, 3), translation (3,) m) of the mount ``t`` mount seconds after the start:
        the drift so far, then every bump due by then, in time order."""
        direction, axis = self.directions()
        R = tf.so3_exp(np.deg2rad(self.drift_deg_per_h) * t / 3600.0 * axis)
        p = self.drift_mm_per_h * 1e-3 * t / 3600.0 * direction
        for bump in sorted(self.bumps, key=lambda b: b.at_s):
            if bump.at_s > t:
                break
            Rb, pb = bump.transform()
            R, p = Rb @ R, p + pb
        return R, p


class RenderedCameraConfig(Params):
    """``[camera]`` table for ``backend = "rendered"``.

    Attributes
    ----------
    setup : Setup
        ``"eye_to_hand"`` or ``"eye_in_hand"``.
    T_base_cam, T_flange_marker : 4x4 nested lists
        True mounting, eye-to-hand (m).
    T_flange_cam, T_base_marker : 4x4 nested lists
        True mounting, eye-in-hand (m).
    dictionary, marker_id, marker_size, plate_size
        The marker (default DICT_4X4_50 id 0, 5 cm on an 8 cm plate, as in the paper's setup).
    width, height, fx, fy, cx, cy
        Pinhole intrinsics (Xtion-like VGA by default), no distortion.
    noise : RenderNoise
        Sensor model; see `handeye.mocks.render.scene.RenderNoise`.
    seed : int
        Seed of the per-frame noise.
    draw_flange, draw_floor : bool
        Add the flange cylinder (eye-to-hand) / a floor plane at base z = 0.
    mount : CameraMount
        Drift and knocks of the camera mount over the run (none by default);
        the transforms above are the camera at the start.
    """

    backend: Literal["rendered"] = "rendered"
    setup: Setup = Setup.EYE_TO_HAND
    T_base_cam: Transform = _DEFAULT_T_BASE_CAM.tolist()
    T_flange_marker: Transform = _DEFAULT_T_FLANGE_MARKER.tolist()
    T_flange_cam: Transform = _DEFAULT_T_FLANGE_CAM.tolist()
    T_base_marker: Transform = _DEFAULT_T_BASE_MARKER.tolist()
    dictionary: Str = "DICT_4X4_50"
    marker_id: NonNegativeInt = 0
    marker_size: PositiveFloat = 0.05
    plate_size: PositiveFloat = 0.08
    width: PositiveInt = 640
    height: PositiveInt = 480
    fx: PositiveFloat = 570.0
    fy: PositiveFloat = 570.0
    cx: Float = 319.5
    cy: Float = 239.5
    noise: RenderNoise = Field(default_factory=RenderNoise)
    seed: Int = 0
    draw_flange: Bool = True
    draw_floor: Bool = True
    mount: CameraMount = Field(default_factory=CameraMount)

    @field_validator("dictionary")
    @classmethod
    def _known_dictionary(cls, name: str) -> str:
        get_dictionary(name)
        return name

    @model_validator(mode="after")
    def _plate_holds_marker(self):
        if self.plate_size < 1.2 * self.marker_size:
            raise ValueError(f"plate_size must be >= 1.2 x marker_size, got {self.plate_size!r}")
        return self

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return CameraIntrinsics(self.width, self.height, float(self.fx), float(self.fy), float(self.cx), float(self.cy))

    @property
    def X(self) -> np.ndarray:
        """The paper's X: ``T_flange_marker`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand)."""
        return np.array(getattr(self, self.setup.x_name), float)

    @property
    def Y(self) -> np.ndarray:
        """The paper's Y: ``T_base_cam`` (eye-to-hand) or ``T_base_marker`` (eye-in-hand)."""
        return np.array(getattr(self, self.setup.y_name), float)


@CAMERAS.register("rendered", RenderedCameraConfig)
class RenderedCamera(Camera):
    """Renders the configured marker at ``flange_pose_source()`` on every `read`.

    Parameters
    ----------
    config : RenderedCameraConfig
    flange_pose_source : callable () -> ndarray (4, 4), optional
        Current ``T_base_flange``; or given later with `follow`, before `connect`.
    """

    simulated = True

    def identity(self) -> dict:
        return {"model": "rendered RGB-D camera (simulated)"}

    def __init__(self, config: RenderedCameraConfig, flange_pose_source: Callable[[], np.ndarray] | None = None):
        self.config = config
        self._source = flange_pose_source
        self._renderer: MarkerSceneRenderer | None = None
        self._rng: np.random.Generator | None = None
        self._index = 0
        #: Wall clock of the mount's time (s); tests replace it to jump through a shift.
        self.clock: Callable[[], float] = time.monotonic
        self._t0: float | None = None

    def mount_time(self) -> float:
        """Mount seconds since `connect` (``mount.time_scale`` x wall seconds; 0 before connecting)."""
        if self._t0 is None:
            return 0.0
        return (self.clock() - self._t0) * self.config.mount.time_scale

    def camera_transform(self, t: float | None = None) -> np.ndarray:
        """The true camera transform (``T_base_cam`` eye-to-hand, ``T_flange_cam`` eye-in-hand) at mount
        time ``t`` (default: now): the configured one moved by `CameraMount.motion`."""
        c = self.config
        T = np.array(getattr(c, c.setup.camera_name), dtype=float)
        if not c.mount.moves:
            return T
        R, p = c.mount.motion(self.mount_time() if t is None else t)
        if c.setup == Setup.EYE_TO_HAND:
            return tf.make_transform(R @ T[:3, :3], T[:3, 3] + p)
        return T @ tf.make_transform(R, p)

    def add_bump(self, translation_mm: float, rotation_deg: float, direction=(1.0, 0.0, 0.0),
                 axis=(0.0, 1.0, 0.0)) -> MountBump:
        """Knock the mount now (a `MountBump` at the current mount time); returns it."""
        bump = MountBump(at_s=self.mount_time(), translation_mm=translation_mm, rotation_deg=rotation_deg,
                         direction=tuple(direction), axis=tuple(axis))
        self.config.mount.bumps.append(bump)
        return bump

    def _XY(self) -> tuple[np.ndarray, np.ndarray]:
        c = self.config
        if c.setup == Setup.EYE_TO_HAND:
            return c.X, self.camera_transform()
        return self.camera_transform(), c.Y

    def follow(self, flange_pose_source: Callable[[], np.ndarray]) -> None:
        self._source = flange_pose_source

    def truth(self) -> dict:
        """The configured true camera and marker transforms (``T_base_cam``/``T_flange_marker``
        eye-to-hand, ``T_flange_cam``/``T_base_marker`` eye-in-hand)."""
        s = self.config.setup
        return {s.camera_name: self.camera_transform(), s.marker_name: np.asarray(getattr(self.config, s.marker_name),
                                                                                   dtype=float)}

    def connect(self) -> None:
        if not callable(self._source):
            raise ParameterError("the rendered camera needs a flange_pose_source callable returning T_base_flange")
        c = self.config
        self._renderer = MarkerSceneRenderer(c.intrinsics, c.dictionary, c.marker_id, c.marker_size, c.plate_size,
                                             c.noise)
        if self._t0 is None:  # a reconnect (an unplugged camera) keeps the mount's clock, noise and frame count
            self._rng = np.random.default_rng(c.seed)
            self._index = 0
            self._t0 = self.clock()

    def disconnect(self) -> None:
        self._renderer = None

    @property
    def is_connected(self) -> bool:
        return self._renderer is not None

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self.config.intrinsics

    def read(self) -> RGBDFrame:
        """Render at the current flange pose (eye-to-hand or eye-in-hand as configured)."""
        if self._renderer is None:
            raise DeviceError("rendered camera is not connected")
        t = time.time()
        try:
            T_base_flange = tf.check_transform(self._source(), "T_base_flange")
        except CalibrationError as e:
            raise DeviceError(f"rendered camera got a bad flange pose: {e}") from None
        c = self.config
        X, Y = self._XY()
        if c.setup == Setup.EYE_TO_HAND:
            T_cam_base = tf.invert(Y)
            T_cam_flange = T_cam_base @ T_base_flange
            T_cam_marker = T_cam_flange @ X
        else:
            T_cam_base = tf.invert(T_base_flange @ X)
            T_cam_flange = None  # the camera rides on the flange: it cannot see it
            T_cam_marker = T_cam_base @ Y
        color, depth, truth = self._renderer.render(
            T_cam_marker,
            self._rng,
            T_cam_flange=T_cam_flange if c.draw_flange else None,
            T_cam_base=T_cam_base if c.draw_floor else None,
        )
        truth.update(T_base_flange=T_base_flange, X=X, Y=Y, setup=c.setup)
        frame = RGBDFrame(color, depth, t, c.intrinsics, self._index, truth, {"source": "rendered"})
        self._index += 1
        return frame
