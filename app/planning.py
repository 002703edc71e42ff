"""Where the active run moves next: optimal (`handeye.calib.planner`), random, or a file (``plan.json``).

Each pose source hands `handeye.app.runs.calibrate.run_calibration` one `Target` at a
time. Validity is checked twice before a motion: by the planner (marker in
view with a margin, depth range, view angle, keep-out boxes) and by the robot
driver's own limit check (`reachable`, the same `check_target` that
``move_to`` runs again before sending anything).

``plan.json`` (written by ``handeye plan``, replayed by ``calibrate --poses
plan.json``)::

    {"format": "handeye-plan", "version": 1, "setup": ..., "equation": ...,
     "camera_transform": "T_base_cam" | "T_flange_cam", "prior": ...,
     "noise_model": ..., "start": {"T_base_flange": 4x4, "q": 6},
     "expected_robot_time_s": ...,
     "poses": [{"index", "kind": "start"|"optimal", "T_base_flange": 4x4,
                "ur_pose": [x, y, z, rx, ry, rz], "q": 6 (rad),
                "pixel": [u, v], "expected_sigma_mm", "expected_sigma_deg",
                "travel_s"}, ...]}

Units: m, rad, s; the expected 1-sigma (worst axis of the camera transform
after that pose is sampled) in mm and deg, as labelled.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from handeye.app.config import CalibrateConfig, Config
from handeye.app.errors import ConfigError, SessionError
from handeye.calib import model
from handeye.calib import planner as pl
from handeye.calib import transforms as tf
from handeye.calib.api import AUTO
from handeye.calib.auto import CONSIDER_SIGMA, MIN_SAMPLES_CAMERA
from handeye.calib.errors import CalibrationError
from handeye.calib.noise import anchored_point_cov, default_point_cov
from handeye.calib.predict import predicted_pixel
from handeye.calib.result import worst_axis_sigma
from handeye.calib.setup import Setup
from handeye.calib.vision.extract import TargetConfig
from handeye.drivers.errors import LimitViolationError
from handeye.drivers.robot.registry import robot_limits

log = logging.getLogger(__name__)

PLAN_FORMAT = "handeye-plan"
PLAN_VERSION = 1
#: Samples (with marker orientations) before a first estimate for planning is tried ...
EARLY_SAMPLES = 3
#: ... and the largest predicted 1-sigma (mm, deg) at which it is trusted to plan with.
EARLY_MAX_SIGMA = (20.0, 2.0)
#: 1-sigma of a measured marker orientation that comes without a covariance, deg (a single-marker PnP pose).
MARKER_ANGLE_SIGMA_DEG = 2.0
#: How plan.json names the default noise model.
NOISE_DEFAULT = "handeye.calib.noise.default_point_cov (depth-dependent marker-center covariance)"
#: Poses a plan file may hold at most (a plan is a handful of motions, not a trajectory).
MAX_PLAN_POSES = 1000


@dataclass(frozen=True)
class Target:
    """The next motion of an active run.

    ``skip`` is a reason not to move there (recorded as a skip); ``q`` the
    joint target the robot check found (None: the driver chooses).
    """

    T_base_flange: np.ndarray
    kind: str
    q: np.ndarray | None = None
    skip: str | None = None


def camera_view(cal: CalibrateConfig, intrinsics, marker: TargetConfig) -> pl.CameraView:
    """The planner's camera model from ``[calibrate]``, the camera intrinsics and ``[marker]``."""
    size = marker.marker_size
    return pl.CameraView(width=intrinsics.width, height=intrinsics.height, fx=intrinsics.fx, fy=intrinsics.fy,
                         cx=intrinsics.cx, cy=intrinsics.cy, margin_px=float(cal.image_margin_px),
                         depth_min_m=float(cal.depth_range_m[0]),
                         depth_max_m=float(cal.depth_range_m[1]), max_view_angle_deg=float(cal.max_view_angle_deg),
                         marker_size_m=float(size))


def planner_config(cfg: Config, **overrides) -> pl.PlannerConfig:
    """`handeye.calib.planner.PlannerConfig` from ``[calibrate]`` and the robot's workspace box."""
    cal, limits = cfg.calibrate, robot_limits(cfg.robot)
    kw = dict(translation_range_m=cal.translation_range_m, tilt_deg=cal.tilt_deg,
              workspace_min=limits.workspace_min, workspace_max=limits.workspace_max,
              keep_out=tuple(pl.KeepOut(min=b[0], max=b[1]) for b in cal.keep_out),
              clearance_m=cal.clearance_m, travel_weight=cal.travel_weight,
              speed_m_s=limits.speed_m_s, acceleration_m_s2=limits.acceleration_m_s2)
    kw.update(overrides)
    return pl.PlannerConfig(**kw)


