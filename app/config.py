"""Application configuration: TOML files in ``config/`` -> validated dataclasses.

The dataclass defaults ARE the simulated cell of ``config/sim.toml`` (the
embedded default that ``handeye demo`` runs with no file); a test keeps the
two identical. Every field is checked in ``__post_init__`` with a message that
names it, and unknown keys are rejected naming the key, so a typo in a config
never silently falls back to a default.

The ``[robot]``, ``[camera]`` and ``[marker]`` tables are handed unchanged to
the device and vision layers, whose own config dataclasses validate them
(see `app.devices`); this module checks only what the application owns.
"""

from __future__ import annotations

import dataclasses
import math
import shlex
import shutil
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from app.errors import ConfigError
from app.files import read_text_file
from calib.setup import Setup, check_setup

# Solver names as in the paper (or "auto", calib.auto); checked against calib.METHODS
# when the solver layer is imported (calib.api), here only for shape.
DEFAULT_METHOD = "auto"
# The monitor re-estimates from a few samples after a move: the paper's point solver.
MONITOR_METHOD = "YKronT'"
# Result formats of app.formats.write_result (kept literal: config must load without the exporters).
EXPORTS = ("yaml", "json", "easy_handeye", "easy_handeye2", "urdf", "ros2_launch")
# [frames]: names every export uses (validated by app.formats.export.check_frames). "camera" is the
# camera's optical frame (z forward, x right, y down), not a ROS camera_link.
FRAMES = {"base": "base", "flange": "flange", "camera": "camera", "marker": "marker"}


def _positive(obj, name: str, *, allow_zero: bool = False) -> None:
    v = getattr(obj, name)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ConfigError(f"{type(obj).SECTION}.{name} must be a finite number, got {v!r}")
    if v < 0 or (v == 0 and not allow_zero):
        raise ConfigError(f"{type(obj).SECTION}.{name} must be {'>= 0' if allow_zero else '> 0'}, got {v!r}")


def _integer(obj, name: str, minimum: int) -> None:
    v = getattr(obj, name)
    if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
        raise ConfigError(f"{type(obj).SECTION}.{name} must be an integer >= {minimum}, got {v!r}")


def _boolean(obj, name: str) -> None:
    if not isinstance(getattr(obj, name), bool):
        raise ConfigError(f"{type(obj).SECTION}.{name} must be true or false, got {getattr(obj, name)!r}")


def _string(obj, name: str, *, choices=None, allow_empty: bool = True) -> None:
    v = getattr(obj, name)
    if not isinstance(v, str) or (not allow_empty and not v):
        raise ConfigError(f"{type(obj).SECTION}.{name} must be a {'non-empty ' if not allow_empty else ''}string, got {v!r}")
    if choices is not None and v not in choices:
        raise ConfigError(f"{type(obj).SECTION}.{name} must be one of {list(choices)}, got {v!r}")


def _method(obj, name: str) -> None:
    """A solver name `calib.api.solve` knows, so a typo fails at load, before any robot motion."""
    from calib.api import AUTO, resolve_method
    from calib.errors import CalibrationError

    _string(obj, name, allow_empty=False)
    if getattr(obj, name).strip().lower() == AUTO:
        setattr(obj, name, AUTO)
        return
    try:
        setattr(obj, name, resolve_method(getattr(obj, name)).name)
    except CalibrationError as e:
        raise ConfigError(f"{type(obj).SECTION}.{name}: {e}") from None


def hook_argv(command: str) -> list[str]:
    """The alarm hook's argument list (split like a shell, run without one); [] for no hook.

    Raises
    ------
    ConfigError
        Naming ``monitor.alarm_hook``: unbalanced quotes, or a program that is
        neither on ``PATH`` nor an executable file.
    """
    if not command.strip():
        return []
    try:
        argv = shlex.split(command)
    except ValueError as e:
        raise ConfigError(f"monitor.alarm_hook: cannot split {command!r} into arguments ({e})") from None
    if not argv:
        return []
    if shutil.which(argv[0]) is None:
        raise ConfigError(f"monitor.alarm_hook: program {argv[0]!r} not found on PATH or not executable")
    return argv


