"""Planned poses against the robot's own limit checks, `handeye plan`, and replaying a plan."""

import json
from pathlib import Path

import numpy as np
import pytest

from handeye.app import devices, planning
from handeye.app.cli import main
from handeye.app.config import load_config
from handeye.app.runs.calibrate import calibrate
from handeye.app.session import read_session
from handeye.calib import planner as pl
from handeye.calib import transforms as tf
from handeye.app.errors import SessionError
from handeye.drivers.camera.base import CameraIntrinsics

pytestmark = pytest.mark.slow

INTR = CameraIntrinsics(640, 480, 570.0, 570.0, 319.5, 239.5)


def _truth(cfg):
    c = cfg.camera
    return c.X, c.Y


@pytest.mark.parametrize("config", ["config/sim.toml", "config/eye_in_hand.toml"])
def test_planned_poses_pass_the_robots_own_check_and_keep_the_marker_in_view(config, sim_config, loopback):
    """From a rough estimate (2 mm / 0.2 deg off, with a matching uncertainty): 25 planned poses, each
    passing `URRobot.check_target` from the previous joints and showing the marker under the true mounting."""
    cfg = sim_config(loopback(20 + ("eye" in config)), base=load_config(config))
    X, Y = _truth(cfg)
    rng = np.random.default_rng(5)
    bump = tf.from_rotvec_translation(rng.normal(0, np.deg2rad(0.2), 3), rng.normal(0, 0.002, 3))
    Xe, Ye = (X, bump @ Y) if cfg.setup == "eye_to_hand" else (X @ bump, Y)
    view = planning.camera_view(cfg.calibrate, INTR, cfg.marker)
    with devices.open_robot(cfg, read_only=True) as robot:
        state = robot.read()
        planner = pl.PosePlanner(cfg.setup, Xe, Ye, view, planning.planner_config(cfg, prior_sigma_m=0.004,
                                                                                  prior_sigma_rad=0.004))
        poses = planner.plan(state.T_base_flange, state.q, 25, rng, planning.reachable(robot))
        assert len(poses) == 25
        q = state.q
        for p in poses:
            np.testing.assert_allclose(robot.check_target(p.T_base_flange, q_start=q), p.q)
            q = p.q
    # Planned with a 40 px margin on a wrong estimate; under the truth the marker stays >= 10 px inside.
    truth = pl.PosePlanner(cfg.setup, X, Y, view.model_copy(update={"margin_px": 10.0}), pl.PlannerConfig(uncertainty_k=0))
    assert truth.screen(np.stack([p.T_base_flange for p in poses]))[0].all()
    lo, hi = np.array(cfg.robot.workspace_min), np.array(cfg.robot.workspace_max)
    A = np.stack([p.T_base_flange for p in poses])
    assert np.all(A[:, :3, 3] >= lo) and np.all(A[:, :3, 3] <= hi)


def test_plan_writes_beside_the_sessions_and_names_the_config_used(tmp_path, loopback, capsys, monkeypatch):
    """Without -o the plan and its recording go into a new directory under session.root, not the working
    directory, and the command printed to run it names the config used (it printed '-c <config>')."""
    cfg_file = tmp_path / "my cell.toml"
    cfg_file.write_text(Path("config/sim.toml").read_text().replace('host = "127.0.0.2"', f'host = "{loopback(23)}"'))
    (tmp_path / "cwd").mkdir()
    monkeypatch.chdir(tmp_path / "cwd")
    root = tmp_path / "s"
    assert main(["plan", "-c", str(cfg_file), "--samples", "3", "--until-sigma", "off", "--session-root",
                 str(root)]) == 0
    printed = capsys.readouterr().out
    assert not list((tmp_path / "cwd").iterdir())
    (plan_dir,) = root.iterdir()
    assert plan_dir.name.endswith("_eye_to_hand_plan") and sorted(p.name for p in plan_dir.iterdir()) == [
        "plan.json", "plan.rrd"]
    assert printed.rstrip().endswith(f"replay on the robot: handeye calibrate -c '{cfg_file}' --poses "
                                     f"{plan_dir / 'plan.json'}"), printed


def test_plan_writes_a_plan_that_calibrate_replays(tmp_path, loopback, capsys):
    cfg_file = tmp_path / "sim.toml"
    cfg_file.write_text(Path("config/sim.toml").read_text().replace('host = "127.0.0.2"', f'host = "{loopback(22)}"'))
    out = tmp_path / "plan.json"
    assert main(["plan", "-c", str(cfg_file), "-o", str(out), "--samples", "10", "--until-sigma", "off"]) == 0
    printed = capsys.readouterr().out
    assert "expected 1-sigma" in printed and str(out) in printed
    doc = json.loads(out.read_text())
    assert doc["format"] == "handeye-plan" and doc["setup"] == "eye_to_hand" and len(doc["poses"]) == 10
    assert doc["poses"][0]["kind"] == "start" and all(len(p["q"]) == 6 for p in doc["poses"])
    assert doc["noise_model"].startswith("handeye.calib.noise.anchored_point_cov")  # measured where the robot stands
    # auto's covariance below 12 samples: the camera corrections at nominal, widened by their typical errors.
    sig = [p["expected_sigma_mm"] for p in doc["poses"]]
    assert sig[-1] < 0.02 * sig[0] and 2.0 < sig[-1] < 20.0
    assert out.with_suffix(".rrd").stat().st_size > 0  # flange poses, frustum, marker view per pose
    # The plan is replayed pose by pose.
    cfg = load_config(cfg_file)
    cfg = cfg.model_copy(update={
        "calibrate": cfg.calibrate.model_copy(update={"poses": str(out), "target_sigma_mm": 0.0, "target_sigma_deg": 0.0,
                                                      "min_samples": 5}),
        "session": cfg.session.model_copy(update={"root": str(tmp_path / "s"), "save_frames": False}),
        "viz": cfg.viz.model_copy(update={"enabled": False})})
    run = calibrate(cfg, progress=False)
    assert run.report.stopped_by == "plan_done" and run.report.n_samples == 10 and run.report.n_skipped == 0
    A = np.array([o.T_base_flange for o in read_session(run.report.session).observations])
    planned = np.array([p["T_base_flange"] for p in doc["poses"]])
    assert np.abs(A[:, :3, 3] - planned[:, :3, 3]).max() < 2e-3
    rot, trans = tf.pose_error(run.report.result.T_base_cam, run.truth)
    assert trans < 3e-3 and np.rad2deg(rot) < 0.2
    # The plan expected what the run reports (worst axis, mm).
    assert 0.67 < run.report.result.sigma[1] * 1e3 / sig[-1] < 1.5


def test_bad_plan_files_are_refused_before_any_motion(tmp_path):
    bad = tmp_path / "plan.json"
    bad.write_text('{"format": "handeye-plan", "version": 1, "setup": "eye_to_hand", "poses": [{"T_base_flange": 5}]}')
    with pytest.raises(SessionError, match=r"poses\[0\]"):
        planning.check_poses_option(str(bad))
    with pytest.raises(SessionError, match="no such plan file"):
        planning.check_poses_option(str(tmp_path / "missing.json"))
    assert main(["calibrate", "--yes-move", "--poses", str(bad)]) == 1
