"""Long runs give up clearly and stay within their disk budget.

- calibrate stops after ``calibrate.max_missed_frames`` consecutive frames without a marker
  and says what the camera saw;
- monitor records a ``device_error`` event (as calibrate does) when the controller drops;
- monitor keeps frames only for its last ``keep_frames`` samples and rotates the rerun recording.
Eye-to-hand simulated cell (``Y = T_base_cam``).
"""

import threading

import numpy as np
import pytest

from handeye.app import devices
from handeye.app.cli import main
from handeye.app.runs.monitor import run_monitor
from handeye.app.session import SessionWriter, read_session
from handeye.app.viz import Viz
from handeye.calib import simulate
from handeye.calib.observation import Observation
from handeye.calib.setup import Setup
from handeye.drivers.errors import DeviceError

SIM_TOML = open("config/sim.toml").read()


def test_calibrate_gives_up_when_the_marker_is_never_seen(tmp_path, capsys, loopback):
    p = tmp_path / "c.toml"
    text = SIM_TOML.replace('host = "127.0.0.2"', f'host = "{loopback(20)}"').replace("marker_id = 0", "marker_id = 7")
    p.write_text(text.replace("max_missed_frames = 10", "max_missed_frames = 4"))
    # Random poses: the planner's own start check (3 tries at the start pose) would stop first.
    assert main(["calibrate", "--yes-move", "-c", str(p), "--session-root", str(tmp_path), "--no-viz",
                 "--poses", "random"]) == 1
    captured = capsys.readouterr()
    out = captured.out
    assert "stopped by: no_marker" in out and "gave up" in out, captured.err
    assert "4x marker 7 of DICT_4X4_50 not found" in out  # what the camera saw
    session = read_session(next(tmp_path.glob("*_eye_to_hand")))
    missed = [s for s in session.skipped if s["reason"].startswith("marker 7")]
    assert len(missed) == 4 and not session.observations  # 4 frames, not max_attempts = 200
    gave_up = [e for e in session.events if e["event"] == "gave_up"]
    assert gave_up and gave_up[0]["missed_frames"] == 4 and "marker 7" in gave_up[0]["camera_saw"]


@pytest.mark.slow
def test_monitor_records_device_error_on_a_dropped_controller(sim_config, tmp_path, loopback):
    cfg = sim_config(loopback(21))
    cfg = cfg.model_copy(update={"monitor": cfg.monitor.model_copy(update={"still_s": 0.05, "poll_s": 0.01,
                                                                           "duration_s": 30.0})})
    rng = np.random.default_rng(0)
    with devices.open_robot(cfg, read_only=True) as robot, devices.open_camera(cfg, robot) as camera:
        dropper = threading.Timer(1.0, lambda: robot.sim.drop(refuse_s=5.0))
        dropper.start()
        writer = SessionWriter.create(cfg.session.root, cfg.setup)
        try:
            with writer, Viz(Setup.EYE_TO_HAND, enabled=False) as viz, pytest.raises(DeviceError):
                run_monitor(robot, camera, devices.make_measure(cfg), devices.make_engine(cfg),
                            devices.make_solve(cfg.calibrate, cfg.setup, rng), writer, cfg.monitor, viz)
        finally:
            dropper.cancel()
    events = read_session(writer.path).events
    assert [e["event"] for e in events] == ["device_error"]
    assert events[0]["error"] and "n_samples" in events[0]


def test_frames_kept_only_for_the_last_samples(tmp_path):
    d = simulate.realistic_cell(6, np.random.default_rng(2))
    img, depth = np.zeros((8, 8, 3), np.uint8), np.ones((8, 8), np.float32)
    with SessionWriter.create(tmp_path, "eye_to_hand", name="s", keep_frames=2) as w:
        for i in range(5):
            w.add_sample(Observation(i, float(i), d.A[i], d.points[i], d.point_cov[i]), color=img, depth=depth)
        w.add_skip(9.0, "marker not found", color=img, depth=depth)
        w.drop_frames(3)  # already pruned: nothing to do, not counted twice
    frames = sorted(p.name for p in (tmp_path / "s" / "frames").iterdir())
    assert frames == ["000004_color.png", "000004_depth.png", "000005_color.png", "000005_depth.png"]
    s = read_session(tmp_path / "s")
    assert len(s.observations) == 5  # every sample line stays
    assert s.load_frames(s.observations[0]) == (None, None)  # pruned: not stored any more
    color, dep = s.load_frames(s.observations[4])
    assert color.shape == (8, 8, 3) and dep.shape == (8, 8)
    assert w.frames_pruned == 4  # monitor reports it in its sample_set event


def test_monitor_drops_the_frames_of_samples_its_bounded_set_drops(tmp_path):
    from handeye.app.runs import monitor as mon
    from handeye.app.config import MonitorConfig

    from handeye.calib.monitor import MonitorEngine

    d = simulate.realistic_cell(7, np.random.default_rng(3))
    img = np.zeros((8, 8, 3), np.uint8)
    cfg = MonitorConfig(keep_samples=6, keep_recent=1, arm_samples=6)
    with SessionWriter.create(tmp_path, "eye_to_hand", name="s") as w:
        kept = [w.add_sample(Observation(i, float(i), d.A[i], d.points[i]), color=img) for i in range(7)]
        dropped = mon.bound_estimation_set(kept, cfg, MonitorEngine())     # not armed: the oldest sample goes
        w.drop_frames(dropped.index)
    assert dropped.index == 0 and [o.index for o in kept] == [1, 2, 3, 4, 5, 6]
    assert sorted(p.name for p in (tmp_path / "s" / "frames").iterdir()) == [
        f"00000{i}_color.png" for i in range(1, 7)]


def test_recording_is_rotated(tmp_path):
    path = tmp_path / "recording.rrd"
    with Viz(Setup.EYE_TO_HAND, path) as viz:
        viz.event(0.0, "x" * 10_000)
        viz._file.flush()
        viz.rotate(1.0)  # anything is larger than 1 byte
        viz.event(1.0, "after the rotation")
        viz.rotate(1e9)  # below the budget: nothing happens
    assert (tmp_path / "recording.old.rrd").stat().st_size > 10_000
    assert path.exists() and path.stat().st_size > 0
