"""The dry-run plan: the poses of an active run, planned without moving, for review.

Writes ``plan.json`` (format in `handeye.app.planning`: joint and Cartesian targets,
expected 1-sigma after each pose) and a rerun recording beside it (flange
poses, camera frustum, predicted marker view per pose); ``handeye calibrate
--poses plan.json`` replays it. The robot connection is read-only. Eye-to-hand
plans ``T_base_cam``, eye-in-hand ``T_flange_cam``.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from handeye.app import devices, planning
from handeye.app.config import Config
from handeye.app.errors import ConfigError, SessionError
from handeye.app.session import new_output_dir, read_session
from handeye.app.viz import Viz
from handeye.calib import transforms as tf
from handeye.calib.api import solve_observations
from handeye.calib.errors import ExtractionError, HandeyeError
from handeye.calib.setup import Setup

log = logging.getLogger(__name__)


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
    SessionError
        The prior cannot be read or is of the other setup.
    """
    setup = Setup(cfg.setup)
    if prior is None:
        truth = devices.truth(camera)
        if not truth:
            raise ConfigError("plan needs a prior calibration of this cell on real hardware: "
                              "--prior result.json (or a session directory)")
        return truth[setup.x_name], truth[setup.y_name], "simulator truth (the rendered camera's mounting)"
    prior = Path(prior)
    if (prior / "session.json").exists():
        session = read_session(prior)
        if session.setup != setup:
            raise SessionError(f"prior session {prior} is {session.setup}, the config is {setup}")
        obs = session.observations
        res = solve_observations(cfg.calibrate.method, obs, setup, refine=cfg.calibrate.refine)
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
    except SessionError:
        raise
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, HandeyeError) as e:
        raise SessionError(f"--prior {prior}: not a handeye result.json or session directory ({e})") from None
    X, Y = (cam, mark) if setup.camera_on_flange else (mark, cam)
    if not known:
        # Point-only result: take the marker as seen squarely where the prior predicts it at the start pose.
        T_cm = tf.invert(T_start @ X) @ Y if setup.camera_on_flange else tf.invert(Y) @ T_start @ X
        X, Y = planning.with_marker_rotation(setup, X, Y, False, [T_start], [None], T_cm[:3, 3])
    return X, Y, f"result {prior}"


def measure_start(cfg: Config, camera) -> tuple | None:
    """``(point_cam, point_cov)`` of the marker in one frame where the robot stands, so that the plan expects
    this camera's noise (None, with a warning, when the frame shows no marker: the default model is used)."""
    try:
        m = devices.make_measure(cfg)(camera.read())
    except ExtractionError as e:
        log.warning("no marker measurement at the start pose (%s): expected 1-sigma from the default noise model", e)
        return None
    return m.point_cam, m.point_cov


def plan(cfg: Config, out: Path | None = None, *, prior: Path | None = None) -> PlanOutput:
    """Plan the poses of an active run without moving (read-only robot connection): write ``out``
    (plan.json, see `handeye.app.planning`; by default ``plan.json`` in a new directory under ``session.root``, not
    the working directory) and a rerun recording beside it."""
    rng = np.random.default_rng(cfg.calibrate.seed)
    with devices.open_robot(cfg, read_only=True) as robot, devices.open_camera(cfg, robot) as camera:
        state = robot.read()
        X, Y, prior_name = load_prior(cfg, prior, camera, state.T_base_flange)
        doc, poses, _ = planning.make_plan(cfg, X, Y, state.T_base_flange, state.q, camera.intrinsics, robot, rng,
                                           prior=prior_name, start_measurement=measure_start(cfg, camera))
        intrinsics = camera.intrinsics
    if out is None:
        out = new_output_dir(cfg.session.root, cfg.setup, "plan") / "plan.json"
    path = planning.write_plan(doc, out)
    rrd = None
    if cfg.viz.enabled:
        rrd = Path(out).with_suffix(".rrd")
        with Viz(cfg.setup, rrd, viewer=cfg.viz.viewer, viewer_bind=cfg.viz.viewer_bind) as viz:
            viz.plan(poses, X, Y, intrinsics, planning.camera_view(cfg.calibrate, intrinsics, cfg.marker).marker_size_m)
    return PlanOutput(doc, path, rrd)
