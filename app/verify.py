"""``handeye verify``'s work: read a result file, measure at fresh poses (or take another session), judge, write.

Eye-to-hand: ``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand:
``X = T_flange_cam``, ``Y = T_base_marker`` (paper eq. 1). The judging is
`handeye.calib.verify`'s; this module reads ``result.yaml`` (`load_result`), picks and
visits the poses (`verify_active`) or samples read-only while production moves
the robot (`verify_passive`), and writes ``verify.yaml`` (`write_verify`).

``verify.yaml``::

    format: handeye-verify, version: 1, setup, equation,
    verdict: {level: pass | warn | fail, summary, reasons} (handeye.calib.verdict.judge_verification)
    per_pose_note: what the per-pose errors are made of (handeye.calib.verdict.per_pose_phrase)
    cell: who verified, where, with what (handeye.app.provenance.cell)
    mode (active | passive | offline),
    result: {path, solver, camera_transform (name), camera_transform_raw_points present}
    source: the session verified against (offline) or recorded (active)
    verification: handeye.calib.verify.Verification.to_dict() (mm, deg; passed)
    rigid_export: the same for camera_transform_raw_points on uncorrected points (ROS/URDF), if any
    frame_safety: handeye.calib.verify.FrameSafety.to_dict() (with --expect-xyz)
    repeated_calibration_poses: indices of the poses within a few mm / tenths of a degree of a calibration pose
    truth: {calibration_error_mm} of the simulated cell's truth over the same poses (simulators only)
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from handeye.app import devices, planning, provenance, stopping
from handeye.app.acquire import take_sample
from handeye.app.config import Config
from handeye.app.errors import SessionError
from handeye.app.files import read_text_file
from handeye.app.production import knock_as_left, record_knocks
from handeye.app.session import SessionWriter, read_session
from handeye.calib import planner as pl
from handeye.calib import transforms as tf
from handeye.calib import verify as cv
from handeye.calib.errors import CalibrationError, HandeyeError
from handeye.calib.model import CameraCorrection
from handeye.calib.observation import Observation
from handeye.calib.setup import Setup
from handeye.calib.verdict import per_pose_phrase
from handeye.drivers.errors import DeviceError, LimitViolationError

log = logging.getLogger(__name__)

VERIFY_FORMAT = "handeye-verify"
VERIFY_VERSION = 1
#: A result.yaml is a few kB; this bounds what a wrong path costs.
MAX_RESULT_BYTES = 4 * 1024 * 1024


@dataclass(frozen=True)
class LoadedResult:
    """A result file read back: the model `handeye.calib.verify` judges, and the rigid export's (None without a
    camera correction: ``camera_transform_raw_points`` is then ``camera_transform``)."""

    path: Path
    model: cv.VerifiedModel
    rigid: cv.VerifiedModel | None
    doc: dict

    @property
    def session(self) -> Path | None:
        """The calibration session the result was written into (its samples are not reused), if any."""
        d = self.path.parent
        return d if (d / "session.json").exists() else None

    @property
    def samples_from(self) -> Path | None:
        """Where the result's samples are: ``samples_from`` in the file (a session or an imported file, as
        calibrate and replay --out write it) when it still exists, else the session holding the file, else None."""
        named = self.doc.get("samples_from")
        if isinstance(named, str) and named and Path(named).exists():
            return Path(named)
        return self.session

    def calibration_samples(self) -> list[Observation]:
        """The samples the result was solved from (`samples_from`), or none when they cannot be read."""
        source = self.samples_from
        if source is None:
            return []
        try:
            if (source / "session.json").exists():
                return read_session(source).observations
            return devices.import_observations(source, self.model.setup.value)[0]
        except HandeyeError as e:
            log.warning("the calibration's samples (%s) cannot be read: %s", source, e)
            return []


def _get(doc, keys: str, where: Path):
    value = doc
    for k in keys.split("."):
        if not isinstance(value, dict) or k not in value:
            raise SessionError(f"{where}: {keys} missing (not a handeye result file?)")
        value = value[k]
    return value


def _matrix(doc, keys: str, where: Path) -> np.ndarray:
    value = _get(doc, keys, where)
    try:
        T = np.array(value, dtype=float)
        return tf.check_transform(T, keys)
    except (TypeError, ValueError, CalibrationError) as e:
        raise SessionError(f"{where}: {keys} must be a rigid 4x4 transform ({str(e)[:120]})") from None


def _number(value, keys: str, where: Path, default: float) -> float:
    if value is None:
        return default
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
        raise SessionError(f"{where}: {keys} must be a finite number >= 0, got {value!r}")
    return float(value)


def load_result(path: Path) -> LoadedResult:
    """Read ``result.yaml`` / ``result.json`` (or a session directory holding one) written by handeye.

    Raises
    ------
    SessionError
        Naming the file and the missing or malformed field.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "result.yaml"
    text = read_text_file(path, SessionError, max_bytes=MAX_RESULT_BYTES)
    try:
        doc = yaml.safe_load(text)
    except (yaml.YAMLError, RecursionError, ValueError) as e:
        raise SessionError(f"{path}: cannot read ({str(e)[:200]})") from None
    if not isinstance(doc, dict) or doc.get("format") != "handeye-result":
        raise SessionError(f"{path}: not a handeye result file (format: handeye-result)")
    model, rigid = models_of(doc, path)
    return LoadedResult(path, model, rigid, doc)