@dataclass
class CalibrateConfig:
    """``[calibrate]``: the active run (robot moves through planned, random or listed poses).

    Poses lie around the start pose: each axis offset within
    ``+-translation_range_m``, a rotation about an axis through the flange by
    up to ``tilt_deg``. ``poses``: ``"optimal"`` (`calib.planner`: a small
    model-free bootstrap, then the pose that teaches the estimator most about
    the camera per second of motion), ``"random"`` (uniform), or a file
    (``plan.json`` from ``handeye plan``). The run stops at ``samples`` or as
    soon as the predicted 1-sigma of the camera transform falls below both
    targets (after ``min_samples``).

    Planner validity (poses that fail are never sent): the marker's corners
    ``image_margin_px`` inside the image, its center's depth within
    ``depth_range_m``, its face within ``max_view_angle_deg`` of the camera
    ray, the flange and the marker (eye-to-hand) / camera (eye-in-hand) at
    least ``clearance_m`` from every ``keep_out`` box (``[[xmin, ymin, zmin],
    [xmax, ymax, zmax]]`` in the base frame, m) along the path; the robot
    driver adds its own limits (joints, workspace box, tilt cone, path).
    ``lever_max_m`` bounds the flange-to-marker (eye-to-hand) or
    flange-to-camera (eye-in-hand) distance that the bootstrap's in-view
    guarantee assumes. ``travel_weight``: information (nats) one second of
    motion is worth.
    """

    SECTION = "calibrate"
    samples: int = 20
    min_samples: int = 8
    target_sigma_mm: float = 1.0
    target_sigma_deg: float = 0.1
    poses: str = "optimal"
    translation_range_m: float = 0.15
    tilt_deg: float = 40.0
    settle_s: float = 0.1
    max_attempts: int = 200
    image_margin_px: int = 40
    depth_range_m: list = field(default_factory=lambda: [0.4, 2.0])
    max_view_angle_deg: float = 60.0
    keep_out: list = field(default_factory=list)
    clearance_m: float = 0.05
    lever_max_m: float = 0.1
    travel_weight: float = 0.05
    method: str = DEFAULT_METHOD
    refine: bool = True
    robust: bool = False
    seed: int = 0

    def __post_init__(self):
        _integer(self, "samples", 3)
        _integer(self, "min_samples", 3)
        if self.min_samples > self.samples:
            raise ConfigError(f"calibrate.min_samples ({self.min_samples}) must be <= calibrate.samples ({self.samples})")
        _positive(self, "target_sigma_mm", allow_zero=True)
        _positive(self, "target_sigma_deg", allow_zero=True)
        _positive(self, "translation_range_m")
        if self.translation_range_m > 1.0:
            raise ConfigError(f"calibrate.translation_range_m must be <= 1.0 m, got {self.translation_range_m}")
        _positive(self, "tilt_deg")
        if self.tilt_deg > 90.0:
            raise ConfigError(f"calibrate.tilt_deg must be <= 90, got {self.tilt_deg}")
        _positive(self, "settle_s", allow_zero=True)
        _integer(self, "max_attempts", 1)
        _integer(self, "image_margin_px", 0)
        _string(self, "poses", allow_empty=False)
        r = self.depth_range_m
        if (not isinstance(r, (list, tuple)) or len(r) != 2 or any(isinstance(v, bool) or not isinstance(v, (int, float))
                                                                   or not math.isfinite(v) for v in r)
                or not 0 <= r[0] < r[1]):
            raise ConfigError(f"calibrate.depth_range_m must be [min, max] m with 0 <= min < max, got {r!r}")
        _positive(self, "max_view_angle_deg")
        if self.max_view_angle_deg >= 90.0:
            raise ConfigError(f"calibrate.max_view_angle_deg must be < 90, got {self.max_view_angle_deg}")
        if not isinstance(self.keep_out, list):
            raise ConfigError(f"calibrate.keep_out must be a list of [[xmin, ymin, zmin], [xmax, ymax, zmax]], "
                              f"got {self.keep_out!r}")
        for i, box in enumerate(self.keep_out):
            try:
                lo, hi = (np.asarray(v, dtype=float) for v in box)
                ok = lo.shape == hi.shape == (3,) and np.isfinite(lo).all() and np.isfinite(hi).all() and (lo < hi).all()
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise ConfigError(f"calibrate.keep_out[{i}] must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] (m) with "
                                  f"min < max, got {box!r}")
        _positive(self, "clearance_m", allow_zero=True)
        _positive(self, "lever_max_m", allow_zero=True)
        _positive(self, "travel_weight", allow_zero=True)
        _method(self, "method")
        _boolean(self, "refine")
        _boolean(self, "robust")
        _integer(self, "seed", 0)


