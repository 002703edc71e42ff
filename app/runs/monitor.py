"""Passive monitoring: sample while something else moves the robot, keep the camera calibrated.

Read-only: this module never commands a motion. Eye-to-hand (static camera,
``Y = T_base_cam``) it follows and re-learns a drifting or bumped camera;
eye-in-hand (``X = T_flange_cam``) a camera that slips on the flange. Every
standstill with the marker in view is a sample for the monitoring engine
(`handeye.calib.monitor`, armed from a reference calibration or, without one, from
the first samples ``auto`` can solve, or continued from a previous run); a
*moved* or *drifting* alarm is logged, recorded in the session, shown in
rerun, published (MQTT) and runs the optional hook command. The calibration
in use is kept in the session (``calibration_in_use.yaml``,
`handeye.app.calibration_in_use`) for the next run. Only samples of distinct poses
enter the bounded estimation set the first calibration and the final result
are solved from. An unexpected error at a sample ends the run with one line
and a non-zero exit (a service restarts it), once the sample, the error and
any alarm of that sample are in the session and on MQTT.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import subprocess
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from handeye.app import calibration_in_use, devices, stopping
from handeye.app.acquire import pose_at_frame, take_sample
from handeye.app.calibration_versions import Approvals, History
from handeye.app.config import Config, MonitorConfig, hook_argv
from handeye.app.consumers import CalibrationLoop, MqttConsumer, RobotProgram, Ros2Consumer
from handeye.app.errors import ConfigError, MonitorError, OutageError
from handeye.app.monitoring import arm_from, arm_from_path, sample_factor
from handeye.app.outage import OutageEvent, Reconnecting
from handeye.app.production import Bump, knock_as_left, record_knocks, start_production
from handeye.app.progress import progress_bar, say, show_monitor
from handeye.app.session import SessionWriter
from handeye.app.shift_record import ShiftRecord
from handeye.app.viz import Viz
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError
from handeye.calib.monitor import AlarmLevel, EngineState, MonitorEngine, MonitorUpdate
from handeye.calib.monitor.filter import is_sound
from handeye.calib.observation import Observation
from handeye.calib.planner import least_informative
from handeye.calib.result import CalibrationResult, worst_axis_sigma
from handeye.calib.vision.extract import MarkerMeasurement
from handeye.drivers.camera.base import Camera, RGBDFrame
from handeye.drivers.errors import DeviceError, PoseTimeError
from handeye.drivers.robot.base import Robot

log = logging.getLogger(__name__)

#: A sample is kept when the robot stood still from its standstill's start to this long after the frame's stamp
#: (s): three frames at 30 Hz, for a camera's stamp a little off the robot's clock or its exposure's length.
CAPTURE_GUARD_S = 0.1


@dataclass
class Alarm:
    """An alarm: when, at which sample, its kind (``"moved"`` or ``"drifting"``) and the engine's figures."""

    t: float
    sample_index: int
    info: dict

    @property
    def kind(self) -> str:
        return self.info.get("alarm", "moved")


@dataclass
class MonitorReport:
    """What a monitoring run saw.

    Attributes
    ----------
    session : Path
    n_samples, n_skipped : int
    alarms : list[Alarm]
    reestimate : CalibrationResult or None
        The camera re-learnt after the last *moved* alarm (None if none yet).
    elapsed_s : float
    estimate : ndarray (4, 4) or None
        The engine's live camera transform (``T_base_cam`` eye-to-hand,
        ``T_flange_cam`` eye-in-hand); None before it is armed.
    estimate_cov : ndarray (6, 6) or None
        Its covariance (`handeye.calib.result` convention).
    estimate_sigma : (float, float) or None
        Its worst-axis 1-sigma ``(rad, m)`` (`handeye.calib.result.worst_axis_sigma`).
    drift : (float, float) or None
        ``(mm, deg)`` of the live estimate against the calibration in use
        (the reference, then each re-learnt one): mm over the workspace.
    samples_until_armed : int
        Samples before the *moved* test runs (0: armed).
    kept : list[int]
        Indices of the bounded estimation set at the end.
    last : MonitorUpdate or None
        The engine's latest figures (drift rate, running verification, level).
    loop : CalibrationLoop or None
        The versions of the calibration in use and who uses which (`handeye.app.consumers`).
    record : ShiftRecord or None
        The timeline, every alarm with what became of it, the outages (`handeye.app.shift_record`: the session's
        ``alarms.yaml``, ``monitor_trace.png`` and ``report.html``, written at every alarm and at the end).
    truth : ndarray (4, 4) or None
        A simulated camera's true camera transform at the end (None for a real one).
    """

    session: Path
    n_samples: int
    n_skipped: int
    alarms: list[Alarm] = field(default_factory=list)
    reestimate: CalibrationResult | None = None
    elapsed_s: float = 0.0
    estimate: np.ndarray | None = None
    estimate_cov: np.ndarray | None = None
    estimate_sigma: tuple[float, float] | None = None
    drift: tuple[float, float] | None = None
    samples_until_armed: int = 0
    kept: list[int] = field(default_factory=list)
    last: MonitorUpdate | None = None
    truth: np.ndarray | None = None
    record: ShiftRecord | None = None
    loop: CalibrationLoop | None = None

    @property
    def last_alarm(self) -> Alarm | None:
        return self.alarms[-1] if self.alarms else None

    @property
    def moved_alarms(self) -> list[Alarm]:
        return [a for a in self.alarms if a.kind == "moved"]