def models_of(doc: dict, path) -> tuple[cv.VerifiedModel, cv.VerifiedModel | None]:
    """The `handeye.calib.verify.VerifiedModel` of a result document (`handeye.app.formats.result_to_dict`), and
    its rigid export's (None without ``camera_transform_raw_points``); `SessionError` naming ``path`` and the field."""
    try:
        setup = Setup(_get(doc, "setup", path))
    except ValueError:
        raise SessionError(f"{path}: setup must be eye_to_hand or eye_in_hand, got {doc['setup']!r}") from None
    cam = _matrix(doc, "camera_transform.matrix", path)
    marker = _matrix(doc, "marker_transform.matrix", path)
    X, Y = (marker, cam) if setup == Setup.EYE_TO_HAND else (cam, marker)
    mdl = doc.get("model") or {}
    if not isinstance(mdl, dict):
        raise SessionError(f"{path}: model must be a table")
    cc = mdl.get("camera_correction") or {}
    if not isinstance(cc, dict):
        raise SessionError(f"{path}: model.camera_correction must be a table")
    unit = {"depth_scale": ("depth_scale_percent", 1e-2), "depth_offset": ("depth_offset_mm", 1e-3),
            "focal_scale": ("focal_scale_percent", 1e-2)}
    values = {}
    for name, (key, scale) in unit.items():
        entry = cc.get(key)
        if entry is None:
            continue
        if not isinstance(entry, dict) or not isinstance(entry.get("value"), (int, float)) \
                or not np.isfinite(entry["value"]):
            raise SessionError(f"{path}: model.camera_correction.{key}.value must be a finite number")
        if entry.get("estimated", True):
            values[name] = float(entry["value"]) * scale
    noise = mdl.get("noise") or {}
    if not isinstance(noise, dict):
        raise SessionError(f"{path}: model.noise must be a table")
    rot = noise.get("marker_rotation_deg")
    try:
        model = cv.VerifiedModel(
            setup, X, Y, CameraCorrection(**values),
            point_scale=_number(noise.get("camera_point_scale"), "model.noise.camera_point_scale", path, 1.0),
            robot_sigma_m=_number(noise.get("robot_mm"), "model.noise.robot_mm", path, 0.0) * 1e-3,
            rotation_sigma_rad=None if rot is None else
            np.deg2rad(_number(rot, "model.noise.marker_rotation_deg", path, 0.0)),
            marker_rotation_known=bool(doc["marker_transform"].get("rotation_known", True)),
            method=str(doc.get("solver", "")))
    except CalibrationError as e:
        raise SessionError(f"{path}: model: {e}") from None
    rigid = None
    if "camera_transform_raw_points" in doc:
        rigid = model.rigid_export(_matrix(doc, "camera_transform_raw_points.matrix", path))
    return model, rigid


