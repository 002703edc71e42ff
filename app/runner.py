"""Compose devices, session store, solvers and rerun into the four runs.

Library entry points that return results (the CLI only parses arguments and
prints): `calibrate`, `monitor`, `replay_source`, `demo`. Every output names
its setup: eye-to-hand (``X = T_flange_marker``, ``Y = T_base_cam``) or
eye-in-hand (``X = T_flange_cam``, ``Y = T_base_marker``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app import devices
from app.calibrate import RunReport, run_calibration
from app.config import CalibrateConfig, Config
from app.monitor import MonitorReport, run_monitor
from app.pipeline import sigma, solve_observations
from app.production import Bump, start_production
from app.progress import progress_bar, say, show_monitor
from app.replay import advice, format_table, replay
from app.session import SessionWriter, read_session
from app.viz import Viz
from calib import transforms as tf
from calib.setup import Setup
from app.errors import ConfigError, SessionError
from calib.errors import CalibrationError, HandeyeError, InsufficientDataError

log = logging.getLogger(__name__)


@dataclass
class CalibrationOutput:
    """An active run and where its outputs went."""

    report: RunReport
    setup: Setup
    method: str
    files: dict
    truth: np.ndarray | None = None
    recording: Path | None = None
    frames: dict | None = None


def make_viz(cfg: Config, session: Path) -> Viz:
    """rerun recording saved as ``<session>/recording.rrd`` (``recording-2.rrd`` ... when resumed; no-op if disabled)."""
    path, n = session / "recording.rrd", 1
    while path.exists():
        n += 1
        path = session / f"recording-{n}.rrd"
    return Viz(cfg.setup, path, viewer=cfg.viz.viewer, viewer_bind=cfg.viz.viewer_bind, enabled=cfg.viz.enabled,
               log_images=cfg.viz.log_images)


def make_solve(cal: CalibrateConfig, setup: Setup, rng: np.random.Generator):
    """``solve(observations, *, final)``: fast unrefined estimates while running, the configured one at the end."""

    def solve(observations, *, final: bool):
        return solve_observations(cal.method, observations, setup,
                                  refine=cal.refine and final, robust=cal.robust and final, rng=rng)

    return solve


def _camera_truth(setup: Setup, truth: dict) -> np.ndarray | None:
    key = Setup(setup).camera_name
    return None if key not in truth else np.asarray(truth[key], dtype=float)


def calibrate(cfg: Config, *, resume: Path | None = None, progress: bool = True) -> CalibrationOutput:
    """Active calibration with the configured robot and camera (the caller confirmed motion).

    ``resume``: a session (same setup) to continue; its samples count towards
    ``calibrate.samples`` and new ones are appended to it.

    Returns
    -------
    CalibrationOutput
        The run report (result, session path, counts) and the files written.
    """
    initial = []
    if resume is not None:
        previous = read_session(resume)
        if previous.setup != cfg.setup:
            raise SessionError(f"session {resume} is {previous.setup}, the config is {cfg.setup}")
        initial = previous.observations
    # A resumed run must not replay the poses it already visited.
    rng = np.random.default_rng([cfg.calibrate.seed, len(initial)])
    with devices.open_robot(cfg, read_only=False) as robot, devices.open_camera(cfg, robot) as camera:
        truth = devices.truth(camera)
        if resume is not None:
            writer = SessionWriter.resume(resume)
        else:
            writer = SessionWriter.create(cfg.session.root, cfg.setup, config=cfg.to_dict(),
                                          intrinsics=dataclasses.asdict(camera.intrinsics), truth=truth)
        with writer, make_viz(cfg, writer.path) as viz:
            recording = viz.rrd_path
            T_true = _camera_truth(cfg.setup, truth)
            if T_true is not None:
                viz.truth(T_true)
            with progress_bar(total=cfg.calibrate.samples, initial=len(initial), enabled=progress) as bar:
                report = run_calibration(robot, camera, devices.make_measure(cfg), make_solve(cfg.calibrate, cfg.setup, rng),
                                         writer, cfg.calibrate, cfg.setup, rng, viz,
                                         save_frames=cfg.session.save_frames, progress=bar, initial=initial)
    files = (devices.write_result(report.result, writer.path, cfg.session.exports, cfg.frames)
             if report.result is not None else {})
    return CalibrationOutput(report, cfg.setup, cfg.calibrate.method, files, _camera_truth(cfg.setup, truth),
                             recording, cfg.frames)


def monitor(cfg: Config, *, reference: Path | None = None, stop=None, progress: bool = True,
            bump: Bump | None = None, production: bool = True, publish=None) -> MonitorReport:
    """Passive monitoring with a read-only robot connection (never moves the robot).

    ``reference``: a previous session (same setup) whose samples are solved
    in one batch to arm the change detector at once (estimate and
    covariance), so detection starts with the first new sample and the
    drift is measured against it.

    On the simulated cell (``robot.type = "ur_sim"``) the simulated controller
    runs a looping production program (``production``, `app.production`) so
    that the robot moves, and ``bump`` knocks the rendered camera partway.
    ``publish``: optional ``(obs, update, report)`` callback; by default the
    ``[mqtt]`` publisher when enabled (`app.mqtt`).
    """
    from app.formats.export import check_frames
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
    publisher = make_publisher(cfg.mqtt, cfg.setup, check_frames(cfg.frames)) if publish is None else None
    with devices.open_robot(cfg, read_only=True) as robot, devices.open_camera(cfg, robot) as camera, \
            (publisher or contextlib.nullcontext()):
        publish = publish or publisher
        if production:
            start_production(robot, cfg, rng, say=say)
        writer = SessionWriter.create(cfg.session.root, cfg.setup, config=cfg.to_dict(),
                                      intrinsics=dataclasses.asdict(camera.intrinsics), truth=devices.truth(camera),
                                      source="handeye monitor")
        solve = make_solve(dataclasses.replace(cfg.calibrate, method=cfg.monitor.method), cfg.setup, rng)
        with writer, make_viz(cfg, writer.path) as viz, progress_bar(enabled=progress) as bar:
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
                               cfg.setup, viz, stop=stop, save_frames=cfg.session.save_frames,
                               on_sample=on_sample, on_update=on_update, reference=T_reference, say=say)


def all_methods() -> list[str]:
    from calib.api import METHODS

    return list(METHODS)


def replay_source(source: Path, methods: list[str], *, refine: bool = False, robust: bool = False,
                  setup: Setup | None = None, rng: np.random.Generator | None = None,
                  target_mm: float = 0.0, target_deg: float = 0.0) -> str:
    """Re-solve a session directory or an imported file with each method; returns the report: the
    tables grouped by what the solvers use and sorted by held-out error, then the advice
    (`app.replay.advice`; ``target_mm``/``target_deg`` are the config's 1-sigma targets)."""
    if not Path(source).exists():
        raise SessionError(f"{source}: no such file or directory")
    if (Path(source) / "session.json").exists():
        session = read_session(source)
        if setup is not None and setup != session.setup:
            raise SessionError(f"{source} is an {session.setup} session; --setup {setup} contradicts it")
        observations, file_setup, truth = session.observations, session.setup, session.truth
        header = ""
    else:
        observations, file_setup, meta = devices.import_observations(Path(source), setup)
        truth, header = {}, _import_summary(meta)
    setup = setup or file_setup
    if not observations:
        raise InsufficientDataError(f"{source}: no samples to replay")
    if methods == ["all"]:
        methods = all_methods()
    rows = replay(observations, setup, methods, refine=refine, robust=robust,
                  truth=_camera_truth(setup, truth), rng=rng)
    if all(r.result is None for r in rows):
        raise HandeyeError(f"no solver succeeded on {source}: " + "; ".join(f"{r.method}: {r.error}" for r in rows))
    lines = advice(rows, observations, refine=refine, target_mm=target_mm, target_deg=target_deg)
    return (f"{source} ({setup}, {len(observations)} samples)\n{header}\n" + format_table(rows, setup)
            + ("\n\n" + "\n".join(lines) if lines else ""))


def _import_summary(meta: dict) -> str:
    """What an importer measured that the table does not show (the streams' clock offset)."""
    if "clock_offset_s" not in meta:
        return ""
    line = f"clock offset (t_robot = t_camera + offset): {meta['clock_offset_s'] * 1e3:+.1f} ms"
    if "xcorr_score" in meta:
        line += f" (angular-speed correlation {meta['xcorr_score']:.2f}"
        if "refine_rms_mm" in meta:
            line += f", refined on the residual: RMS {meta['refine_rms_mm']:.2f} mm"
        line += ")"
    return line + "\n"


def demo(cfg: Config, *, progress: bool = True) -> CalibrationOutput:
    """Calibrate the simulated cell: the UR simulator (started by the robot driver, driven
    through the real ur_rtde client) and the rendered camera, whose true pose is known.

    Raises
    ------
    ConfigError
        If the config names real hardware: the demo moves without asking.
    """
    if cfg.robot.get("type") != "ur_sim" or cfg.camera.get("backend") != "rendered":
        raise ConfigError("demo runs only the simulated cell (robot.type = 'ur_sim', camera.backend = 'rendered'); "
                          "use 'handeye calibrate' for hardware")
    return calibrate(cfg, progress=progress)


#: Monitor settings of ``handeye demo --monitor``: quick standstills and a small estimator bootstrap,
#: so the whole story (arming, bump, alarm, re-estimate) fits in about half a minute.
DEMO_MONITOR = {"still_s": 0.2, "poll_s": 0.02, "reestimate_samples": 6,
                "online": {"bootstrap": 6, "warmup": 4, "detector": {"window": 6}}}


def demo_monitor(cfg: Config, *, bump: Bump | None, reference: Path | None = None, max_samples: int | None = None,
                 progress: bool = True, publish=None) -> MonitorReport:
    """Passive monitoring of the simulated cell: its controller runs a looping production program,
    the rendered camera is bumped partway (``bump``), the monitor alarms and re-estimates.

    Without ``max_samples`` the run ends a few samples after the re-estimate is due.

    Raises
    ------
    ConfigError
        If the config names real hardware.
    """
    if cfg.robot.get("type") != "ur_sim" or cfg.camera.get("backend") != "rendered":
        raise ConfigError("demo --monitor runs only the simulated cell (robot.type = 'ur_sim', "
                          "camera.backend = 'rendered'); use 'handeye monitor' for hardware")
    mon = dict(DEMO_MONITOR)
    if cfg.monitor.online:  # the config's own estimator settings win
        mon.pop("online")
    after = bump.after if bump is not None else 0
    mon["max_samples"] = max_samples or (after + 4 + mon["reestimate_samples"] + 6 if bump else 30)
    mon["duration_s"] = cfg.monitor.duration_s or 300.0
    cfg = dataclasses.replace(cfg, monitor=dataclasses.replace(cfg.monitor, **mon))
    devices.validate(cfg)
    return monitor(cfg, reference=reference, progress=progress, bump=bump, publish=publish)


def _pose_line(T: np.ndarray) -> str:
    xyz, q = tf.to_xyz_quat(T)
    return (f"xyz [mm] = {np.array2string(xyz * 1e3, precision=2)}  "
            f"quat (x,y,z,w) = {np.array2string(q, precision=5)}")


def print_calibration_summary(out: CalibrationOutput) -> None:
    r = out.report
    cam = Setup(out.setup).camera_name
    print(f"\nsession: {r.session}")
    print(f"setup: {out.setup}   solver: {out.method}   samples: {r.n_samples}   skipped: {r.n_skipped}   "
          f"stopped by: {r.stopped_by}   time: {r.elapsed_s:.1f} s")
    reasons = sorted(r.skip_reasons.items(), key=lambda kv: -kv[1])[:3]
    if reasons:
        print("most frequent skips: " + "; ".join(f"{n}x {why}" for why, n in reasons))
    if r.result is None:
        print(f"no calibration: {r.n_samples} samples are too few (every skip and its reason is in "
              f"{r.session / 'samples.jsonl'})")
        return
    res = r.result
    rows = [("estimate " + cam, _pose_line(res.camera_transform))]
    if out.truth is not None:
        rows.append(("truth    " + cam, _pose_line(out.truth)))
    for name, line in rows:
        print(f"  {name}: {line}")
    print()
    print("| quantity | value |\n|---|---|")
    print(f"| residual RMS [mm] | {res.residuals.rms_translation * 1e3:.2f} |")
    print(f"| residual max [mm] | {res.residuals.max_translation * 1e3:.2f} |")
    if res.cov is not None:
        s_deg, s_mm = sigma(res.cov)
        print(f"| 1-sigma [mm] | {s_mm:.2f} |\n| 1-sigma [deg] | {s_deg:.3f} |")
    if out.truth is not None:
        rot, trans = tf.pose_error(res.camera_transform, out.truth)
        print(f"| error vs truth [mm] | {trans * 1e3:.2f} |\n| error vs truth [deg] | {np.rad2deg(rot):.3f} |")
    for kind, path in out.files.items():
        print(f"| {kind} | {path} |")
    print_next_steps(out)


def print_next_steps(out: CalibrationOutput) -> None:
    """How to look at the run (rerun) and use its result (ROS 2), as commands to paste."""
    from app.formats import ros2_command
    from app.viz import open_command

    print()
    if out.recording is not None and out.recording.exists():
        print(f"open the recording:  {open_command(out.recording)}")
    if out.report.result is not None:
        print(f"publish in ROS 2:    {ros2_command(out.report.result, out.frames)}")


def print_monitor_summary(report: MonitorReport, setup: Setup = Setup.EYE_TO_HAND) -> None:
    """Counts, detector state, latest estimate with 1-sigma, drift, every alarm, the re-estimate."""
    from app.monitor import detector_state

    cam = Setup(setup).camera_name
    print(f"\nsession: {report.session}")
    print(f"samples: {report.n_samples}   skipped: {report.n_skipped}   alarms: {len(report.alarms)}   "
          f"time: {report.elapsed_s:.1f} s   change detector: {detector_state(report.samples_until_armed)}")
    if report.estimate is None:
        print("  estimate: none yet (the online estimator is still collecting its first samples)")
    else:
        line = f"  estimate {cam}: {_pose_line(report.estimate)}"
        if report.estimate_cov is not None:
            s_deg, s_mm = sigma(report.estimate_cov)
            line += f"  1-sigma {s_mm:.2f} mm {s_deg:.3f} deg"
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
              f"{_pose_line(report.reestimate.camera_transform)}")
    if report.session is not None and (report.session / "recording.rrd").exists():
        from app.viz import open_command

        print(f"\nopen the recording:  {open_command(report.session / 'recording.rrd')}")


print_demo_summary = print_calibration_summary