def reachable(robot) -> pl.Reachable | None:
    """The robot driver's own limit check (`Robot.check_target`) as the planner's callback (None without a robot).

    ``check_target`` (the UR's: IK nearest the previous joints within the joint limits,
    workspace box and tilt cone along the path, no branch jump) sends nothing.
    """
    if robot is None:
        return None

    def ok(T_base_flange, q_from):
        try:
            return robot.check_target(T_base_flange, q_start=q_from)
        except LimitViolationError:
            return None

    return ok


def _facing(point_cam: np.ndarray) -> np.ndarray:
    """A marker pose at ``point_cam`` facing the camera squarely (its normal along the viewing ray)."""
    z = -point_cam / np.linalg.norm(point_cam)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    return tf.make_transform(np.column_stack([x, np.cross(z, x), z]), point_cam)


def with_marker_rotation(setup: str, X, Y, rotation_known: bool, A, T_cam_marker, point_cam) -> tuple:
    """(X, Y) with the marker-side rotation filled in when the solver did not estimate it.

    Point-only solvers (YKronT') leave it at identity; the planner needs it
    to know which way the marker faces. Taken from the measured marker
    orientations ``T_cam_marker`` (None entries ignored) at flange poses
    ``A``; without any, the marker is assumed to face the camera squarely at
    ``A[0]``, where it was seen at ``point_cam``.
    """
    if rotation_known:
        return X, Y
    have = [i for i, B in enumerate(T_cam_marker) if B is not None]
    if have:
        return pl.marker_rotation(setup, X, Y, np.array([A[i] for i in have]), np.array([T_cam_marker[i] for i in have]))
    return pl.marker_rotation(setup, X, Y, np.asarray(A[0])[None], _facing(np.asarray(point_cam, float))[None])


def camera_correction(method: str, estimate) -> tuple | None:
    """``(theta, free, sigma)`` of the camera correction for the planner when the run's solver is ``auto``
    (None otherwise), so that it plans for, and predicts the covariance of, what ``auto`` reports.

    ``auto`` estimates the depth scale / offset and focal scale the samples
    determine and widens the covariance by a typical error (`handeye.calib.auto.CONSIDER_SIGMA`)
    for the others: all three are unknowns here, the estimated ones with a
    weak prior at their estimate, the others with that typical error as prior.
    """
    if method != AUTO:
        return None
    cc = estimate.auto.camera_correction if estimate is not None and estimate.auto is not None else {}
    theta = np.array([cc[n].value if n in cc else 0.0 for n in model.CAMERA_PARAMS])
    sigma = np.array([pl.CORRECTION_PRIOR_SIGMA if n in cc and cc[n].estimated else CONSIDER_SIGMA[n]
                      for n in model.CAMERA_PARAMS])
    return theta, (True, True, True), sigma


def _estimate_transforms(setup: str, estimate, observations) -> tuple:
    return with_marker_rotation(setup, estimate.X, estimate.Y, estimate.marker_rotation_known,
                                [o.T_base_flange for o in observations], [o.T_cam_marker for o in observations],
                                observations[0].point_cam)


def random_pose(T_start: np.ndarray, cfg: CalibrateConfig, rng: np.random.Generator) -> np.ndarray:
    """A flange pose around ``T_start``: each axis offset uniform in +-range, tilt <= cfg.tilt_deg.

    The rotation is applied about the flange origin (in the base frame), so the
    tilt does not swing the flange away from its sampled position.
    """
    T_start = tf.check_transform(T_start, "T_start")
    R = tf.random_rotations(1, np.deg2rad(cfg.tilt_deg), rng)[0]
    dt = rng.uniform(-cfg.translation_range_m, cfg.translation_range_m, size=3)
    return tf.make_transform(R @ T_start[:3, :3], T_start[:3, 3] + dt)


def _same_pose(T1, T2) -> bool:
    rot, dist = tf.pose_error(T1, T2)
    return bool(dist < 1e-3 and rot < np.deg2rad(0.1))


class RandomPoses:
    """Uniform poses around the start (`random_pose`); skips those the estimate puts outside the image."""

    def __init__(self, start: np.ndarray, cal: CalibrateConfig, intrinsics, rng: np.random.Generator):
        self.start, self.cal, self.intrinsics, self.rng = start, cal, intrinsics, rng
        self.done_reason = "max_attempts"

    def next(self, state, estimate, observations) -> Target:
        T = random_pose(self.start, self.cal, self.rng)
        if estimate is not None and predicted_pixel(estimate, T, self.intrinsics, self.cal.image_margin_px) is None:
            return Target(T, "random", skip="marker predicted outside the image")
        return Target(T, "random")