def detector_state(n: int) -> str:
    """When the *moved* test runs, in words: ``"testing every sample"`` or ``"testing from N more samples"``."""
    return "testing every sample" if n == 0 else f"testing from {n} more sample{'s' if n != 1 else ''}"


def monitor(cfg: Config, *, reference: Path | None = None, stop=None, progress: bool = True,
            bump: Bump | None = None, production: bool = True, publish=None,
            knocks_from: Path | None = None) -> MonitorReport:
    """Passive monitoring with a read-only robot connection (never moves the robot).

    ``reference``: a calibration session (or its ``result.yaml``), solved
    with ``auto`` to arm the monitoring engine at once, or a previous
    monitoring run to continue from (`handeye.app.monitoring.arm_from_path`); with
    ``[monitor] carry_over`` the newest earlier run under ``session.root``
    takes its place; without either the engine arms itself from the run's
    first samples that ``auto`` can solve (`MonitorConfig.arm_samples`).

    On a simulated cell (the ``ur_sim`` robot) the simulated controller
    runs a looping production program (``production``, `handeye.app.production`) so
    that the robot moves, and ``bump`` knocks the rendered camera partway.
    ``publish``: optional ``(obs, update, report)`` callback; by default the
    ``[mqtt]`` publisher when enabled (`handeye.app.mqtt`). A simulated camera starts
    knocked as the monitoring run ``reference`` (else ``knocks_from``: a
    calibration in use, for ``verify --passive``) left it
    (`handeye.app.production.carried_knocks`).
    """
    from handeye.app.mqtt import make_publisher
    from handeye.app.ros2 import make_diagnostics

    devices.check_session_root(cfg)
    publisher = make_publisher(cfg.mqtt, cfg.setup, cfg.frames.model_dump()) if publish is None else None
    # ROS 2 (/diagnostics, ~/camera_transform; [ros2] diagnostics): beside MQTT or a given publish, gets the same.
    diagnostics = make_diagnostics(cfg.ros2, cfg.setup, cfg.frames.model_dump())
    outage_sinks = [p.outage for p in (publisher, diagnostics) if p is not None]
    stop = stop or threading.Event()
    outages = _OutageLog(publish=(lambda e: [sink(e) for sink in outage_sinks]) if outage_sinks else None)
    # A device that goes away mid-shift is an outage and a reconnect with backoff (`handeye.app.outage`), not an exit.
    with Reconnecting("robot", devices.open_robot(cfg, read_only=True), cfg.reconnect, on_event=outages,
                      stop=stop) as robot, \
            Reconnecting("camera", devices.open_camera(cfg, robot), cfg.reconnect, on_event=outages,
                         stop=stop) as camera, \
            (publisher or contextlib.nullcontext()), (diagnostics or contextlib.nullcontext()), \
            contextlib.closing(make_loop(cfg, robot, publisher, diagnostics)) as loop:
        cell = _Cell(cfg, robot, camera, devices.make_engine(cfg), np.random.default_rng(cfg.calibrate.seed),
                     publisher, diagnostics, publish or publisher, outages, loop)
        cell.start(carried_over(cfg) or reference, knocks_from, production)
        return cell.watch(stop, bump, progress)


def make_loop(cfg: Config, robot: Robot | None = None, publisher=None, diagnostics=None) -> CalibrationLoop:
    """The versions (``[monitor] apply``) and the consumers of ``[consumers]`` (`handeye.app.consumers`): the
    robot program at the address ``robot`` is connected to (default: the config's), those over MQTT through
    ``publisher`` and over ROS 2 through ``diagnostics``'s node."""
    consumers = []
    if cfg.consumers.robot_program:       # a robot with a host (`handeye.app.config.Config` checked it)
        consumers.append(RobotProgram(cfg.robot.host if robot is None else (lambda: robot.config.host)))
    if publisher is not None:
        consumers += [MqttConsumer(publisher, name) for name in cfg.consumers.mqtt]
    if diagnostics is not None:
        diagnostics.listen_approvals()
    if diagnostics is not None and cfg.consumers.ros2:
        diagnostics.listen_calibration()
        consumers += [Ros2Consumer(diagnostics, name) for name in cfg.consumers.ros2]
    return CalibrationLoop.of(History(cfg.monitor.apply), consumers, ack_timeout_s=cfg.consumers.ack_timeout_s)