def average_frames(observations: list[Observation], groups: list[int]) -> list[Observation]:
    """One observation per pose: the mean point of the frames taken there (``groups[i]``: pose of sample i),
    the covariance divided by their number, the first frame's flange pose and marker orientation."""
    out = []
    for g in dict.fromkeys(groups):
        members = [o for o, k in zip(observations, groups) if k == g]
        first = members[0]
        n = len(members)
        p = np.mean([o.point_cam for o in members], axis=0)
        covs = [o.point_cov for o in members]
        cov = None if any(c is None for c in covs) else np.mean(covs, axis=0) / n
        out.append(dataclasses.replace(first, point_cam=p, point_cov=cov, meta={**first.meta, "frames": n}))
    return out


def pose_errors(model: cv.VerifiedModel, observations: list[Observation]) -> cv.PoseErrors:
    """`handeye.calib.verify.prediction_errors` of ``model`` on the samples."""
    covs = [o.point_cov for o in observations]
    # Pose-only samples (some imports) carry their marker center in the pose.
    points = [o.point_cam if o.point_cam is not None else o.T_cam_marker[:3, 3] for o in observations]
    return cv.prediction_errors(model, np.array([o.T_base_flange for o in observations]), np.array(points),
                                None if any(c is None for c in covs) else np.array(covs),
                                [o.T_cam_marker for o in observations])


def true_error_mm(loaded: LoadedResult, observations: list[Observation], truth: dict, camera_bias=None) -> float:
    """RMS over the poses of the error `handeye.calib.verify` would see without noise: the result's marker against
    the true marker, the camera's true systematic error (``camera_bias``, a `CameraCorrection`) applied, mm.

    ``truth``: the simulated cell's true transforms (``T_base_cam``/``T_flange_marker`` eye-to-hand,
    ``T_flange_cam``/``T_base_marker`` eye-in-hand)."""
    setup = loaded.model.setup
    cam, marker = truth[setup.camera_name], truth[setup.marker_name]
    X_true, Y_true = (marker, cam) if setup == Setup.EYE_TO_HAND else (cam, marker)
    A = np.array([o.T_base_flange for o in observations])
    if setup == Setup.EYE_TO_HAND:
        p_true = tf.transform_points(tf.invert(Y_true) @ A, X_true[:3, 3])
    else:
        p_true = tf.transform_points(tf.invert(A @ X_true), Y_true[:3, 3])
    seen = (camera_bias or CameraCorrection()).measure(p_true)
    e = cv.prediction_errors(loaded.model, A, seen).translation
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1)))) * 1e3


def verify_poses(cfg: Config, model: cv.VerifiedModel, T_start: np.ndarray, q_start, robot, intrinsics,
                 calibration: list[Observation], rng: np.random.Generator) -> list[np.ndarray]:
    """``[verify] poses`` flange poses spread over the ``[calibrate]`` region around ``T_start``: valid for the
    camera at the result (marker in view with the margin, depth range, view angle, keep-out boxes), reachable
    by the robot's own limit check, each ``min_separation_m`` from every calibration pose."""
    X, Y = model.X, model.Y
    if not model.marker_rotation_known:
        if not calibration:
            raise SessionError("the result has no marker orientation (a point-only solver) and its calibration "
                               "session is not beside it: verify needs one of them to plan where the marker faces")
        X, Y = planning.with_marker_rotation(model.setup, X, Y, False, [o.T_base_flange for o in calibration],
                                             [o.T_cam_marker for o in calibration], calibration[0].point_cam)
    # Without the calibration's samples there is no covariance to widen the margins by: plan at the result.
    pcfg = planning.planner_config(cfg, **({} if calibration else {"uncertainty_k": 0.0}))
    view = planning.camera_view(cfg.calibrate, intrinsics, cfg.marker)
    planner = pl.PosePlanner(model.setup, X, Y, view, pcfg)
    if calibration:
        planner.add(np.array([o.T_base_flange for o in calibration]))
    avoid = np.array([o.T_base_flange for o in calibration]) if calibration else None
    return cv.spread_poses(planner, T_start, cfg.verify.poses, rng, avoid=avoid,
                           min_separation_m=cfg.verify.min_separation_m, reachable=planning.reachable(robot),
                           q_start=q_start)