@dataclass
class MonitorConfig:
    """``[monitor]``: passive sampling while something else moves the robot.

    A sample is taken when the robot has been still for ``still_s`` and its
    pose differs from each of the last ``diversity_window`` samples by at
    least ``min_translation_m`` or ``min_rotation_deg``. The samples since the
    start (or the last alarm) are held in a set of at most ``keep_samples``
    (0 = unbounded): beyond it, the sample whose loss costs the estimate the
    least information goes, never one of the ``keep_recent`` newest
    (`calib.planner.least_informative`, docs/planning.md).
    """

    SECTION = "monitor"
    still_s: float = 0.3
    poll_s: float = 0.05
    min_translation_m: float = 0.03
    min_rotation_deg: float = 5.0
    diversity_window: int = 10
    max_samples: int = 0
    duration_s: float = 0.0
    alarm_hook: str = ""
    reestimate_samples: int = 8
    keep_samples: int = 300
    keep_recent: int = 50
    method: str = MONITOR_METHOD
    online: dict = field(default_factory=dict)

    def __post_init__(self):
        _positive(self, "still_s", allow_zero=True)
        _positive(self, "poll_s")
        _positive(self, "min_translation_m", allow_zero=True)
        _positive(self, "min_rotation_deg", allow_zero=True)
        _integer(self, "diversity_window", 0)
        _integer(self, "max_samples", 0)
        _positive(self, "duration_s", allow_zero=True)
        _string(self, "alarm_hook")
        hook_argv(self.alarm_hook)
        _integer(self, "reestimate_samples", 3)
        _integer(self, "keep_samples", 0)
        _integer(self, "keep_recent", 0)
        if self.keep_samples and self.keep_recent >= self.keep_samples:
            raise ConfigError(f"monitor.keep_recent ({self.keep_recent}) must be below monitor.keep_samples "
                              f"({self.keep_samples})")
        _method(self, "method")
        if not isinstance(self.online, dict):
            raise ConfigError(f"monitor.online must be a table, got {self.online!r}")


@dataclass
class SessionConfig:
    """``[session]``: where sessions (samples, frames, result, .rrd) are written.

    ``exports`` lists the result files written into the session at the end of
    a run (formats of `app.formats.write_result`).
    """

    SECTION = "session"
    root: str = "sessions"
    save_frames: bool = True
    exports: list = field(default_factory=lambda: list(EXPORTS))

    def __post_init__(self):
        _string(self, "root", allow_empty=False)
        _boolean(self, "save_frames")
        if not isinstance(self.exports, list) or any(e not in EXPORTS for e in self.exports):
            raise ConfigError(f"session.exports must be a list of {list(EXPORTS)}, got {self.exports!r}")


@dataclass
class VizConfig:
    """``[viz]``: rerun logging (an ``.rrd`` beside the session; live viewer on request).

    ``viewer_bind`` is the address the live viewer listens on: loopback, so
    the recording is not served to the network, unless set otherwise.
    """

    SECTION = "viz"
    enabled: bool = True
    viewer: bool = False
    viewer_bind: str = "127.0.0.1"
    log_images: bool = True

    def __post_init__(self):
        _boolean(self, "enabled")
        _boolean(self, "viewer")
        _string(self, "viewer_bind", allow_empty=False)
        _boolean(self, "log_images")


# The simulated cell (config/sim.toml): a UR10 simulator (mocks.ur_sim, started by the
# robot driver itself and driven through the real ur_rtde client) holding the
# flange 0.9 m in front of the base with the marker facing the rendered camera,
# whose true pose is the rendered camera's default (calib.simulate.realistic_cell).
SIM_START_Q = [0.367792, -3.559685, 1.448735, -1.704477, -0.767569, 0.521542]


def _default_robot() -> dict:
    return {
        "type": "ur_sim",
        "host": "127.0.0.2",
        "model": "ur10",
        "controller": "3.15",
        "initial_q": list(SIM_START_Q),
        "sim_tcp_offset": [0.0, 0.0, 0.1, 0.0, 0.0, 0.0],
        "tcp_offset": [0.0, 0.0, 0.1, 0.0, 0.0, 0.0],
        "speed": 0.5,
        "acceleration": 2.0,
        "workspace_min": [0.65, -0.15, 0.25],
        "workspace_max": [1.15, 0.35, 0.75],
        "tilt_reference": [-0.2476, -0.8666, 0.4333],
        "max_tilt_deg": 45.0,
    }


def _default_camera() -> dict:
    return {"backend": "rendered", "setup": Setup.EYE_TO_HAND.value}


def _default_marker() -> dict:
    return {"kind": "aruco", "dictionary": "DICT_4X4_50", "marker_id": 0, "marker_size": 0.05}