@dataclass
class _Cell:
    """The parts of one `monitor` run, once its devices are open."""

    cfg: Config
    robot: Robot
    camera: Camera
    engine: MonitorEngine
    rng: np.random.Generator
    publisher: object
    diagnostics: object
    publish: Callable | None
    outages: _OutageLog
    loop: CalibrationLoop
    reference: Path | None = None
    carried: list = field(default_factory=list)

    def start(self, reference: Path | None, knocks_from: Path | None, production: bool) -> None:
        """Arm from ``reference``; knock a simulated camera as the run it continues left it; start production."""
        cfg, camera = self.cfg, self.camera
        self.reference = reference
        if reference is not None:
            say(arm_from_path(self.engine, reference, cfg.setup, self.robot.shared_error_factor, rng=self.rng,
                              t=time.time()))
        # A simulated camera starts unmoved in every process: knocked as the monitoring run left it, it is not
        # a move the engine has re-learnt, reported again.
        knocked = reference if reference is not None else knocks_from
        self.carried = knock_as_left(camera, cfg.setup, knocked)
        if self.carried:
            say(f"simulated camera: knocked as {knocked} left it ({len(self.carried)} knock"
                f"{'s' if len(self.carried) != 1 else ''})")
        if production:
            start_production(self.robot, cfg, self.rng, say=say)

    def watch(self, stop, bump: Bump | None, progress: bool) -> MonitorReport:
        """The session, the callbacks, and `run_monitor` until the run ends."""
        cfg, camera, engine, outages = self.cfg, self.camera, self.engine, self.outages
        writer = SessionWriter.create(cfg.session.root, cfg.setup, config=cfg.to_dict(),
                                      intrinsics=dataclasses.asdict(camera.intrinsics), truth=devices.truth(camera),
                                      source="handeye monitor", keep_frames=cfg.monitor.keep_frames)
        solve = devices.make_solve(cfg.calibrate.model_copy(update={"method": "auto"}), cfg.setup, self.rng,
                                   self.robot.shared_error_factor)
        for approvals in (self.publisher, self.diagnostics):
            if approvals is not None:
                approvals.session = str(writer.path)
        with writer, devices.make_viz(cfg, writer.path) as viz, progress_bar(enabled=progress) as bar:
            outages.writer, outages.viz = writer, viz
            outages.shift = ShiftRecord(cfg.setup, str(writer.path), str(self.reference or ""))
            record_knocks(writer, self.carried, time.time())
            on_sample = _Bumper(bump, camera, cfg, engine, writer, viz, bar)
            report = run_monitor(self.robot, camera, devices.make_measure(cfg), engine, solve, writer, cfg.monitor,
                                 viz, stop=stop, save_frames=cfg.session.save_frames, on_sample=on_sample,
                                 on_update=self.on_update(bar), say=say, shared_error=self.robot.shared_error_factor,
                                 frames=cfg.frames.model_dump(), on_error=self.on_error, record=outages.shift,
                                 loop=self.loop, continues=self.reference)
            outages.record_broker(self.publisher)
            report.truth = devices.camera_truth(cfg.setup, devices.truth(camera))
            return report

    def on_update(self, bar):
        def on_update(obs, update, report):
            show_monitor(bar, report)
            if self.publish is not None:
                self.publish(obs, update, report)
            if self.diagnostics is not None:
                self.diagnostics(obs, update, report)
            self.outages.record_broker(self.publisher)
        return on_update

    def on_error(self, obs, message):
        if self.publisher is not None:
            self.publisher.error(obs.index, message)


@dataclass
class _Bumper:
    """``on_sample`` of a simulated cell: counts the samples (the progress bar) and knocks the camera after
    ``bump.after`` of them."""

    bump: Bump | None
    camera: Camera
    cfg: Config
    engine: MonitorEngine
    writer: SessionWriter
    viz: Viz
    bar: object
    seen: int = 0

    def __call__(self, obs) -> None:
        self.bar.update(1)
        self.seen += 1
        bump, engine, cfg = self.bump, self.engine, self.cfg
        if bump is None or self.seen != bump.after:
            return
        bump.apply(self.camera, cfg.setup)
        # Before the moved test runs the bump is not a move to detect: arming takes it in, or the detector's first
        # samples do, and what is reported of it is a part of it.
        early = not engine.armed or engine.samples_until_tested > 0
        text = (f"simulated camera bumped by {bump.translation_mm:g} mm and {bump.rotation_deg:g} deg after sample "
                f"{obs.index}")
        if early:
            when, least = (("while the monitor was still arming", cfg.monitor.arm_samples + 3) if not engine.armed
                           else ("before the moved test ran", self.seen + engine.samples_until_tested))
            text += (f", {when}: part of the bump goes into the calibration it watches from, so what it reports of "
                     f"the move is less than the bump; bump once the moved test runs (--bump-after {least} or more, "
                     f"or --reference to arm at once)")
        say(text)
        self.writer.add_event(obs.t, "simulated_bump", sample_index=obs.index, translation_mm=bump.translation_mm,
                              rotation_deg=bump.rotation_deg, before_test=early)
        self.viz.event(obs.t, text, "WARN")


