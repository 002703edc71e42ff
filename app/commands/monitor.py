"""``handeye monitor``: sample while something else moves the robot, watch for a moved camera.

Read-only: this module never commands a motion. Eye-to-hand (static camera,
``Y = T_base_cam``) it detects a bumped camera; eye-in-hand (``X =
T_flange_cam``) a camera that slipped on the flange. Each accepted sample
feeds the online estimator and change detector (``calib.online``); on an
alarm the run logs it, records an event in the session, shows it in rerun,
runs the optional hook command, and re-estimates from the samples taken after
the move once there are enough.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import os
import subprocess
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from app import devices
from app.acquire import take_sample
from app.commands.common import add_run_options, load_config_args, pose_line
from app.config import Config, MonitorConfig, hook_argv
from app.errors import ConfigError, SessionError
from app.production import Bump, start_production
from app.progress import progress_bar, say, show_monitor
from app.session import SessionWriter, read_session
from app.viz import Viz
from calib import transforms as tf
from calib.planner import least_informative
from calib.errors import CalibrationError
from calib.observation import Observation
from calib.result import CalibrationResult
from calib.setup import Setup
from calib.vision.extract import MarkerMeasurement
from drivers.camera.base import Camera, RGBDFrame
from drivers.errors import DeviceError
from drivers.robot.base import Robot

log = logging.getLogger(__name__)

NAME = "monitor"
HELP = "passive: sample while the robot works, alarm when the camera moved"
EXIT_ALARM = 3


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_run_options(p)
    p.add_argument("--reference", type=Path, help="session whose samples give the reference calibration")
    p.add_argument("--duration", type=float, help="seconds to run (overrides monitor.duration_s)")
    p.add_argument("--max-samples", type=int, help="stop after this many samples")
    p.add_argument("--hook", help="command to run on an alarm (overrides monitor.alarm_hook)")


def run(args) -> int:
    cfg = load_config_args(args)
    report = monitor(cfg, reference=args.reference)
    print_monitor_summary(report, cfg.setup)
    return EXIT_ALARM if report.alarms else 0


@dataclass
class Alarm:
    """A detected camera move: when, after which sample, and the detector's figures."""

    t: float
    sample_index: int
    info: dict