class OptimalPoses:
    """Sample where the flange is, then a model-free bootstrap, then information-optimal poses.

    The bootstrap (`handeye.calib.planner.bootstrap_poses`) is sized from the first
    measurement so the marker provably stays in view; once a solver gives an
    estimate, every pose comes from `handeye.calib.planner.PosePlanner` at the
    current estimate, with the image margin widened by the predicted pixel
    uncertainty.
    """

    def __init__(self, cfg: Config, start: np.ndarray, view: pl.CameraView, robot, rng: np.random.Generator):
        self.cfg, self.start, self.view, self.rng = cfg, start, view, rng
        self.pcfg = planner_config(cfg)
        self.reachable = reachable(robot)
        self.bootstrap: list[np.ndarray] | None = None
        self.done_reason = "max_attempts"

    def next(self, state, estimate, observations) -> Target | None:
        setup = self.cfg.setup
        # The bootstrap's guarantee rests on a sample at the start pose (a resumed session may not have one);
        # while the marker is not seen there, the run's max_missed_frames ends it.
        at_start = [o for o in observations if _same_pose(o.T_base_flange, self.start)]
        if self.bootstrap is None and not at_start and estimate is None:
            return Target(self.start, "start", q=state.q if _same_pose(state.T_base_flange, self.start) else None)
        if self.bootstrap is None and at_start:
            first = at_start[0]
            self.bootstrap = list(pl.bootstrap_poses(self.start, setup, self.view, first.point_cam, self.pcfg,
                                                     lever_max_m=self.cfg.calibrate.lever_max_m,
                                                     view_angle_deg=view_angle_bound(first, self.pcfg.uncertainty_k)))
            if not self.bootstrap:
                log.warning("the marker is too close to the image border (or too oblique) for a safe bootstrap")
        if estimate is None:
            estimate = _early_estimate(setup, observations)
        if estimate is None:
            while self.bootstrap:
                T = self.bootstrap.pop(0)
                q = self.reachable(T, state.q) if self.reachable is not None else None
                if self.reachable is None or q is not None:
                    return Target(T, "bootstrap", q=q)
                log.info("bootstrap pose unreachable, next one")
            self.done_reason = "no_estimate_after_bootstrap"
            return None
        X, Y = _estimate_transforms(setup, estimate, observations)
        planner = pl.PosePlanner(setup, X, Y, self.view, self.pcfg,
                                 correction=camera_correction(self.cfg.calibrate.method, estimate))
        planner.add(np.array([o.T_base_flange for o in observations]))
        pose = planner.next_pose(self.start, state.T_base_flange, state.q, self.rng, self.reachable)
        if pose is None:
            self.done_reason = "no_valid_pose"
            log.warning("no valid pose among %d candidates (%s)", self.pcfg.n_candidates,
                        dict(planner.stats.reasons))
            return None
        return Target(pose.T_base_flange, "optimal", q=pose.q)


def view_angle_bound(observation, k: float) -> float:
    """The marker's view angle at a sample, deg, plus ``k`` standard deviations of its measured orientation
    (`pose_cov`; `MARKER_ANGLE_SIGMA_DEG` without one): what the bootstrap may rely on.

    0 when the sample has no marker orientation (the bootstrap then assumes the marker faces the camera).
    """
    B = observation.T_cam_marker
    if B is None:
        return 0.0
    angle = float(np.degrees(np.arccos(np.clip(-B[:3, 2] @ B[:3, 3] / np.linalg.norm(B[:3, 3]), -1, 1))))
    cov = observation.pose_cov
    sigma = MARKER_ANGLE_SIGMA_DEG if cov is None else \
        float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(np.asarray(cov)[:3, :3])[-1], 0.0))))
    return angle + k * sigma