def carried_over(cfg: Config) -> Path | None:
    """With ``[monitor] carry_over``: the newest earlier run's ``calibration_in_use.yaml`` of this setup under
    ``session.root`` (`handeye.app.calibration_in_use.latest`), else None."""
    if not cfg.monitor.carry_over:
        return None
    return calibration_in_use.latest(Path(cfg.session.root), cfg.setup)


@dataclass
class _OutageLog:
    """`handeye.app.outage.OutageEvent` sink: one console line each, the session's events and rerun once they exist,
    and ``publish`` (the MQTT publisher's `handeye.app.mqtt.MqttPublisher.outage`) when there is one."""

    publish: Callable[[OutageEvent], None] | None = None
    writer: SessionWriter | None = None
    viz: Viz | None = None
    shift: ShiftRecord | None = None

    def __call__(self, event: OutageEvent) -> None:
        say(event.message())
        if self.publish is not None:
            self.publish(event)
        self.record(event)

    def record_broker(self, publisher) -> None:
        """Record the MQTT broker's own outage steps (`handeye.app.mqtt.MqttPublisher.broker_outages`, appended from its
        network thread, which has logged and published them) from this thread, which owns the session."""
        while publisher is not None and publisher.broker_outages:
            self.record(publisher.broker_outages.popleft())

    def record(self, event: OutageEvent) -> None:
        """Into the session's events and rerun, once they exist."""
        if self.writer is not None:
            self.writer.add_event(event.t, event.event, **{k: v for k, v in dataclasses.asdict(event).items()
                                                           if k not in ("t", "event")})
        if self.viz is not None:
            self.viz.event(event.t, event.message(), "WARN" if event.event != "outage_end" else "INFO")
        if self.shift is not None and event.event in ("outage_start", "outage_end"):
            self.shift.outage(event.t, event.device, event.event, event.message())


def is_diverse(T: np.ndarray, recent, min_translation_m: float, min_rotation_deg: float) -> bool:
    """True if ``T`` differs from every recent pose by >= the translation OR the rotation threshold."""
    if len(recent) == 0:
        return True
    rot, trans = tf.pose_error(np.array(recent), np.broadcast_to(T, (len(recent), 4, 4)))
    close = (trans < min_translation_m) & (np.rad2deg(rot) < min_rotation_deg)
    return not bool(close.any())


def _same_pose(T1: np.ndarray, T2: np.ndarray, *, mm: float = 1.0, deg: float = 0.2) -> bool:
    rot, trans = tf.pose_error(T1, T2)
    return bool(trans < mm * 1e-3 and rot < np.deg2rad(deg))


def left_standstill(robot: Robot, T_still: np.ndarray, frame_t: float) -> str | None:
    """Why a frame stamped ``frame_t`` and its pose may be of different places, or None.

    The robot must stand at its standstill pose ``T_still`` at the frame's stamp and still `CAPTURE_GUARD_S`
    after it (a stamp off by less than that changes nothing). Leaving afterwards, while the frame is measured,
    does not matter: on the ROS 2 cell the check of the pose after the measurement skipped 7 of 46 standstills
    of 0.6 s that this keeps."""
    try:
        still = all(_same_pose(pose_at_frame(robot, t), T_still) for t in (frame_t, frame_t + CAPTURE_GUARD_S))
    except PoseTimeError:
        return "no robot pose at the frame's time"
    return None if still else "robot moved during the capture"


#: A hook runs in line with the sampling (so its alarm or calibration is in place when it starts): one slower
#: than this is told to background its work; one slower than the timeout is stopped.
HOOK_SLOW_S, HOOK_TIMEOUT_S = 1.0, 30.0


def run_hook(command: str, env: dict, field: str = "monitor.alarm_hook") -> None:
    """Run a hook command (no shell; arguments split like a shell would). Failures are logged, not raised.

    The command was checked at config load (`handeye.app.config.hook_argv`); a failure
    here (the program removed since) is logged so the alarm itself still counts.
    ``field``: the config field that names it, for the log.
    """
    t0 = time.monotonic()
    try:
        argv = hook_argv(command, field)
        if not argv:
            return
        # Its own session: a terminal's Ctrl-C is for the monitor, not for the hook and the programs it starts.
        done = subprocess.run(argv, env={**os.environ, **env}, timeout=HOOK_TIMEOUT_S, capture_output=True,
                              text=True, start_new_session=True)
    except (OSError, subprocess.TimeoutExpired, ConfigError) as e:
        log.error("%s %r failed: %s", field, command, e)
        return
    if done.returncode != 0:
        log.error("%s %r exited %d: %s", field, command, done.returncode, done.stderr.strip()[:200])
    took = time.monotonic() - t0
    if took > HOOK_SLOW_S:
        log.warning("%s %r took %.1f s: no sample is taken while a hook runs; start long work in the background "
                    "(setsid ... &)", field, command, took)


