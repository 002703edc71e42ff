"""Application configuration: a TOML file in ``config/`` -> one typed `Config`, parsed and validated once.

Every table is a pydantic model (`handeye.calib.params.Params`: unknown keys rejected,
numbers finite and never booleans): ``[calibrate]``, ``[monitor]`` (with
``[monitor.engine]`` = `handeye.calib.monitor.MonitorSettings`), ``[session]``, ``[viz]``,
``[frames]``, ``[mqtt]`` (`handeye.app.mqtt.MqttConfig`), ``[ros2]`` (`handeye.app.ros2.Ros2Config`), ``[production]`` (the simulated robot's program), ``[console]``,
``[reconnect]`` (`handeye.app.outage.ReconnectConfig`),
``[marker]`` = `handeye.calib.vision.extract.TargetConfig`, and ``[robot]`` /
``[camera]``, a union over the registered backends selected by ``type`` /
``backend`` (`handeye.drivers.robot.registry.ROBOTS`, `handeye.drivers.camera.registry.CAMERAS`;
every backend is registered by `handeye.app.backends`). A bad field is a `ConfigError`
naming the file and ``section.field``.

The models are the one source of defaults: ``Config()`` is the simulated cell
(a UR10 simulator driven through the real ur_rtde client, the rendered camera),
which ``handeye demo`` runs without a file; ``config/sim.toml`` spells the same
cell out for illustration, and a test keeps the two identical.
"""

from __future__ import annotations

import shlex
import shutil
import sys
from pathlib import Path
from typing import Annotated, Any, Literal, Union

if sys.version_info >= (3, 11):
    import tomllib
else:       # Python 3.10 (ROS 2 Humble): the same parser, before it joined the standard library
    import tomli as tomllib

from pydantic import AfterValidator, Discriminator, Field, Tag, ValidationError, model_validator

from handeye.app import backends  # noqa: F401  every backend registers itself before the unions are built
from handeye.app.errors import ConfigError
from handeye.app.mqtt import MqttConfig
from handeye.app.outage import ReconnectConfig
from handeye.app.ros2 import Ros2Config
from handeye.app.files import read_text_file
from handeye.calib.monitor import MonitorSettings
from handeye.calib.params import (
    Bool,
    Int,
    NonEmptyStr,
    NonNegativeFloat,
    NonNegativeInt,
    Params,
    PositiveFloat,
    PositiveInt,
    Str,
    Vector3,
    Vector6,
    describe,
)
from handeye.calib.setup import Setup
from handeye.calib.vision.extract import TargetConfig
from handeye.drivers.camera.registry import CAMERAS
from handeye.drivers.registry import Registry
from handeye.drivers.robot.registry import ROBOTS
from handeye.mocks.render.camera import RenderedCameraConfig
from handeye.mocks.ur_sim.robot import URSimRobotConfig

# Solver names as in the paper (or "auto", handeye.calib.auto), checked against handeye.calib.api at load.
DEFAULT_METHOD = "auto"
# Result formats of handeye.app.formats.write_result (kept literal: config must load without the exporters).
EXPORTS = ("yaml", "json", "easy_handeye", "easy_handeye2", "urdf", "ros2_launch")


def _method(name: str) -> str:
    """A solver name `handeye.calib.api.solve` knows (its canonical spelling), so a typo fails at load, before any motion."""
    from handeye.calib.api import AUTO, resolve_method
    from handeye.calib.errors import CalibrationError

    if name.strip().lower() == AUTO:
        return AUTO
    try:
        return resolve_method(name).name
    except CalibrationError as e:
        raise ValueError(str(e)) from None


def hook_argv(command: str, field: str = "monitor.alarm_hook") -> list[str]:
    """A hook command's argument list (split like a shell, run without one); [] for no hook.

    Raises
    ------
    ConfigError
        Naming ``field``: unbalanced quotes, or a program that is neither on
        ``PATH`` nor an executable file.
    """
    if not command.strip():
        return []
    try:
        argv = shlex.split(command)
    except ValueError as e:
        raise ConfigError(f"{field}: cannot split {command!r} into arguments ({e})") from None
    if not argv:
        return []
    if shutil.which(argv[0]) is None:
        raise ConfigError(f"{field}: program {argv[0]!r} not found on PATH or not executable")
    return argv