def _early_estimate(setup: str, observations):
    """A first estimate for planning before the run's solver has enough samples (None if not possible).

    From `EARLY_SAMPLES` samples with marker orientations: YQuatT' (paper,
    from poses), then ML refinement on the marker centers
    (`handeye.calib.refine.refine`), so the estimate and the planner's uncertainty
    come from the same point model; used only when its predicted 1-sigma is
    below `EARLY_MAX_SIGMA` (the bootstrap continues otherwise).
    """
    from handeye.calib.api import solve
    from handeye.calib.problem import CalibrationProblem
    from handeye.calib.refine import refine

    if len(observations) < EARLY_SAMPLES or any(o.T_cam_marker is None or o.point_cov is None
                                                 for o in observations):
        return None
    A = np.array([o.T_base_flange for o in observations])
    try:
        start = solve("YQuatT'", A, np.array([o.T_cam_marker for o in observations]), setup=setup)
        est = refine(start, CalibrationProblem.from_arrays(A, np.array([o.point_cam for o in observations]),
                                                           setup=setup,
                                                           point_cov=np.array([o.point_cov for o in observations])))
    except CalibrationError as e:
        log.info("no early estimate from %d samples: %s", len(observations), e)
        return None
    s_rot, s_t = est.sigma
    if s_t * 1e3 > EARLY_MAX_SIGMA[0] or np.degrees(s_rot) > EARLY_MAX_SIGMA[1]:
        log.info("early estimate too uncertain to plan with (%.1f mm, %.2f deg)", s_t * 1e3, np.degrees(s_rot))
        return None
    return est


class FilePoses:
    """The poses of a plan file, in order (each is checked again by the robot before it moves)."""

    def __init__(self, path: Path, setup: str, cal: CalibrateConfig, intrinsics):
        self.plan = read_plan(path)
        if self.plan["setup"] != setup:
            raise ConfigError(f"{path} is a plan for {self.plan['setup']}, the config is {setup}")
        self.poses = [np.asarray(p["T_base_flange"], dtype=float) for p in self.plan["poses"]]
        self.cal, self.setup, self.intrinsics = cal, setup, intrinsics
        self.done_reason = "plan_done"

    def next(self, state, estimate, observations) -> Target | None:
        if not self.poses:
            return None
        T = self.poses.pop(0)
        if estimate is not None and predicted_pixel(estimate, T, self.intrinsics, self.cal.image_margin_px) is None:
            return Target(T, "file", skip="marker predicted outside the image")
        return Target(T, "file")


def make_pose_source(cfg: Config, robot, intrinsics, start: np.ndarray, rng: np.random.Generator):
    """The pose source named by ``calibrate.poses``: ``optimal``, ``random`` or a plan file path."""
    kind = cfg.calibrate.poses
    if kind == "optimal":
        return OptimalPoses(cfg, start, camera_view(cfg.calibrate, intrinsics, cfg.marker), robot, rng)
    if kind == "random":
        return RandomPoses(start, cfg.calibrate, intrinsics, rng)
    return FilePoses(Path(kind), cfg.setup, cfg.calibrate, intrinsics)


def check_poses_option(value: str) -> str:
    """``optimal``, ``random`` or an existing plan file (checked before the robot moves)."""
    if value in ("optimal", "random"):
        return value
    read_plan(Path(value))
    return value


# --------------------------------------------------------------------------- plan files


def _m(T) -> list:
    return np.asarray(T, dtype=float).tolist()


def make_plan(cfg: Config, X, Y, T_start, q_start, intrinsics, robot, rng: np.random.Generator, *,
              prior: str, n: int | None = None, start_measurement=None
              ) -> tuple[dict, list[pl.PlannedPose], pl.PosePlanner]:
    """A pose list from a known cell (prior X, Y), without moving: the plan document and the planned poses.

    The first pose is the start pose itself (the run samples where it
    stands); then optimal poses until the expected 1-sigma is below the
    ``[calibrate]`` targets (after ``min_samples``) or ``samples`` poses.
    ``start_measurement``: ``(point_cam, point_cov)`` the camera measured at
    the start pose; the expected 1-sigma then uses this camera's noise level
    (`handeye.calib.noise.anchored_point_cov`), else the default depth model's.
    """
    cal = cfg.calibrate
    n = cal.samples if n is None else n
    view = camera_view(cal, intrinsics, cfg.marker)
    if start_measurement is None:
        point_cov, noise = default_point_cov, NOISE_DEFAULT
    else:
        point_cov = anchored_point_cov(*start_measurement)
        S, p = np.asarray(start_measurement[1]), np.asarray(start_measurement[0])
        r = p / np.linalg.norm(p)
        noise = (f"handeye.calib.noise.anchored_point_cov: the default depth dependence at the levels measured at "
                 f"the start ({np.sqrt(r @ S @ r) * 1e3:.2f} mm along the ray at {p[2]:.2f} m)")
    planner = pl.PosePlanner(cfg.setup, X, Y, view, planner_config(cfg, uncertainty_k=0.0), point_cov=point_cov,
                             correction=camera_correction(cal.method, None))
    start_ok = planner.screen(np.asarray(T_start)[None])[0][0]
    if not start_ok:
        raise CalibrationError("with the prior calibration the marker is not in view at the current robot pose: "
                               "jog the robot to where the camera sees the marker, or check --prior")
    planner.add(T_start)

    def expected(n_samples: int) -> np.ndarray:
        # auto keeps the camera parameters at nominal, widened by their typical errors, below MIN_SAMPLES_CAMERA.
        considered = cal.method == AUTO and n_samples < MIN_SAMPLES_CAMERA
        return planner.consider_cov() if considered else planner.camera_cov()

    p0 = planner.marker_in_camera(np.asarray(T_start)[None])[0, :3, 3]
    start = pl.PlannedPose(np.asarray(T_start, float), None if q_start is None else np.asarray(q_start, float), 0.0,
                           0.0, view.project(p0), p0, expected(1))
    poses = [start]
    T_cur, q_cur = np.asarray(T_start, float), q_start
    check = reachable(robot) if robot is not None else None
    while len(poses) < n:
        s_rot, s_t = worst_axis_sigma(poses[-1].cov)
        if len(poses) >= cal.min_samples and cal.target_sigma_mm > 0 and cal.target_sigma_deg > 0 \
                and s_t * 1e3 <= cal.target_sigma_mm and np.degrees(s_rot) <= cal.target_sigma_deg:
            break
        pose = planner.next_pose(T_start, T_cur, q_cur, rng, check)
        if pose is None:
            log.warning("plan stops after %d poses: no valid candidate (%s)", len(poses), dict(planner.stats.reasons))
            break
        planner.add(pose.T_base_flange)
        poses.append(dataclasses.replace(pose, cov=expected(len(poses) + 1)))
        T_cur, q_cur = pose.T_base_flange, pose.q
    return plan_document(cfg.setup, poses, prior, T_start, q_start, noise), poses, planner