@dataclass
class _Standstill:
    """Where the robot stands still, since when, and the pose already tried there."""

    since: float | None = None
    pose: np.ndarray | None = None
    tried: np.ndarray | None = None

    def ready(self, state, cfg: MonitorConfig) -> bool:
        """True once per standstill of ``cfg.still_s`` (a new pose, even between two reads, starts a new one)."""
        T = state.T_base_flange
        if not state.is_still or self.pose is None or not _same_pose(T, self.pose):
            self.since, self.pose = (state.t_host, T) if state.is_still else (None, None)
            return False
        if (self.tried is not None and _same_pose(T, self.tried)) or state.t_host - self.since < cfg.still_s:
            return False
        self.tried = T
        return True


def run_monitor(
    robot: Robot,
    camera: Camera,
    measure: Callable[[RGBDFrame], MarkerMeasurement],
    engine: MonitorEngine,
    solve: Callable[..., CalibrationResult],
    writer: SessionWriter,
    cfg: MonitorConfig,
    viz: Viz,
    *,
    stop: threading.Event | None = None,
    save_frames: bool = True,
    on_sample: Callable[[Observation], None] | None = None,
    on_update: Callable[[Observation, object, MonitorReport], None] | None = None,
    say: Callable[[str], None] = log.info,
    shared_error=None,
    frames: dict | None = None,
    on_error: Callable[[Observation, str], None] | None = None,
    record: ShiftRecord | None = None,
    loop: CalibrationLoop | None = None,
    continues: Path | None = None,
) -> MonitorReport:
    """Passive run until ``cfg.max_samples``, ``cfg.duration_s``, ``stop`` or Ctrl-C.

    Parameters
    ----------
    robot : Robot connected read-only (this function only reads it).
    camera : Camera
    measure : callable(RGBDFrame) -> MarkerMeasurement (raises ExtractionError to skip).
    engine : handeye.calib.monitor.MonitorEngine
        Armed (from a reference), or armed here from the first samples ``solve`` determines the camera from.
    solve : callable(observations, *, final) -> CalibrationResult
        ``auto`` (`handeye.app.devices.make_solve`), for arming without a reference.
    writer : SessionWriter
    cfg : MonitorConfig
    stop : threading.Event, optional
        Set from another thread to end the run.
    on_sample : callable, optional
        Called with each accepted sample (progress display).
    on_update : callable(obs, MonitorUpdate or None, MonitorReport), optional
        Called after each sample (live displays, the MQTT publisher).
    say : callable(str)
        Where the engine's state changes are told.
    shared_error : callable, optional
        The robot's `Robot.shared_error_factor`, for samples with joints.
    frames : dict, optional
        ``[frames]`` names for ``calibration_in_use.yaml``.
    on_error : callable(obs, message), optional
        Told of an unexpected error at a sample before the run ends with `MonitorError` (the MQTT publisher).
    record : ShiftRecord, optional
        Where the timeline, the alarms and the outages go (a new one by default); written into the session
        (``alarms.yaml``, ``monitor_trace.png``, ``report.html``) at every alarm and at the end.
    loop : CalibrationLoop, optional
        The versions of the calibration in use and its consumers (`handeye.app.consumers`; default: ``apply = "auto"``,
        no consumer); polled at every step, its events go into the session.
    continues : Path, optional
        What the engine was armed from: a monitoring run's versions go on from it (`handeye.app.calibration_in_use`).

    Raises
    ------
    MonitorError
        An unexpected error at a sample (recorded in the session first, with the sample).
    """
    t0 = time.monotonic()
    report = MonitorReport(writer.path, 0, 0, record=record or ShiftRecord(engine.reference.setup if engine.armed
                                                                         else writer.header["setup"], str(writer.path)))
    in_use = _in_use_file(writer, cfg, frames, loop, continues)
    report.loop = report.record.loop = in_use.loop
    in_use.status = report.record.status
    run = _PassiveRun(robot, camera, measure, engine, solve, writer, cfg, viz, save_frames, on_sample, on_update,
                      say, shared_error, report, in_use, on_error)
    report.samples_until_armed = _until_armed(engine, run.kept, cfg)
    say(f"monitoring engine: {_engine_state(engine, run.kept, cfg)}")
    _run_until_stopped(run, stop, t0)
    return _end_run(run, t0)