@dataclass
class VerifyRun:
    """What an active (or passive) verification recorded: the session, the per-pose observations (frames
    averaged; passive: one frame each), the poses planned (passive: wanted)."""

    session: Path
    observations: list[Observation]
    planned: int
    n_skipped: int
    truth: dict = field(default_factory=dict)
    camera_bias: CameraCorrection | None = None
    interrupted: bool = False


def verify_active(cfg: Config, loaded: LoadedResult, *, rng: np.random.Generator,
                  confirm: Callable[[], None] = lambda: None) -> VerifyRun:
    """Move to fresh planned poses, measure the marker ``frames_per_pose`` times at each, record everything in
    a new session under ``session.root``; returns the per-pose observations. ``confirm`` is called once the
    devices are connected and the poses planned, before the first motion (raises to refuse)."""
    if loaded.model.setup != cfg.setup:
        raise SessionError(f"{loaded.path} is an {loaded.model.setup} result, the config is {cfg.setup}")
    calibration = loaded.calibration_samples()
    devices.check_session_root(cfg)
    measure = devices.make_measure(cfg)
    observations, groups, n_skipped, interrupted = [], [], 0, False
    with devices.open_robot(cfg, read_only=False) as robot, devices.open_camera(cfg, robot) as camera:
        # A monitoring run's calibration in use, on a simulated cell: its camera as that run left it.
        carried = knock_as_left(camera, cfg.setup, loaded.path)
        truth = devices.truth(camera)
        start = robot.read()
        poses = verify_poses(cfg, loaded.model, start.T_base_flange, start.q, robot, camera.intrinsics,
                             calibration, rng)
        if not poses:
            raise SessionError("no valid verification pose in the [calibrate] region at this result (is the "
                               "marker in view from the start pose?)")
        confirm()
        writer = SessionWriter.create(cfg.session.root, cfg.setup, config=cfg.to_dict(),
                                      intrinsics=dataclasses.asdict(camera.intrinsics), truth=truth,
                                      source="handeye verify",
                                      devices=provenance.device_identity(cfg, robot, camera))
        # The session exists from here: a Ctrl-C anywhere after it (the viewer starting, the knocks recorded, the
        # first motion) is the run's stop, with its event, not a bare KeyboardInterrupt.
        with writer:
            try:
                with devices.make_viz(cfg, writer.path) as viz:
                    record_knocks(writer, carried, time.time())
                    for k, T in enumerate(poses):
                        try:
                            state = robot.move_to(T)
                        except LimitViolationError as e:
                            log.info("verify pose %d skipped: %s", k, e)
                            writer.add_skip(time.time(), f"limit: {e}", T_base_flange=T)
                            n_skipped += 1
                            continue
                        time.sleep(cfg.calibrate.settle_s)
                        not_before = state.t_host + cfg.calibrate.settle_s
                        for _ in range(cfg.verify.frames_per_pose):
                            obs = take_sample(robot, camera, measure, writer, viz, not_before=not_before,
                                              save_frames=cfg.session.save_frames, pose_kind="verify")
                            if obs is None:
                                n_skipped += 1
                                continue
                            observations.append(obs)
                            groups.append(k)
                            not_before = obs.t + 1e-6
                    robot.move_to(start.T_base_flange)
            except DeviceError as e:
                writer.add_event(time.time(), "device_error", error=str(e), n_samples=len(observations))
                raise
            except KeyboardInterrupt:
                stopping.winding_down()
                robot.stop()
                interrupted = True
                writer.add_event(time.time(), "interrupted", n_samples=len(observations))
    bias = None
    noise = getattr(cfg.camera, "noise", None)
    if truth and noise is not None:
        bias = CameraCorrection(depth_scale=noise.depth_scale, depth_offset=noise.depth_offset_m)
    return VerifyRun(writer.path, average_frames(observations, groups), len(poses), n_skipped, truth, bias,
                     interrupted)


