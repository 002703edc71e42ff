"""Application configuration: a TOML file in ``config/`` -> one typed `Config`, parsed and validated once.

Every table is a pydantic model (`calib.params.Params`: unknown keys rejected,
numbers finite and never booleans): ``[calibrate]``, ``[monitor]`` (with
``[monitor.online]`` = `calib.online.OnlineConfig`), ``[session]``, ``[viz]``,
``[marker]`` = `calib.vision.extract.TargetConfig`, and ``[robot]`` /
``[camera]``, a union over the registered backends selected by ``type`` /
``backend`` (`drivers.robot.registry.ROBOTS`, `drivers.camera.registry.CAMERAS`;
every backend is registered by `app.backends`). A bad field is a `ConfigError`
naming the file and ``section.field``.

The models are the one source of defaults: ``Config()`` is the simulated cell
(a UR10 simulator driven through the real ur_rtde client, the rendered camera),
which ``handeye demo`` runs without a file; ``config/sim.toml`` spells the same
cell out for illustration, and a test keeps the two identical.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal, Union

from pydantic import Discriminator, Field, Tag, ValidationError, model_validator

from app import backends  # noqa: F401  every backend registers itself before the unions are built
from app.errors import ConfigError
from calib.online import OnlineConfig
from calib.params import (
    Bool,
    Int,
    NonEmptyStr,
    NonNegativeFloat,
    NonNegativeInt,
    Params,
    PositiveFloat,
    PositiveInt,
    Str,
    describe,
)
from calib.setup import Setup
from calib.vision.extract import TargetConfig
from drivers.camera.registry import CAMERAS
from drivers.registry import Registry
from drivers.robot.registry import ROBOTS
from mocks.render.camera import RenderedCameraConfig
from mocks.ur_sim.robot import URSimRobotConfig

# Solver names as in the paper; checked against calib.METHODS when a run solves.
DEFAULT_METHOD = "YKronT'"
# Result formats of app.formats.write_result (kept literal: config must load without the exporters).
EXPORTS = ("yaml", "json", "easy_handeye", "easy_handeye2", "urdf", "ros2_launch")


class CalibrateConfig(Params):
    """``[calibrate]``: the active run (robot moves through random poses).

    Poses are drawn around the start pose: each axis offset uniform in
    ``+-translation_range_m``, a rotation about a random axis by up to
    ``tilt_deg``. The run stops at ``samples`` or as soon as the predicted
    1-sigma of the camera transform falls below both targets (after
    ``min_samples``).
    """

    samples: Annotated[Int, Field(ge=3)] = 20
    min_samples: Annotated[Int, Field(ge=3)] = 8
    target_sigma_mm: NonNegativeFloat = 0.0
    target_sigma_deg: NonNegativeFloat = 0.0
    translation_range_m: Annotated[PositiveFloat, Field(le=1.0)] = 0.15
    tilt_deg: Annotated[PositiveFloat, Field(le=90.0)] = 40.0
    settle_s: NonNegativeFloat = 0.1
    max_attempts: PositiveInt = 200
    image_margin_px: NonNegativeInt = 40
    method: NonEmptyStr = DEFAULT_METHOD
    refine: Bool = True
    robust: Bool = False
    seed: NonNegativeInt = 0

    @model_validator(mode="after")
    def _enough(self):
        if self.min_samples > self.samples:
            raise ValueError(f"min_samples ({self.min_samples}) must be <= samples ({self.samples})")
        return self


class MonitorConfig(Params):
    """``[monitor]``: passive sampling while something else moves the robot.

    A sample is taken when the robot has been still for ``still_s`` and its
    pose differs from each of the last ``diversity_window`` samples by at
    least ``min_translation_m`` or ``min_rotation_deg``. ``[monitor.online]``
    configures the online estimator and change detector (its setup is the
    config's).
    """

    still_s: NonNegativeFloat = 0.3
    poll_s: PositiveFloat = 0.05
    min_translation_m: NonNegativeFloat = 0.03
    min_rotation_deg: NonNegativeFloat = 5.0
    diversity_window: NonNegativeInt = 10
    max_samples: NonNegativeInt = 0
    duration_s: NonNegativeFloat = 0.0
    alarm_hook: Str = ""
    reestimate_samples: Annotated[Int, Field(ge=3)] = 8
    method: NonEmptyStr = DEFAULT_METHOD
    online: OnlineConfig = Field(default_factory=OnlineConfig)


class SessionConfig(Params):
    """``[session]``: where sessions (samples, frames, result, .rrd) are written.

    ``exports`` lists the result files written into the session at the end of
    a run (formats of `app.formats.write_result`).
    """

    root: NonEmptyStr = "sessions"
    save_frames: Bool = True
    exports: list[Literal[EXPORTS]] = Field(default_factory=lambda: list(EXPORTS))


class VizConfig(Params):
    """``[viz]``: rerun logging (an ``.rrd`` beside the session; live viewer on request).

    ``viewer_bind`` is the address the live viewer listens on: loopback, so
    the recording is not served to the network, unless set otherwise.
    """

    enabled: Bool = True
    viewer: Bool = False
    viewer_bind: NonEmptyStr = "127.0.0.1"
    log_images: Bool = True


def backend_union(registry: Registry):
    """The config models of every registered backend, told apart by the registry's key field."""

    def tag(value: Any):
        if isinstance(value, dict):
            return value.get(registry.key, registry.default)
        return getattr(value, registry.key, None)

    members = tuple(Annotated[b.config, Tag(b.name)] for b in registry.backends())
    return Annotated[Union[members], Discriminator(  # noqa: UP007  a runtime-built union
        tag, custom_error_type="backend",
        custom_error_message=f"{registry.key} must be one of {registry.names()}")]


RobotConfig = backend_union(ROBOTS)
CameraConfig = backend_union(CAMERAS)
#: Location parts pydantic adds for a union member (the backend names); left out of messages.
_TAGS = frozenset(ROBOTS.names()) | frozenset(CAMERAS.names())

# The simulated cell (config/sim.toml): a UR10 simulator (mocks.ur_sim, started by the
# robot driver itself and driven through the real ur_rtde client) holding the
# flange 0.9 m in front of the base with the marker facing the rendered camera,
# whose true pose is the rendered camera's default (calib.simulate.realistic_cell).
SIM_START_Q = (0.367792, -3.559685, 1.448735, -1.704477, -0.767569, 0.521542)


def _sim_robot() -> URSimRobotConfig:
    return URSimRobotConfig(**{
                "host": "127.0.0.2",
        "model": "ur10",
        "controller": "3.15",
        "initial_q": SIM_START_Q,
        "sim_tcp_offset": [0.0, 0.0, 0.1, 0.0, 0.0, 0.0],
        "tcp_offset": [0.0, 0.0, 0.1, 0.0, 0.0, 0.0],
        "speed": 0.5,
        "acceleration": 2.0,
        "workspace_min": [0.65, -0.15, 0.25],
        "workspace_max": [1.15, 0.35, 0.75],
        "tilt_reference": [-0.2476, -0.8666, 0.4333],
        "max_tilt_deg": 45.0,
    })



class Config(Params):
    """The whole application configuration (one TOML file).

    ``setup`` is ``"eye_to_hand"`` (static camera, marker on the flange:
    ``X = T_flange_marker``, ``Y = T_base_cam``) or ``"eye_in_hand"`` (camera
    on the flange, static marker: ``X = T_flange_cam``, ``Y = T_base_marker``);
    a camera backend or the online estimator that has a setup of its own takes
    this one unless its table states the same.
    """

    setup: Setup = Setup.EYE_TO_HAND
    robot: RobotConfig = Field(default_factory=_sim_robot)
    camera: CameraConfig = Field(default_factory=RenderedCameraConfig)
    marker: TargetConfig = Field(default_factory=TargetConfig)
    calibrate: CalibrateConfig = Field(default_factory=CalibrateConfig)
    monitor: MonitorConfig = Field(default_factory=MonitorConfig)
    session: SessionConfig = Field(default_factory=SessionConfig)
    viz: VizConfig = Field(default_factory=VizConfig)

    @model_validator(mode="after")
    def _one_setup(self):
        for name, part in (("camera", self.camera), ("monitor.online", self.monitor.online)):
            if "setup" not in type(part).model_fields:
                continue
            if "setup" in part.model_fields_set and part.setup != self.setup:
                raise ValueError(f"{name}.setup ({part.setup.value!r}) must match setup ({self.setup.value!r})")
            part.setup = self.setup
        return self

    def to_dict(self) -> dict:
        """Plain-data form (for ``session.json``): the config that was actually used."""
        return self.model_dump(mode="json")


def config_from_dict(data: dict, where: str = "") -> Config:
    """Validate a parsed TOML document into a `Config`.

    Raises
    ------
    ConfigError
        Naming ``where`` (the file), the section and the field.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: config must be a table, got {type(data).__name__}".lstrip(": "))
    try:
        return Config.model_validate(data)
    except ValidationError as e:
        raise ConfigError(f"{where + ': ' if where else ''}{describe(e, skip=_TAGS)}") from None


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
    return config_from_dict(data, str(path))