def _run_until_stopped(run: "_PassiveRun", stop: threading.Event | None, t0: float) -> None:
    """`run_monitor`'s loop: a step at a time until it should stop; a Ctrl-C, or a stop while a device is away,
    is its normal end, a device error or an outage given up on is recorded and raised."""
    report, engine, writer, viz, cfg = run.report, run.engine, run.writer, run.viz, run.cfg
    try:
        if engine.armed:      # the camera it watches, also if the run ends before its first sample
            report.estimate, report.estimate_cov = engine.camera_transform, engine.cov
            report.estimate_sigma = worst_axis_sigma(engine.cov)
        # Its calibration hook may take a while: a Ctrl-C meanwhile is the run's normal end as any other.
        run.in_use.armed(engine, time.time())
        while not _should_stop(report, cfg, stop, t0):
            run.step()
    except DeviceError as e:
        # As calibrate does: leave the reason in the session next to the samples it kept, then report it.
        writer.add_event(time.time(), "device_error", error=str(e), n_samples=report.n_samples)
        viz.event(time.time(), f"device error: {e}", "ERROR")
        raise
    except KeyboardInterrupt:
        stopping.winding_down()
        log.warning("monitor interrupted; %d samples kept in %s", report.n_samples, writer.path)
        writer.add_event(time.time(), "interrupted", n_samples=report.n_samples)
    except OutageError as e:
        if stop is None or not stop.is_set():
            writer.add_event(time.time(), "gave_up", error=str(e), n_samples=report.n_samples)
            raise
        # Stopped while waiting for a device: a normal end, every sample kept.


def _in_use_file(writer: SessionWriter, cfg: MonitorConfig, frames: dict | None, loop: CalibrationLoop | None,
                 continues: Path | None) -> calibration_in_use.InUseFile:
    """The run's ``calibration_in_use.yaml`` and its versions: the calibration hook told of each version put in
    use, the loop's events into the session, approvals read from the run's directory (and the one it continues)."""

    def new_calibration(path: Path, why: str, t: float) -> None:
        version = loop.history.in_use
        run_hook(cfg.calibration_hook, {"HANDEYE_EVENT": "calibration_in_use", "HANDEYE_REASON": why,
                                        "HANDEYE_VERSION": str(version.number if version is not None else 0),
                                        "HANDEYE_CALIBRATION": str(path.absolute()),
                                        "HANDEYE_SESSION": str(writer.path.absolute()),
                                        "HANDEYE_TIME": calibration_in_use.local_time(t)}, "monitor.calibration_hook")

    loop = loop or CalibrationLoop(History("auto"))
    loop.run, loop.approvals = writer.path, Approvals([writer.path])
    loop.on_event = lambda t, kind, fields: writer.add_event(t, kind, **fields)
    in_use = calibration_in_use.InUseFile(writer.path, frames, on_new=new_calibration, loop=loop)
    found = calibration_in_use.find(continues) if continues is not None else None
    if found is not None:
        in_use.resume(found)
    return in_use


def _end_run(run: "_PassiveRun", t0: float) -> MonitorReport:
    """The end of a run: the calibration in use, the shift record and the sample set written."""
    report, writer, engine, cfg = run.report, run.writer, run.engine, run.cfg
    report.elapsed_s = time.monotonic() - t0
    run.in_use.poll(engine, time.time())
    run.in_use.end(engine, time.time())
    report.record.write(writer.path)
    report.kept = [o.index for o in run.kept]
    writer.add_event(time.time(), "sample_set", indices=report.kept, keep_samples=cfg.keep_samples,
                     frames_pruned=writer.frames_pruned)
    return report


def _should_stop(report: MonitorReport, cfg: MonitorConfig, stop: threading.Event | None, t0: float) -> bool:
    """``stop`` set, ``cfg.duration_s`` over or ``cfg.max_samples`` taken."""
    if stop is not None and stop.is_set():
        return True
    if cfg.duration_s and time.monotonic() - t0 >= cfg.duration_s:
        return True
    return bool(cfg.max_samples and report.n_samples >= cfg.max_samples)