def _hook(command: str) -> str:
    try:
        hook_argv(command, "")
    except ConfigError as e:
        raise ValueError(str(e).removeprefix(": ")) from None
    return command


def _box(box):
    if not all(lo < hi for lo, hi in zip(*box)):
        raise ValueError(f"must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] (m) with min < max, got {box!r}")
    return box


def _range(r):
    if not r[0] < r[1]:
        raise ValueError(f"must be [min, max] with min < max, got {list(r)}")
    return r


Method = Annotated[NonEmptyStr, AfterValidator(_method)]


class CalibrateConfig(Params):
    """``[calibrate]``: the active run (robot moves through planned, random or listed poses).

    Poses lie around the start pose: each axis offset within
    ``+-translation_range_m``, a rotation about an axis through the flange by
    up to ``tilt_deg``. ``poses``: ``"optimal"`` (`handeye.calib.planner`: a small
    model-free bootstrap, then the pose that teaches the estimator most about
    the camera per second of motion), ``"random"`` (uniform), or a file
    (``plan.json`` from ``handeye plan``). The run stops at ``samples`` or as
    soon as the predicted 1-sigma of the camera transform falls below both
    targets (after ``min_samples``; a target of 0 disables the stop).

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
    motion is worth. ``max_missed_frames``: the run gives up after this many
    consecutive frames without a marker measurement, saying what the camera saw.

    ``tolerance_mm`` / ``tolerance_deg``: the error the cell accepts; the result's verdict
    (`handeye.calib.verdict.judge`) compares its predicted error over the workspace with them, as
    ``[verify]``'s judge a verification.
    """

    samples: Annotated[Int, Field(ge=3)] = 30
    min_samples: Annotated[Int, Field(ge=3)] = 8
    target_sigma_mm: NonNegativeFloat = 1.0
    target_sigma_deg: NonNegativeFloat = 0.1
    tolerance_mm: PositiveFloat = 2.0
    tolerance_deg: PositiveFloat = 1.0
    poses: NonEmptyStr = "optimal"
    translation_range_m: Annotated[PositiveFloat, Field(le=1.0)] = 0.25
    tilt_deg: Annotated[PositiveFloat, Field(le=90.0)] = 40.0
    settle_s: NonNegativeFloat = 0.1
    max_attempts: PositiveInt = 200
    image_margin_px: NonNegativeInt = 40
    max_missed_frames: PositiveInt = 10
    depth_range_m: Annotated[tuple[NonNegativeFloat, NonNegativeFloat], AfterValidator(_range)] = (0.4, 2.0)
    max_view_angle_deg: Annotated[PositiveFloat, Field(lt=90.0)] = 60.0
    keep_out: list[Annotated[tuple[Vector3, Vector3], AfterValidator(_box)]] = Field(default_factory=list)
    clearance_m: NonNegativeFloat = 0.05
    lever_max_m: NonNegativeFloat = 0.1
    travel_weight: NonNegativeFloat = 0.05
    method: Method = DEFAULT_METHOD
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

    A sample is taken at every standstill of ``still_s`` with the marker in
    view (a stop the program returns to is tested again: the best test there
    is of a moved camera). Only a sample whose pose differs from every one
    held by at least ``min_translation_m`` or ``min_rotation_deg`` enters the
    estimation set (since the start or the last move), which holds at most
    ``keep_samples`` (0 = unbounded): beyond it, the sample whose loss costs
    the estimate the least information goes, never one of the
    ``keep_recent`` newest (`handeye.calib.planner.least_informative`,
    docs/planning.md). Without ``--reference`` the monitoring engine is armed
    from that set once it holds ``arm_samples`` and ``auto`` gives a 1-sigma
    over the workspace within ``arm_sigma_mm`` (tried every
    ``reestimate_samples`` new poses). ``carry_over``: a run continues from
    the calibration in use at the end of the newest earlier run of the same
    setup under ``session.root`` (its ``calibration_in_use.yaml``), a
    restarted service and the next shift alike; ``--reference`` then serves
    only the first run. ``alarm_hook`` (run on an alarm) and
    ``calibration_hook`` (run when the calibration in use changes: armed,
    re-learnt, settled after a re-learn) are split like a shell line and
    must name a program on ``PATH``. ``apply``: what happens to a re-learnt
    calibration once it has settled (`handeye.app.calibration_versions`):
    ``"approve"`` (the default) keeps the version in use until a person
    approves the new one (``handeye approve <run>``), ``"auto"`` puts it in
    use at once; docs/monitor-service.md says why approve is the default. ``[monitor.engine]`` configures
    the engine (`handeye.calib.monitor.MonitorSettings`: random-walk rates,
    ``tolerance_mm``, the drifting horizon, the detector).

    Disk budget: frames (PNG) are kept only for samples the bounded set
    still holds, and for at most the last ``keep_frames`` samples and skips
    (default 100, the change detector's long window); the rerun recording is
    rotated at ``max_recording_mb`` (the current file and one previous,
    ``recording.old.rrd``, are kept).
    """

    still_s: NonNegativeFloat = 0.3
    poll_s: PositiveFloat = 0.05
    min_translation_m: NonNegativeFloat = 0.03
    min_rotation_deg: NonNegativeFloat = 5.0
    max_samples: NonNegativeInt = 0
    duration_s: NonNegativeFloat = 0.0
    alarm_hook: Annotated[Str, AfterValidator(_hook)] = ""
    calibration_hook: Annotated[Str, AfterValidator(_hook)] = ""
    reestimate_samples: Annotated[Int, Field(ge=1)] = 8
    keep_samples: NonNegativeInt = 300
    keep_recent: NonNegativeInt = 50
    arm_samples: Annotated[Int, Field(ge=6)] = 12
    arm_sigma_mm: PositiveFloat = 3.0
    keep_frames: NonNegativeInt = 100
    max_recording_mb: PositiveFloat = 200.0
    carry_over: Bool = False
    apply: Literal["approve", "auto"] = "approve"
    engine: MonitorSettings = Field(default_factory=MonitorSettings)

    @model_validator(mode="after")
    def _keep(self):
        if self.keep_samples and self.keep_recent >= self.keep_samples:
            raise ValueError(f"keep_recent ({self.keep_recent}) must be below keep_samples ({self.keep_samples})")
        if self.keep_samples and self.arm_samples > self.keep_samples:
            raise ValueError(f"arm_samples ({self.arm_samples}) must not exceed keep_samples ({self.keep_samples})")
        return self


class ProductionWaypoint(Params):
    """One stop of an explicit ``[production]`` program: joints ``q`` (rad) or a flange ``pose``, not both.

    ``pose`` is ``T_base_flange`` as a UR pose ``[x, y, z, rx, ry, rz]`` (m, rad; the flange, not the TCP),
    reached by the inverse kinematics nearest to the previous stop. ``pause_s``: how long the tool works
    there (None: the table's ``pause_s``); ``tool``: the job's name, logged by the simulator.
    """

    q: Vector6 | None = None
    pose: Vector6 | None = None
    pause_s: NonNegativeFloat | None = None
    tool: Str = ""

    @model_validator(mode="after")
    def _one_target(self):
        if (self.q is None) == (self.pose is None):
            raise ValueError("give the stop's joints q (rad) or its flange pose (UR pose, m / rad), exactly one")
        return self


class ProductionConfig(Params):
    """``[production]``: the looping program a *simulated* robot runs while ``monitor`` watches (a real
    robot runs its own; `handeye.app.production.start_production` then does nothing).

    Either explicit ``waypoints`` (2 or more), or a ``preset``:

    - ``"random"`` (the default, also when the table is absent): ``stops`` (14) random poses around the
      start pose, drawn like the active calibration's (``[calibrate] translation_range_m``, tilt up to
      ``max_tilt_deg``, default ``min(calibrate.tilt_deg, 30)``);
    - ``"pick_and_place"``: ``stops`` (4) tool stops evenly spaced on a horizontal circle of
      ``radius_m`` (default ``min(0.15, calibrate.translation_range_m)``) around the start flange
      position, each tilted by at most ``max_tilt_deg`` (default 10) from the start orientation. The
      program returns to the same few stops forever, as a real cell's does.

    ``pause_s`` is the tool stop at each waypoint (s); ``speed`` (rad/s) and ``acceleration`` (rad/s^2)
    those of the leading joint; ``seed`` the seed of the preset's poses (None: the run's generator).
    """

    preset: Literal["random", "pick_and_place"] = "random"
    waypoints: list[ProductionWaypoint] = Field(default_factory=list)
    stops: Annotated[Int, Field(ge=2)] | None = None
    max_tilt_deg: Annotated[PositiveFloat, Field(le=90.0)] | None = None
    radius_m: Annotated[PositiveFloat, Field(le=1.0)] | None = None
    pause_s: NonNegativeFloat = 0.6
    speed: PositiveFloat = 2.0
    acceleration: PositiveFloat = 8.0
    seed: NonNegativeInt | None = None

    @model_validator(mode="after")
    def _waypoints_or_preset(self):
        if self.waypoints:
            given = sorted({"preset", "stops", "max_tilt_deg", "radius_m"} & self.model_fields_set)
            if given:
                raise ValueError(f"waypoints and {', '.join(given)} exclude each other: give waypoints or a preset")
            if len(self.waypoints) < 2:
                raise ValueError("waypoints: a program needs at least 2 stops to move between")
        return self


class ConsumersConfig(Params):
    """``[consumers]``: what is given the calibration in use and reports the version it has taken
    (`handeye.app.consumers`). ``robot_program``: the UR program over RTDE registers (a ``ur`` or ``ur_sim`` robot;
    the URScript snippet in docs/monitor-service.md). ``mqtt``: the names of the consumers that take it from
    ``<prefix>/calibration`` and acknowledge on ``<prefix>/calibration/ack`` (needs ``[mqtt] enabled``);
    ``ros2``: those that take it from ``/handeye/calibration`` and acknowledge on ``/handeye/calibration_ack``
    (needs ``[ros2] diagnostics``). A
    consumer that has not reported the version in use
    ``ack_timeout_s`` after it was given is a warning with its name."""

    robot_program: Bool = False
    mqtt: list[NonEmptyStr] = Field(default_factory=list)
    ros2: list[NonEmptyStr] = Field(default_factory=list)
    ack_timeout_s: PositiveFloat = 60.0


class ConsoleConfig(Params):
    """``[console]``: how a run shows its progress (`handeye.app.progress`).

    ``progress``: ``"auto"`` draws a progress bar on a terminal and prints plain lines off one (a
    service's journal, CI, a pipe); ``"bar"`` or ``"lines"`` force one. ``status_every``: in line mode, a
    status line (count, detector state, 1-sigma, drift, alarms) every this many samples; every event
    (an alarm, the detector armed, a reconnect) is a line of its own.
    """

    progress: Literal["auto", "bar", "lines"] = "auto"
    status_every: PositiveInt = 20
class VerifyConfig(Params):
    """``[verify]``: ``handeye verify`` (`handeye.app.verify`).

    A result passes when its error in the base frame, the measurement noise
    removed (`handeye.calib.verify`), is within ``tolerance_mm`` and, where the marker
    orientation is measured, ``tolerance_deg``. The active mode moves to
    ``poses`` fresh planned poses spread over the ``[calibrate]`` region, each at
    least ``min_separation_m`` from every calibration pose, each measured as the
    mean of ``frames_per_pose`` frames.
    """

    tolerance_mm: PositiveFloat = 2.0
    tolerance_deg: PositiveFloat = 1.0
    poses: Annotated[PositiveInt, Field(ge=3, le=200)] = 12
    min_separation_m: NonNegativeFloat = 0.03
    frames_per_pose: Annotated[PositiveInt, Field(le=20)] = 3
    seed: NonNegativeInt = 1


class ReportConfig(Params):
    """``[report]``: who and where, as ``report.html`` names them (`handeye.app.report`): the ``site`` (plant),
    the robot ``cell`` and the ``operator`` who ran the calibration (CLI: ``--site``, ``--cell``,
    ``--operator``)."""

    site: Str = ""
    cell: Str = ""
    operator: Str = ""


class SessionConfig(Params):
    """``[session]``: where sessions (samples, frames, result, .rrd) are written.

    ``exports`` lists the result files written into the session at the end of
    a run (formats of `handeye.app.formats.write_result`).
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


def _frame_name(name: str) -> str:
    if any(c.isspace() for c in name):
        raise ValueError(f"a frame name has no spaces, got {name!r}")
    return name


FrameName = Annotated[NonEmptyStr, AfterValidator(_frame_name)]


class FramesConfig(Params):
    """``[frames]``: the frame names every export uses (result files, ROS launch/URDF, MQTT).

    ``camera`` is the camera's OPTICAL frame: z forward (the viewing direction),
    x right, y down in the image (ROS REP 103's ``*_optical_frame``), not a ROS
    ``camera_link``; ``flange`` is the flange or tool frame the marker (eye-to-hand)
    or the camera (eye-in-hand) is mounted on, e.g. ``tool0``.
    """

    base: FrameName = "base"
    flange: FrameName = "flange"
    camera: FrameName = "camera"
    marker: FrameName = "marker"


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

# The simulated cell (config/sim.toml): a UR10 simulator (handeye.mocks.ur_sim, started by the
# robot driver itself and driven through the real ur_rtde client) holding the
# flange 0.9 m in front of the base with the marker facing the rendered camera,
# whose true pose is the rendered camera's default (handeye.calib.simulate.realistic_cell).
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
    a camera backend that has a setup of its own takes this one unless its
    table states the same.
    """

    setup: Setup = Setup.EYE_TO_HAND
    robot: RobotConfig = Field(default_factory=_sim_robot)
    camera: CameraConfig = Field(default_factory=RenderedCameraConfig)
    marker: TargetConfig = Field(default_factory=TargetConfig)
    calibrate: CalibrateConfig = Field(default_factory=CalibrateConfig)
    monitor: MonitorConfig = Field(default_factory=MonitorConfig)
    session: SessionConfig = Field(default_factory=SessionConfig)
    verify: VerifyConfig = Field(default_factory=VerifyConfig)
    report: ReportConfig = Field(default_factory=ReportConfig)
    viz: VizConfig = Field(default_factory=VizConfig)
    frames: FramesConfig = Field(default_factory=FramesConfig)
    mqtt: MqttConfig = Field(default_factory=MqttConfig)
    ros2: Ros2Config = Field(default_factory=Ros2Config)
    production: ProductionConfig = Field(default_factory=ProductionConfig)
    console: ConsoleConfig = Field(default_factory=ConsoleConfig)
    consumers: ConsumersConfig = Field(default_factory=ConsumersConfig)
    reconnect: ReconnectConfig = Field(default_factory=ReconnectConfig)

    @model_validator(mode="after")
    def _one_setup(self):
        for name, part in (("camera", self.camera),):
            if "setup" not in type(part).model_fields:
                continue
            if "setup" in part.model_fields_set and part.setup != self.setup:
                raise ValueError(f"{name}.setup ({part.setup.value!r}) must match setup ({self.setup.value!r})")
            part.setup = self.setup
        if self.consumers.ros2 and not self.ros2.diagnostics:
            raise ValueError("consumers.ros2: the ROS 2 consumers need [ros2] diagnostics = true (its node)")
        if self.consumers.mqtt and not self.mqtt.enabled:
            raise ValueError("consumers.mqtt: the MQTT consumers need [mqtt] enabled = true")
        if self.consumers.robot_program and getattr(self.robot, "host", None) is None:
            raise ValueError(f"consumers.robot_program: the robot program takes the calibration over RTDE, and "
                             f"robot.type {self.robot.type!r} has no host: use a ur robot, or robot_program = false")
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
        raise ConfigError(f"{where + ': ' if where else ''}{describe(e, skip=_TAGS, model=Config)}") from None


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


#: The configs the package ships (``config/`` of the repository, ``handeye/config/`` of an installed wheel).
SHIPPED_CONFIGS = Path(__file__).resolve().parents[1] / "config"


def shipped_config(path: Path) -> Path:
    """``path`` as given; a shipped config named the way the docs do (``config/sim.toml``) or by its file name
    that is not found from the current directory comes from the installed package."""
    if path.exists() or path.parent not in (Path("config"), Path(".")):
        return path
    shipped = SHIPPED_CONFIGS / path.name
    return shipped if shipped.is_file() else path


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
    path = shipped_config(Path(path))
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
    return config_from_dict(data, str(path))
