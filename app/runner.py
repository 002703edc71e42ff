"""Compose devices, session store, solvers and rerun into the four runs.

Library entry points that return results (the CLI only parses arguments and
prints): `calibrate`, `monitor`, `replay_source`, `demo`. Every output names
its setup: eye-to-hand (``X = T_flange_marker``, ``Y = T_base_cam``) or
eye-in-hand (``X = T_flange_cam``, ``Y = T_base_marker``).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app import devices, planning
from app.calibrate import RunReport, run_calibration
from app.config import CalibrateConfig, Config
from app.monitor import MonitorReport, run_monitor
from app.pipeline import sigma, solve_observations
from app.replay import format_table, replay
from app.session import SessionWriter, read_session
from app.viz import Viz
from calib import transforms as tf
from calib.errors import ConfigError, HandeyeError, InsufficientDataError, SessionError

log = logging.getLogger(__name__)


@dataclass
class CalibrationOutput:
    """An active run and where its outputs went."""

    report: RunReport
    setup: str
    method: str
    files: dict
    truth: np.ndarray | None = None


def make_viz(cfg: Config, session: Path) -> Viz:
    """rerun recording saved as ``<session>/recording.rrd`` (``recording-2.rrd`` ... when resumed; no-op if disabled)."""
    path, n = session / "recording.rrd", 1
    while path.exists():
        n += 1
        path = session / f"recording-{n}.rrd"
    return Viz(cfg.setup, path, viewer=cfg.viz.viewer, enabled=cfg.viz.enabled, log_images=cfg.viz.log_images)


def make_solve(cal: CalibrateConfig, setup: str, rng: np.random.Generator):
    """``solve(observations, *, final)``: the configured solver (refined if configured: the stop on the
    predicted 1-sigma and the planner then see the covariance of the result that will be reported);
    outlier rejection only at the end."""

    def solve(observations, *, final: bool):
        return solve_observations(cal.method, observations, setup,
                                  refine=cal.refine, robust=cal.robust and final, rng=rng)

    return solve


def _camera_truth(setup: str, truth: dict) -> np.ndarray | None:
    key = "T_base_cam" if setup == "eye_to_hand" else "T_flange_cam"
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
    from tqdm import tqdm

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
            T_true = _camera_truth(cfg.setup, truth)
            if T_true is not None:
                viz.truth(T_true)
            bar = tqdm(total=cfg.calibrate.samples, initial=len(initial), desc="samples", unit="sample",
                       disable=not progress)
            poses = planning.make_pose_source(cfg, robot, camera.intrinsics, robot.read().T_base_flange, rng)
            with bar:
                report = run_calibration(robot, camera, devices.make_measure(cfg), make_solve(cfg.calibrate, cfg.setup, rng),
                                         writer, cfg.calibrate, cfg.setup, rng, viz,
                                         save_frames=cfg.session.save_frames, progress=bar, initial=initial,
                                         poses=poses)
    files = devices.write_result(report.result, writer.path, cfg.session.exports) if report.result is not None else {}
    if "json" in files:
        _add_run_summary(files["json"], report, cfg.calibrate.poses)
    return CalibrationOutput(report, cfg.setup, cfg.calibrate.method, files, _camera_truth(cfg.setup, truth))


def _add_run_summary(path: Path, report: RunReport, poses: str) -> None:
    """Record how the run ended in result.json: samples used, skips, why it stopped, which poses."""
    doc = json.loads(Path(path).read_text(encoding="utf-8"))
    doc["run"] = {"n_samples": report.n_samples, "n_skipped": report.n_skipped, "stopped_by": report.stopped_by,
                  "poses": poses, "n_motions": report.n_motions, "robot_time_s": report.robot_time_s,
                  "elapsed_s": report.elapsed_s}
    Path(path).write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")


def monitor(cfg: Config, *, reference: Path | None = None, stop=None, progress: bool = True) -> MonitorReport:
    """Passive monitoring with a read-only robot connection (never moves the robot).

    ``reference``: a previous session (same setup) whose samples prime the
    online estimator, so change detection starts with the first new sample
    instead of after the estimator's bootstrap and warm-up.
    """
    from tqdm import tqdm

    rng = np.random.default_rng(cfg.calibrate.seed)
    online = devices.make_online(cfg)
    if reference is not None:
        ref = read_session(reference)
        if ref.setup != cfg.setup:
            raise SessionError(f"reference session {reference} is {ref.setup}, the config is {cfg.setup}")
        for obs in ref.observations:
            online.update(obs.T_base_flange, obs.point_cam, obs.point_cov)
    with devices.open_robot(cfg, read_only=True) as robot, devices.open_camera(cfg, robot) as camera:
        writer = SessionWriter.create(cfg.session.root, cfg.setup, config=cfg.to_dict(),
                                      intrinsics=dataclasses.asdict(camera.intrinsics), truth=devices.truth(camera),
                                      source="handeye monitor")
        solve = make_solve(dataclasses.replace(cfg.calibrate, method=cfg.monitor.method), cfg.setup, rng)
        with writer, make_viz(cfg, writer.path) as viz, \
                tqdm(desc="samples", unit="sample", disable=not progress) as bar:
            return run_monitor(robot, camera, devices.make_measure(cfg), online, solve, writer, cfg.monitor,
                               cfg.setup, viz, stop=stop, save_frames=cfg.session.save_frames,
                               on_sample=lambda obs: bar.update(1))


@dataclass
class PlanOutput:
    """A dry-run plan and where it went."""

    document: dict
    path: Path
    recording: Path | None


def load_prior(cfg: Config, prior: Path | None, camera, T_start: np.ndarray) -> tuple[np.ndarray, np.ndarray, str]:
    """X, Y to plan with: an earlier result.json or session of this cell, or the simulator's truth.

    Raises
    ------
    ConfigError
        No prior given and the camera is not simulated.
    """
    setup = cfg.setup
    if prior is None:
        truth = devices.truth(camera)
        if not truth:
            raise ConfigError("plan needs a prior calibration of this cell on real hardware: "
                              "--prior result.json (or a session directory)")
        names = ("T_flange_marker", "T_base_cam") if setup == "eye_to_hand" else ("T_flange_cam", "T_base_marker")
        return truth[names[0]], truth[names[1]], "simulator truth (the rendered camera's mounting)"
    prior = Path(prior)
    if (prior / "session.json").exists():
        session = read_session(prior)
        if session.setup != setup:
            raise SessionError(f"prior session {prior} is {session.setup}, the config is {setup}")
        res = solve_observations(cfg.calibrate.method, session.observations, setup, refine=cfg.calibrate.refine)
        obs = session.observations
        X, Y = planning.with_marker_rotation(setup, res.X, res.Y, res.marker_rotation_known,
                                             [o.T_base_flange for o in obs], [o.T_cam_marker for o in obs],
                                             obs[0].point_cam)
        return X, Y, f"session {prior} ({res.method}, {res.n_samples} samples)"
    try:
        doc = json.loads(prior.read_text(encoding="utf-8"))
        if doc["setup"] != setup:
            raise SessionError(f"prior {prior} is {doc['setup']}, the config is {setup}")
        cam = tf.check_transform(doc["camera_transform"]["matrix"], "camera_transform")
        mark = tf.check_transform(doc["marker_transform"]["matrix"], "marker_transform")
        known = bool(doc["marker_transform"].get("rotation_known", True))
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, HandeyeError) as e:
        if isinstance(e, SessionError):
            raise
        raise SessionError(f"--prior {prior}: not a handeye result.json or session directory ({e})") from None
    X, Y = (mark, cam) if setup == "eye_to_hand" else (cam, mark)
    if not known:
        # Seen squarely at the start pose: where the prior predicts the marker there.
        p0 = (tf.invert(Y) @ T_start @ X)[:3, 3] if setup == "eye_to_hand" else (tf.invert(T_start @ X) @ Y)[:3, 3]
        X, Y = planning.with_marker_rotation(setup, X, Y, False, [T_start], [None], p0)
    return X, Y, f"result {prior}"


def plan(cfg: Config, out: Path, *, prior: Path | None = None) -> PlanOutput:
    """Plan the poses of an active run without moving (read-only robot connection): write ``out``
    (plan.json, see `app.planning`) and a rerun recording beside it."""
    rng = np.random.default_rng(cfg.calibrate.seed)
    with devices.open_robot(cfg, read_only=True) as robot, devices.open_camera(cfg, robot) as camera:
        state = robot.read()
        X, Y, prior_name = load_prior(cfg, prior, camera, state.T_base_flange)
        doc, poses, _ = planning.make_plan(cfg, X, Y, state.T_base_flange, state.q, camera.intrinsics, robot, rng,
                                           prior=prior_name)
        intrinsics = camera.intrinsics
    path = planning.write_plan(doc, out)
    rrd = None
    if cfg.viz.enabled:
        rrd = Path(out).with_suffix(".rrd")
        with Viz(cfg.setup, rrd, viewer=cfg.viz.viewer) as viz:
            viz.plan(poses, X, Y, intrinsics, planning.camera_view(cfg.calibrate, intrinsics, cfg.marker).marker_size_m)
    return PlanOutput(doc, path, rrd)


def print_plan_summary(out: PlanOutput) -> None:
    d = out.document
    print(f"\nplan: {out.path}   setup: {d['setup']}   prior: {d['prior']}")
    print(f"poses: {len(d['poses'])}   expected robot time: {d['expected_robot_time_s']:.1f} s")
    print("\n| pose | kind | x, y, z [mm] | marker px | expected 1-sigma [mm] | [deg] |\n|---|---|---|---|---|---|")
    for p in d["poses"]:
        xyz = np.asarray(p["T_base_flange"])[:3, 3] * 1e3
        print(f"| {p['index']} | {p['kind']} | {xyz[0]:.0f}, {xyz[1]:.0f}, {xyz[2]:.0f} | "
              f"{p['pixel'][0]:.0f}, {p['pixel'][1]:.0f} | {p['expected_sigma_mm']:.2f} | {p['expected_sigma_deg']:.3f} |")
    if out.recording is not None:
        print(f"\nrerun recording: {out.recording}  (open with: rerun {out.recording})")
    print(f"replay on the robot: handeye calibrate -c <config> --poses {out.path}")


def all_methods() -> list[str]:
    from calib.api import METHODS

    return list(METHODS)


def replay_source(source: Path, methods: list[str], *, refine: bool = False, robust: bool = False,
                  setup: str | None = None, rng: np.random.Generator | None = None) -> str:
    """Re-solve a session directory or an imported file with each method; returns the markdown table."""
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
    return f"{source} ({setup}, {len(observations)} samples)\n{header}\n" + format_table(rows, setup)


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


def _pose_line(T: np.ndarray) -> str:
    xyz, q = tf.to_xyz_quat(T)
    return (f"xyz [mm] = {np.array2string(xyz * 1e3, precision=2)}  "
            f"quat (x,y,z,w) = {np.array2string(q, precision=5)}")


def print_calibration_summary(out: CalibrationOutput) -> None:
    r = out.report
    cam = "T_base_cam" if out.setup == "eye_to_hand" else "T_flange_cam"
    print(f"\nsession: {r.session}")
    print(f"setup: {out.setup}   solver: {out.method}   samples: {r.n_samples}   skipped: {r.n_skipped}   "
          f"stopped by: {r.stopped_by}   time: {r.elapsed_s:.1f} s (robot motions: {r.n_motions}, "
          f"{r.robot_time_s:.1f} s)")
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


def print_monitor_summary(report: MonitorReport) -> None:
    print(f"\nsession: {report.session}")
    print(f"samples: {report.n_samples}   skipped: {report.n_skipped}   alarms: {len(report.alarms)}   "
          f"time: {report.elapsed_s:.1f} s")
    for a in report.alarms:
        print(f"  ALARM camera moved at sample {a.sample_index} ({time.strftime('%H:%M:%S', time.localtime(a.t))})")
    if report.reestimate is not None:
        print(f"  re-estimate after the move: {_pose_line(report.reestimate.camera_transform)}")


print_demo_summary = print_calibration_summary