@dataclass
class _PassiveRun:
    """The devices and running state of `run_monitor`; `step` is one poll of the robot."""

    robot: Robot
    camera: Camera
    measure: Callable[[RGBDFrame], MarkerMeasurement]
    engine: MonitorEngine
    solve: Callable[..., CalibrationResult]
    writer: SessionWriter
    cfg: MonitorConfig
    viz: Viz
    save_frames: bool
    on_sample: Callable[[Observation], None] | None
    on_update: Callable[[Observation, object, MonitorReport], None] | None
    say: Callable[[str], None]
    shared_error: object
    report: MonitorReport
    in_use: calibration_in_use.InUseFile
    on_error: Callable[[Observation, str], None] | None = None
    #: The bounded estimation set: distinct poses since the start or the last move.
    kept: list[Observation] = field(default_factory=list)
    still: _Standstill = field(default_factory=_Standstill)

    def step(self) -> None:
        """Sample once the robot stands still at a new pose, then feed the engine (or arm it); the approvals and
        the consumers' acknowledgements are polled meanwhile."""
        self.in_use.poll(self.engine, time.time())
        state = self.robot.read()
        if not self.still.ready(state, self.cfg):
            time.sleep(self.cfg.poll_s)
            return
        T, robot = state.T_base_flange, self.robot
        obs = take_sample(robot, self.camera, self.measure, self.writer, self.viz, not_before=self.still.since,
                          save_frames=self.save_frames, check=lambda frame_t: left_standstill(robot, T, frame_t))
        if obs is None:
            self.report.n_skipped += 1
            return
        self.report.n_samples += 1
        self.viz.rotate(self.cfg.max_recording_mb * 1e6)
        if self.on_sample is not None:
            self.on_sample(obs)
        alarms, told = len(self.report.alarms), False
        try:
            self.keep(obs)
            update = self.estimate(obs)
            self.in_use.update(self.engine, update, obs.t)
            if self.on_update is not None:
                told = True
                self.on_update(obs, update, self.report)
        except (DeviceError, OutageError, MonitorError):
            raise
        except KeyboardInterrupt:
            # A Ctrl-C in the sample's alarm hook: the alarm is in the session; it goes out too before the run ends.
            if len(self.report.alarms) > alarms and not told and self.on_update is not None:
                self.on_update(obs, self.report.last, self.report)
            raise
        except Exception as e:    # noqa: BLE001 - recorded, published and ended with one line (never a lost alarm)
            self.fail(obs, e, alarms, told)

    def fail(self, obs: Observation, error: Exception, alarms: int, told: bool) -> None:
        """An unexpected error at sample ``obs``: the sample is in the session already; record the error, publish
        any alarm of this sample not published yet and the error, keep the calibration in use if the engine's
        state is sound, and end the run with `MonitorError` (one line; a service restarts it)."""
        text = f"{type(error).__name__}: {error}"
        message = (f"unexpected error at sample {obs.index} ({text}); the sample is kept in {self.writer.path}, "
                   "the run ends for the service to restart it")
        log.error("%s\n%s", message, traceback.format_exc())
        self.writer.add_event(time.time(), "engine_error", sample_index=obs.index, error=text,
                              traceback=traceback.format_exc(limit=8))
        self.viz.event(obs.t, message, "ERROR")
        if len(self.report.alarms) > alarms and not told and self.on_update is not None:
            try:
                self.on_update(obs, self.report.last, self.report)
            except Exception:      # noqa: BLE001 - the alarm is in the session and the hook ran; say so
                log.exception("sample %d: the alarm could not be published", obs.index)
        if self.on_error is not None:
            self.on_error(obs, message)
        if self.engine.armed and is_sound(self.engine.filter):
            self.in_use.write(self.engine, time.time(), "before an unexpected error")
        self.report.record.write(self.writer.path)
        raise MonitorError(message) from error

    def keep(self, obs: Observation) -> None:
        """Add a sample of a distinct pose to the bounded estimation set (its frames go with a dropped one)."""
        if is_diverse(obs.T_base_flange, [o.T_base_flange for o in self.kept], self.cfg.min_translation_m,
                      self.cfg.min_rotation_deg):
            self.kept.append(obs)
            dropped = bound_estimation_set(self.kept, self.cfg, self.engine)
            if dropped is not None:
                self.writer.drop_frames(dropped.index)  # disk budget: frames only for samples the set holds

    def estimate(self, obs: Observation) -> MonitorUpdate | None:
        """The engine's update from ``obs`` once armed; before, an attempt to arm it. Tells the detector's arming."""
        update = None
        if self.engine.armed:
            update = _update(self.engine, obs, self.shared_error, self.report, self.writer, self.viz, self.cfg,
                             self.say)
            if update is not None and update.alarm == AlarmLevel.MOVED:
                self.kept = [obs]      # the samples before it are of the old camera
        elif _arm_from_samples(self.engine, self.kept, self.solve, obs, self.shared_error, self.cfg):
            self.say(f"monitoring engine armed from {len(self.kept)} samples of distinct poses (auto)")
            self.writer.add_event(obs.t, "armed", n_samples=len(self.kept),
                                  T_camera=self.engine.camera_transform.tolist())
            self.in_use.armed(self.engine, obs.t)
        before = self.report.samples_until_armed
        self.report.samples_until_armed = _until_armed(self.engine, self.kept, self.cfg)
        if before and not self.report.samples_until_armed:
            self.say(f"change detector: testing every sample from sample {obs.index} on")
        return update