@dataclass
class Config:
    """The whole application configuration (one TOML file).

    ``setup`` is ``"eye_to_hand"`` (static camera, marker on the flange:
    ``X = T_flange_marker``, ``Y = T_base_cam``) or ``"eye_in_hand"`` (camera
    on the flange, static marker: ``X = T_flange_cam``, ``Y = T_base_marker``).
    """

    SECTION = "config"
    setup: Setup = Setup.EYE_TO_HAND
    robot: dict = field(default_factory=_default_robot)
    camera: dict = field(default_factory=_default_camera)
    marker: dict = field(default_factory=_default_marker)
    calibrate: CalibrateConfig = field(default_factory=CalibrateConfig)
    monitor: MonitorConfig = field(default_factory=MonitorConfig)
    session: SessionConfig = field(default_factory=SessionConfig)
    viz: VizConfig = field(default_factory=VizConfig)
    frames: dict = field(default_factory=lambda: dict(FRAMES))
    mqtt: dict = field(default_factory=dict)

    def __post_init__(self):
        self.setup = check_setup(self.setup, error=ConfigError)
        for name in ("robot", "camera", "marker", "frames", "mqtt"):
            if not isinstance(getattr(self, name), dict):
                raise ConfigError(f"[{name}] must be a table, got {getattr(self, name)!r}")
        backend = self.camera.get("backend")
        if not isinstance(backend, str) or not backend:
            raise ConfigError(f"camera.backend must be a non-empty string, got {backend!r}")
        if "setup" in self.camera and self.camera["setup"] != self.setup:
            raise ConfigError(f"camera.setup ({self.camera['setup']!r}) must match setup ({self.setup!r})")

    def to_dict(self) -> dict:
        """Plain-data form (for ``session.json``): the config that was actually used."""
        return dataclasses.asdict(self)


_SECTIONS = {f.name: f for f in dataclasses.fields(Config)}


def _build(cls, data: Any, section: str):
    if not isinstance(data, dict):
        raise ConfigError(f"[{section}] must be a table, got {data!r}")
    known = {f.name for f in dataclasses.fields(cls)}
    for key in data:
        if key not in known:
            raise ConfigError(f"unknown key {section}.{key} (known: {', '.join(sorted(known))})")
    return cls(**data)


def config_from_dict(data: dict) -> Config:
    """Validate a parsed TOML document into a `Config`.

    Raises
    ------
    ConfigError
        Naming the unknown key or the bad field.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"config must be a table, got {type(data).__name__}")
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key not in _SECTIONS:
            raise ConfigError(f"unknown key {key!r} (known: {', '.join(sorted(_SECTIONS))})")
        ftype = _SECTIONS[key].type
        sub = {"CalibrateConfig": CalibrateConfig, "MonitorConfig": MonitorConfig,
               "SessionConfig": SessionConfig, "VizConfig": VizConfig}.get(ftype)
        kwargs[key] = _build(sub, value, key) if sub is not None else value
    return Config(**kwargs)


#: A config is a few kB; this bounds what a wrong path (a log, a disk image) can cost.
MAX_CONFIG_BYTES = 1024 * 1024
#: Deepest nesting of tables/arrays a config may have (ours has 3); deeper input
#: would otherwise exhaust the TOML parser's recursion.
MAX_CONFIG_DEPTH = 16


def _depth(value, limit: int, level: int = 0) -> int:
    if level > limit:
        return level
    if isinstance(value, dict):
        return max((_depth(v, limit, level + 1) for v in value.values()), default=level + 1)
    if isinstance(value, list):
        return max((_depth(v, limit, level + 1) for v in value), default=level + 1)
    return level


def load_config(path: str | Path | None = None) -> Config:
    """Load and validate a TOML config; ``None`` gives the embedded simulated cell.

    Raises
    ------
    ConfigError
        If the file is missing, not a regular UTF-8 file, not valid TOML,
        nested deeper than `MAX_CONFIG_DEPTH`, or a field is invalid; the
        message names the file and the field.
    """
    if path is None:
        return Config()
    path = Path(path)
    try:
        text = read_text_file(path, ConfigError, max_bytes=MAX_CONFIG_BYTES)
    except ConfigError as e:
        raise ConfigError(f"config file {e}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: invalid TOML: {e}") from None
    except RecursionError:
        raise ConfigError(f"{path}: nested deeper than the TOML parser allows") from None
    if _depth(data, MAX_CONFIG_DEPTH) > MAX_CONFIG_DEPTH:
        raise ConfigError(f"{path}: nested deeper than {MAX_CONFIG_DEPTH} levels; not a handeye config")
    try:
        return config_from_dict(data)
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}") from None