def plan_document(setup: str, poses: list[pl.PlannedPose], prior: str, T_start, q_start,
                  noise_model: str = NOISE_DEFAULT) -> dict:
    """The ``plan.json`` document (module docstring) of planned poses."""
    rows = []
    for i, p in enumerate(poses):
        s_rot, s_t = worst_axis_sigma(p.cov)
        s_deg, s_mm = float(np.degrees(s_rot)), s_t * 1e3
        rows.append({"index": i, "kind": "start" if i == 0 else "optimal", "T_base_flange": _m(p.T_base_flange),
                     "ur_pose": tf.to_ur_pose(p.T_base_flange).tolist(),
                     "q": None if p.q is None else np.asarray(p.q).tolist(),
                     "pixel": np.asarray(p.pixel).tolist(), "expected_sigma_mm": s_mm, "expected_sigma_deg": s_deg,
                     "travel_s": p.travel_s})
    setup = Setup(setup)
    cam = setup.camera_name
    equation = f"A_i X = Y B_i, X = {setup.x_name}, Y = {setup.y_name}"
    return {"format": PLAN_FORMAT, "version": PLAN_VERSION, "setup": setup, "equation": equation,
            "camera_transform": cam, "prior": prior,
            "noise_model": noise_model,
            "start": {"T_base_flange": _m(T_start), "q": None if q_start is None else np.asarray(q_start).tolist()},
            "expected_robot_time_s": float(sum(p.travel_s for p in poses)), "poses": rows}


def write_plan(doc: dict, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return path


def read_plan(path: Path) -> dict:
    """Read and validate a ``plan.json``; raises SessionError naming the file and the bad entry."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SessionError(f"--poses: no such plan file {path} (or use 'optimal' / 'random')") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SessionError(f"{path}: not a readable plan file: {e}") from None
    if not isinstance(doc, dict) or doc.get("format") != PLAN_FORMAT:
        raise SessionError(f"{path}: not a {PLAN_FORMAT} file (write one with 'handeye plan')")
    if doc.get("version") != PLAN_VERSION:
        raise SessionError(f"{path}: plan version {doc.get('version')!r}, this handeye reads {PLAN_VERSION}")
    if doc.get("setup") not in tuple(Setup):
        raise SessionError(f"{path}: setup must be eye_to_hand or eye_in_hand, got {doc.get('setup')!r}")
    poses = doc.get("poses")
    if not isinstance(poses, list) or not 0 < len(poses) <= MAX_PLAN_POSES:
        raise SessionError(f"{path}: 'poses' must be a list of 1..{MAX_PLAN_POSES} poses")
    for i, p in enumerate(poses):
        try:
            tf.check_transform(p["T_base_flange"], f"poses[{i}].T_base_flange")
        except (KeyError, TypeError, ValueError, CalibrationError) as e:
            raise SessionError(f"{path}: poses[{i}]: T_base_flange must be a rigid 4x4 transform ({e})") from None
    return doc