def _update(engine: MonitorEngine, obs: Observation, shared_error, report: MonitorReport, writer: SessionWriter,
            viz: Viz, cfg: MonitorConfig, say) -> MonitorUpdate | None:
    """One sample through the engine; alarms and re-learns recorded. A malformed sample is a logged skip."""
    try:
        upd = engine.update(obs.t, obs.T_base_flange, obs.point_cam, obs.point_cov,
                            sample_factor(engine, obs, shared_error))
    except CalibrationError as e:
        log.warning("sample %d not used by the monitoring engine: %s", obs.index, e)
        writer.add_skip(obs.t, f"monitoring engine: {e}", T_base_flange=obs.T_base_flange)
        return None
    report.last = upd
    report.record.add(obs.index, upd, engine)
    report.estimate, report.estimate_cov = upd.camera_transform, upd.cov
    report.estimate_sigma = worst_axis_sigma(upd.cov)
    report.drift = (upd.drift_mm, upd.drift_deg)
    viz.sample(obs, upd.camera_transform)
    viz.drift(obs.t, upd.drift_mm, upd.drift_deg)
    if upd.alarm:
        _raise_alarm(report, obs, upd, writer, viz, cfg)
    if upd.state == EngineState.RELEARNING and upd.message and not upd.alarm:
        log.info("sample %d: %s", obs.index, upd.message)
    relearnt = upd.message.startswith("re-learnt") or "; re-learnt" in upd.message
    if relearnt:
        report.reestimate = engine.result()
        writer.add_event(obs.t, "relearnt", sample_index=obs.index, T_camera=upd.camera_transform.tolist(),
                         message=upd.message)
        viz.event(obs.t, upd.message, "WARN")
        say(upd.message.split("; ")[-1])
    if upd.alarm or relearnt:
        # A plant reads alarms.yaml and the report as the alarm happens, and the alarm's outcome true when read:
        # once per sample, after both.
        report.record.write(writer.path)
    return upd


def _arm_from_samples(engine: MonitorEngine, kept, solve, obs, shared_error, cfg: MonitorConfig) -> bool:
    """Without a reference: solve the estimation set with ``auto`` every ``reestimate_samples`` new distinct
    poses from ``arm_samples`` on; arm once its 1-sigma over the workspace is within ``arm_sigma_mm``."""
    n = len(kept)
    if n < cfg.arm_samples or (n - cfg.arm_samples) % cfg.reestimate_samples or kept[-1] is not obs:
        return False
    try:
        ref = arm_from(engine, solve(kept, final=True), kept, devices.robot_shared_error("auto", kept, shared_error),
                       t=obs.t)
    except CalibrationError as e:
        log.info("not armed yet from %d samples: %s", n, e)
        return False
    if ref.sigma_mm > cfg.arm_sigma_mm:
        engine.disarm()
        log.info("not armed yet: %d samples give a 1-sigma of %.2f mm over the workspace", n, ref.sigma_mm)
        return False
    return True


def _until_armed(engine: MonitorEngine, kept, cfg: MonitorConfig) -> int:
    """Samples before the *moved* test runs: the detector's first three once armed; before, the distinct
    poses still missing for the first calibration (at least one)."""
    if engine.armed:
        return engine.samples_until_tested
    return max(cfg.arm_samples - len(kept), 1) + 3


def _engine_state(engine: MonitorEngine, kept, cfg: MonitorConfig) -> str:
    if engine.armed:
        return "armed from the reference"
    return (f"not armed: collecting samples of distinct poses for a first calibration (auto, from "
            f"{cfg.arm_samples}; a production program of a few stops cannot give one: pass --reference); "
            f"change detector: {detector_state(_until_armed(engine, kept, cfg))}")


def bound_estimation_set(kept: list[Observation], cfg: MonitorConfig, engine: MonitorEngine) -> Observation | None:
    """Hold at most ``cfg.keep_samples``: drop the least informative at the live estimate
    (`handeye.calib.planner.least_informative`), the oldest while there is no estimate yet; returns the dropped one."""
    if not cfg.keep_samples or len(kept) <= cfg.keep_samples:
        return None
    if not engine.armed:
        return kept.pop(0)
    estimate = engine.result()
    A = np.array([o.T_base_flange for o in kept])
    return kept.pop(least_informative(estimate.setup, estimate.X, estimate.Y, A, keep_recent=cfg.keep_recent))


def _raise_alarm(report: MonitorReport, obs: Observation, upd: MonitorUpdate, writer: SessionWriter, viz: Viz,
                 cfg: MonitorConfig) -> None:
    info = {"alarm": str(upd.alarm), "statistic": float(upd.statistic), "n_samples": int(upd.index),
            "drift_mm": upd.drift_mm, "drift_rate_mm_h": upd.drift_rate_mm_h,
            "hours_to_tolerance": upd.hours_to_tolerance, "message": upd.message}
    report.alarms.append(Alarm(obs.t, obs.index, info))
    if upd.alarm == AlarmLevel.MOVED and report.loop is not None:
        report.loop.last_move = {"time": calibration_in_use.local_time(obs.t), "sample": obs.index, "mm": None}
    if upd.alarm == AlarmLevel.MOVED:
        text = f"ALARM: camera moved (detected at sample {obs.index}, GLR statistic {upd.statistic:.1f})"
    else:
        text = f"ALARM: {upd.message} (sample {obs.index})"
    log.warning(text)
    writer.add_event(obs.t, "alarm", sample_index=obs.index, **info)
    viz.event(obs.t, text, "ERROR" if upd.alarm == AlarmLevel.MOVED else "WARN")
    run_hook(cfg.alarm_hook, {"HANDEYE_EVENT": "camera_moved" if upd.alarm == AlarmLevel.MOVED else "camera_drifting",
                              "HANDEYE_SESSION": str(writer.path.absolute()), "HANDEYE_SAMPLE": str(obs.index)})