@dataclass
class MonitorReport:
    """What a monitoring run saw.

    Attributes
    ----------
    session : Path
    n_samples, n_skipped : int
    alarms : list[Alarm]
    reestimate : CalibrationResult or None
        Solved from the samples after the last alarm (None if too few).
    elapsed_s : float
    estimate : ndarray (4, 4) or None
        The online estimator's latest camera transform (``T_base_cam``
        eye-to-hand, ``T_flange_cam`` eye-in-hand).
    estimate_cov : ndarray (6, 6) or None
        Its covariance (`calib.result` convention).
    estimate_sigma : (float, float) or None
        Its worst-axis 1-sigma ``(rad, m)`` (`CalibrationResult.sigma`).
    drift : (float, float) or None
        ``(mm, deg)`` of the latest estimate against the reference (the
        reference session's estimate, else the first online estimate since
        the start or the last alarm).
    samples_until_armed : int
        Change detector state at the end (0: armed).
    kept : list[int]
        Indices of the samples held at the end (since the start or the last
        alarm, bounded by ``keep_samples``, chosen by information).
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

    @property
    def last_alarm(self) -> Alarm | None:
        return self.alarms[-1] if self.alarms else None


def detector_state(n: int) -> str:
    """``"armed"`` or ``"armed after N more samples"`` (from `OnlineCalibrator.samples_until_armed`)."""
    return "armed" if n == 0 else f"armed after {n} more sample{'s' if n != 1 else ''}"


def monitor(cfg: Config, *, reference: Path | None = None, stop=None, progress: bool = True,
            bump: Bump | None = None, production: bool = True, publish=None) -> MonitorReport:
    """Passive monitoring with a read-only robot connection (never moves the robot).

    ``reference``: a previous session (same setup) whose samples are solved
    in one batch to arm the change detector at once (estimate and
    covariance, `calib.online.OnlineCalibrator.arm`), so detection starts with
    the first new sample and the drift is measured against it.

    On a simulated cell (the ``ur_sim`` robot) the simulated controller
    runs a looping production program (``production``, `app.production`) so
    that the robot moves, and ``bump`` knocks the rendered camera partway.
    ``publish``: optional ``(obs, update, report)`` callback; by default the
    ``[mqtt]`` publisher when enabled (`app.mqtt`).
    """
    from app.mqtt import make_publisher

    rng = np.random.default_rng(cfg.calibrate.seed)
    online = devices.make_online(cfg)
    T_reference = None
    if reference is not None:
        ref = read_session(reference)
        if ref.setup != cfg.setup:
            raise SessionError(f"reference session {reference} is {ref.setup}, the config is {cfg.setup}")
        usable = [o for o in ref.observations if o.point_cam is not None]
        covs = None if any(o.point_cov is None for o in usable) else np.array([o.point_cov for o in usable])
        try:
            online.arm(np.array([o.T_base_flange for o in usable]).reshape(-1, 4, 4),
                       np.array([o.point_cam for o in usable]).reshape(-1, 3), covs)
        except CalibrationError as e:
            raise SessionError(f"reference session {reference}: cannot arm the change detector: {e}") from None
        T_reference = online.camera_transform
        say(f"reference {reference}: {len(usable)} samples, change detector armed from its estimate and covariance")
    devices.check_session_root(cfg)
    publisher = make_publisher(cfg.mqtt, cfg.setup, cfg.frames.model_dump()) if publish is None else None
    with devices.open_robot(cfg, read_only=True) as robot, devices.open_camera(cfg, robot) as camera, \
            (publisher or contextlib.nullcontext()):
        publish = publish or publisher
        if production:
            start_production(robot, cfg, rng, say=say)
        writer = SessionWriter.create(cfg.session.root, cfg.setup, config=cfg.to_dict(),
                                      intrinsics=dataclasses.asdict(camera.intrinsics), truth=devices.truth(camera),
                                      source="handeye monitor", keep_frames=cfg.monitor.keep_frames)
        solve = devices.make_solve(cfg.calibrate.model_copy(update={"method": cfg.monitor.method}), cfg.setup, rng,
                                   robot.shared_error_factor)
        with writer, devices.make_viz(cfg, writer.path) as viz, progress_bar(enabled=progress) as bar:
            seen = []

            def on_sample(obs):
                bar.update(1)
                seen.append(obs.index)
                if bump is not None and len(seen) == bump.after:
                    bump.apply(camera, cfg.setup)
                    text = (f"simulated camera bumped by {bump.translation_mm:g} mm and {bump.rotation_deg:g} deg "
                            f"after sample {obs.index}")
                    say(text)
                    writer.add_event(obs.t, "simulated_bump", sample_index=obs.index,
                                     translation_mm=bump.translation_mm, rotation_deg=bump.rotation_deg)
                    viz.event(obs.t, text, "WARN")

            def on_update(obs, update, report):
                show_monitor(bar, report)
                if publish is not None:
                    publish(obs, update, report)

            return run_monitor(robot, camera, devices.make_measure(cfg), online, solve, writer, cfg.monitor,
                               viz, stop=stop, save_frames=cfg.session.save_frames,
                               on_sample=on_sample, on_update=on_update, reference=T_reference, say=say)


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


def run_hook(command: str, env: dict) -> None:
    """Run the alarm hook (no shell; arguments split like a shell would). Failures are logged, not raised.

    The command was checked at config load (`app.config.hook_argv`); a failure
    here (the program removed since) is logged so the alarm itself still counts.
    """
    try:
        argv = hook_argv(command)
        if not argv:
            return
        done = subprocess.run(argv, env={**os.environ, **env}, timeout=30, capture_output=True, text=True)
    except (OSError, subprocess.TimeoutExpired, ConfigError) as e:
        log.error("alarm hook %r failed: %s", command, e)
        return
    if done.returncode != 0:
        log.error("alarm hook %r exited %d: %s", command, done.returncode, done.stderr.strip()[:200])


def run_monitor(
    robot: Robot,
    camera: Camera,
    measure: Callable[[RGBDFrame], MarkerMeasurement],
    online,
    solve: Callable[..., CalibrationResult],
    writer: SessionWriter,
    cfg: MonitorConfig,
    viz: Viz,
    *,
    stop: threading.Event | None = None,
    save_frames: bool = True,
    on_sample: Callable[[Observation], None] | None = None,
    on_update: Callable[[Observation, object, MonitorReport], None] | None = None,
    reference: np.ndarray | None = None,
    say: Callable[[str], None] = log.info,
) -> MonitorReport:
    """Passive run until ``cfg.max_samples``, ``cfg.duration_s``, ``stop`` or Ctrl-C.

    Parameters
    ----------
    robot : Robot connected read-only (this function only reads it).
    camera : Camera
    measure : callable(RGBDFrame) -> MarkerMeasurement (raises ExtractionError to skip).
    online : calib.online.OnlineCalibrator
        ``update(T_base_flange, point_cam, point_cov) -> OnlineUpdate`` (estimate, cov, alarm).
    solve : callable(observations, *, final) -> CalibrationResult, for the re-estimate.
    writer : SessionWriter
    cfg : MonitorConfig
    stop : threading.Event, optional
        Set from another thread to end the run.
    on_sample : callable, optional
        Called with each accepted sample (progress display).
    on_update : callable(obs, OnlineUpdate, MonitorReport), optional
        Called after each sample was fused (and an alarm handled): live
        displays and publishers (MQTT) read the estimate, drift and alarms there.
    reference : ndarray (4, 4), optional
        Camera transform the drift is measured against (the reference
        session's); default: the first online estimate.
    say : callable(str)
        Where the change detector's state changes are told ("armed", "armed
        after N more samples").
    """
    t0 = time.monotonic()
    report = MonitorReport(writer.path, 0, 0)
    recent: deque = deque(maxlen=max(cfg.diversity_window, 1))
    kept: list[Observation] = []  # since the start or the last alarm; bounded by information
    n_after_alarm = 0
    still_since: float | None = None
    still_pose: np.ndarray | None = None
    tried_pose: np.ndarray | None = None
    report.samples_until_armed = online.samples_until_armed
    say(f"change detector: {detector_state(report.samples_until_armed)}")
    try:
        while True:
            if stop is not None and stop.is_set():
                break
            if cfg.duration_s and time.monotonic() - t0 >= cfg.duration_s:
                break
            if cfg.max_samples and report.n_samples >= cfg.max_samples:
                break
            state = robot.read()
            T = state.T_base_flange
            # A standstill is a pose held with zero joint speed; a new pose (even one reached
            # between two reads) starts a new standstill.
            if not state.is_still or still_pose is None or not _same_pose(T, still_pose):
                still_since, still_pose = (state.t_host, T) if state.is_still else (None, None)
                time.sleep(cfg.poll_s)
                continue
            # One attempt per standstill: the view cannot change until the robot moves.
            if (tried_pose is not None and _same_pose(T, tried_pose)) or state.t_host - still_since < cfg.still_s:
                time.sleep(cfg.poll_s)
                continue
            tried_pose = T
            if cfg.diversity_window and not is_diverse(T, recent, cfg.min_translation_m, cfg.min_rotation_deg):
                writer.add_skip(state.t_host, "near-duplicate of a recent pose", T_base_flange=T)
                report.n_skipped += 1
                continue
            # The robot may leave during the exposure: frame and interpolated pose could then disagree.
            obs = take_sample(robot, camera, measure, writer, viz, not_before=still_since, save_frames=save_frames,
                              check=lambda T=T: None if _same_pose(robot.read().T_base_flange, T)
                              else "robot moved during the capture")
            if obs is None:
                report.n_skipped += 1
                continue
            recent.append(obs.T_base_flange)
            report.n_samples += 1
            viz.rotate(cfg.max_recording_mb * 1e6)
            if on_sample is not None:
                on_sample(obs)
            update = online.update(obs.T_base_flange, obs.point_cam, obs.point_cov)
            kept.append(obs)
            dropped = _bound(kept, cfg, online)
            if dropped is not None:
                writer.drop_frames(dropped.index)  # disk budget: frames only for samples the estimate holds
            viz.sample(obs, update.camera_transform)
            if update.camera_transform is not None:
                if reference is None:
                    reference = update.camera_transform
                rot, trans = tf.pose_error(update.camera_transform, reference)
                report.estimate, report.estimate_cov = update.camera_transform, update.cov
                current = online.result()  # None right after an alarm reset the estimator
                if current is not None:
                    report.estimate_sigma = current.sigma
                report.drift = (float(trans) * 1e3, float(np.rad2deg(rot)))
                viz.drift(obs.t, *report.drift)
            armed_before, report.samples_until_armed = report.samples_until_armed, online.samples_until_armed
            if update.alarm:
                _raise_alarm(report, obs, update, writer, viz, cfg)
                # The reference stays: the drift of the re-learnt camera against it is how far it moved.
                kept, n_after_alarm = [], 0
                say(f"change detector: re-{detector_state(report.samples_until_armed)} "
                    "(learning the moved camera from new samples)")
            elif armed_before and not report.samples_until_armed:
                say(f"change detector: armed (sample {obs.index})")
            if on_update is not None:
                on_update(obs, update, report)
            if update.alarm:
                continue
            if report.alarms:
                n_after_alarm += 1
                # Re-solve every reestimate_samples new samples: cheap, and improves as they accrue.
                if n_after_alarm % cfg.reestimate_samples == 0:
                    report.reestimate = _reestimate(kept, solve, writer, viz) or report.reestimate
    except DeviceError as e:
        # As calibrate does: leave the reason in the session next to the samples it kept, then report it.
        writer.add_event(time.time(), "device_error", error=str(e), n_samples=report.n_samples)
        viz.event(time.time(), f"device error: {e}", "ERROR")
        raise
    except KeyboardInterrupt:
        log.warning("monitor interrupted; %d samples kept in %s", report.n_samples, writer.path)
        writer.add_event(time.time(), "interrupted", n_samples=report.n_samples)
    report.elapsed_s = time.monotonic() - t0
    report.kept = [o.index for o in kept]
    writer.add_event(time.time(), "sample_set", indices=report.kept, keep_samples=cfg.keep_samples,
                     frames_pruned=writer.frames_pruned)
    return report


def _bound(kept: list[Observation], cfg: MonitorConfig, online) -> Observation | None:
    """Hold at most ``cfg.keep_samples``: drop the least informative at the online estimate
    (`calib.planner.least_informative`), the oldest while there is no estimate yet; returns the dropped one."""
    if not cfg.keep_samples or len(kept) <= cfg.keep_samples:
        return None
    estimate = online.result()
    if estimate is None:
        return kept.pop(0)
    A = np.array([o.T_base_flange for o in kept])
    return kept.pop(least_informative(estimate.setup, estimate.X, estimate.Y, A, keep_recent=cfg.keep_recent))


def _raise_alarm(report: MonitorReport, obs: Observation, update, writer: SessionWriter, viz: Viz,
                 cfg: MonitorConfig) -> None:
    info = {"statistic": float(update.statistic), "n_samples": int(update.n_samples)}
    alarm = Alarm(obs.t, obs.index, info)
    report.alarms.append(alarm)
    text = f"ALARM: camera moved (detected at sample {obs.index}, GLR statistic {update.statistic:.1f})"
    log.warning(text)
    writer.add_event(obs.t, "alarm", sample_index=obs.index, **info)
    viz.event(obs.t, text, "ERROR")
    run_hook(cfg.alarm_hook, {"HANDEYE_EVENT": "camera_moved", "HANDEYE_SESSION": str(writer.path),
                              "HANDEYE_SAMPLE": str(obs.index)})


def _reestimate(samples: list[Observation], solve, writer: SessionWriter, viz: Viz) -> CalibrationResult | None:
    try:
        res = solve(samples, final=True)
    except CalibrationError as e:
        log.info("re-estimate after the move not possible yet: %s", e)
        return None
    writer.add_event(samples[-1].t, "reestimate", n_samples=len(samples),
                     T_camera=res.camera_transform.tolist(), method=res.method)
    viz.estimate(samples[-1].t, res, samples)
    log.info("re-estimated the camera from %d samples after the move", len(samples))
    return res


def print_monitor_summary(report: MonitorReport, setup: Setup = Setup.EYE_TO_HAND) -> None:
    """Counts, detector state, latest estimate with 1-sigma, drift, every alarm, the re-estimate."""
    cam = Setup(setup).camera_name
    print(f"\nsession: {report.session}")
    print(f"samples: {report.n_samples}   skipped: {report.n_skipped}   alarms: {len(report.alarms)}   "
          f"time: {report.elapsed_s:.1f} s   change detector: {detector_state(report.samples_until_armed)}")
    if report.estimate is None:
        print("  estimate: none yet (the online estimator is still collecting its first samples)")
    else:
        line = f"  estimate {cam}: {pose_line(report.estimate)}"
        if report.estimate_sigma is not None:
            line += f"  1-sigma {report.estimate_sigma[1] * 1e3:.2f} mm {np.rad2deg(report.estimate_sigma[0]):.3f} deg"
        print(line)
    if report.drift is not None:
        print(f"  drift vs. reference: {report.drift[0]:.2f} mm  {report.drift[1]:.3f} deg")
    for a in report.alarms:
        print(f"  ALARM camera moved at sample {a.sample_index} ({time.strftime('%H:%M:%S', time.localtime(a.t))}, "
              f"GLR statistic {a.info.get('statistic', float('nan')):.1f})")
    if report.last_alarm is None:
        print("  last alarm: none")
    if report.reestimate is not None:
        print(f"  re-estimate after the move ({report.reestimate.n_samples} samples): "
              f"{pose_line(report.reestimate.camera_transform)}")
    if report.session is not None and (report.session / "recording.rrd").exists():
        from app.viz import open_command

        print(f"\nopen the recording:  {open_command(report.session / 'recording.rrd')}")