def verify_passive(cfg: Config, loaded: LoadedResult, *, progress: bool = False) -> VerifyRun:
    """Sample read-only while something else moves the robot (`handeye.app.runs.monitor.monitor`: a still robot,
    a pose unlike the recent ones), until ``[verify] poses`` samples or ``monitor.duration_s``; on the simulated
    cell its controller runs the production program. The samples are recorded in a new session."""
    from handeye.app.runs.monitor import monitor
    from handeye.app.config import config_from_dict

    if loaded.model.setup != cfg.setup:
        raise SessionError(f"{loaded.path} is an {loaded.model.setup} result, the config is {cfg.setup}")
    data = cfg.model_dump()
    data["monitor"]["max_samples"] = cfg.verify.poses
    cfg = config_from_dict(data, "verify --passive")
    report = monitor(cfg, progress=progress, publish=lambda *_: None, knocks_from=loaded.path)
    session = read_session(report.session)
    bias = None
    noise = getattr(cfg.camera, "noise", None)
    if session.truth and noise is not None:
        bias = CameraCorrection(depth_scale=noise.depth_scale, depth_offset=noise.depth_offset_m)
    # A monitor's Ctrl-C is its normal end (Session.interrupted is False for it): the event says it.
    interrupted = any(e.get("event") == "interrupted" for e in session.events)
    return VerifyRun(report.session, session.observations, cfg.verify.poses, report.n_skipped, session.truth, bias,
                     interrupted)


def verify_document(loaded: LoadedResult, mode: str, source: Path, verification: cv.Verification,
                    rigid: cv.Verification | None, safety: cv.FrameSafety | None,
                    truth_mm: float | None = None, *, verdict=None, repeated=(), cell: dict | None = None) -> dict:
    """The content of ``verify.yaml`` (module docstring); ``verdict``: `handeye.calib.verdict.judge_verification`'s,
    ``repeated``: the poses that repeat calibration poses (`handeye.calib.verify.repeated_poses`); ``cell``: who
    verified, where, with what (`handeye.app.provenance.cell`)."""
    setup = loaded.model.setup
    doc = {
        "format": VERIFY_FORMAT, "version": VERIFY_VERSION, "setup": setup.value, "equation": setup.equation,
        **({"verdict": verdict.to_dict()} if verdict is not None else {}),
        "per_pose_note": per_pose_phrase(verification),
        **({"cell": cell} if cell is not None else {}),
        "mode": mode,
        "result": {"path": str(loaded.path), "solver": loaded.model.method, "camera_transform": setup.camera_name,
                   "camera_correction_applied": loaded.model.correction.as_array().tolist()},
        "source": str(source),
        "verification": verification.to_dict(),
    }
    if rigid is not None:
        doc["rigid_export"] = {"note": "camera_transform_raw_points on the uncorrected points: what ROS/URDF "
                                       "consumers of the exports get", **rigid.to_dict()}
    if safety is not None:
        doc["frame_safety"] = safety.to_dict()
    doc["repeated_calibration_poses"] = [int(i) for i in repeated]
    if truth_mm is not None:
        doc["truth"] = {"calibration_error_mm": truth_mm,
                        "note": "RMS over the same poses of the result's marker against the simulator's true one"}
    return doc


def write_verify(doc: dict, directory: Path) -> Path:
    """``directory/verify.yaml``."""
    path = Path(directory) / "verify.yaml"
    path.write_text("# handeye verify: a result judged on samples it did not see (base frame, mm and deg)\n"
                    + yaml.safe_dump(json.loads(json.dumps(doc)), sort_keys=False, width=1000))
    return path
