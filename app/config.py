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
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from app.errors import ConfigError
from calib.setup import Setup, check_setup

# Solver names as in the paper; checked against calib.METHODS when the solver
# layer is imported (calib.api), here only for shape.
DEFAULT_METHOD = "YKronT'"
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


@dataclass
class CalibrateConfig:
    """``[calibrate]``: the active run (robot moves through random poses).

    Poses are drawn around the start pose: each axis offset uniform in
    ``+-translation_range_m``, a rotation about a random axis by up to
    ``tilt_deg``. The run stops at ``samples`` or as soon as the predicted
    1-sigma of the camera transform falls below both targets (after
    ``min_samples``).
    """

    SECTION = "calibrate"
    samples: int = 20
    min_samples: int = 8
    target_sigma_mm: float = 0.0
    target_sigma_deg: float = 0.0
    translation_range_m: float = 0.15
    tilt_deg: float = 40.0
    settle_s: float = 0.1
    max_attempts: int = 200
    image_margin_px: int = 40
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
        _string(self, "method", allow_empty=False)
        _boolean(self, "refine")
        _boolean(self, "robust")
        _integer(self, "seed", 0)


@dataclass
class MonitorConfig:
    """``[monitor]``: passive sampling while something else moves the robot.

    A sample is taken when the robot has been still for ``still_s`` and its
    pose differs from each of the last ``diversity_window`` samples by at
    least ``min_translation_m`` or ``min_rotation_deg``.
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
    method: str = DEFAULT_METHOD
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
        _integer(self, "reestimate_samples", 3)
        _string(self, "method", allow_empty=False)
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


def load_config(path: str | Path | None = None) -> Config:
    """Load and validate a TOML config; ``None`` gives the embedded simulated cell.

    Raises
    ------
    ConfigError
        If the file is missing, not valid TOML, or a field is invalid.
    """
    if path is None:
        return Config()
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: invalid TOML: {e}") from None
    try:
        return config_from_dict(data)
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}") from None
