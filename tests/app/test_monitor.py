"""monitor: passive sampling through a read-only robot connection flags a bumped camera."""

import threading

import numpy as np
import pytest
import yaml

from handeye.app import devices
from handeye.app.planning import random_pose
from handeye.app.runs.monitor import run_monitor
from handeye.app.config import Config
from handeye.app.session import SessionWriter, read_session
from handeye.calib import transforms as tf
from handeye.drivers.errors import DeviceError
from handeye.drivers.robot import ur_kinematics as kin

pytestmark = pytest.mark.slow

BUMP_AT = 16  # samples before the camera is knocked


def _mover(sim, start_T, start_q, cal_cfg, stop, rng):
    """Someone else's program moving the robot: jump to a random pose every few tenths of a second."""
    while not stop.is_set():
        q = kin.inverse_nearest(random_pose(start_T, cal_cfg, rng), start_q, "ur10")
        if q is not None:
            sim.set_q(q)
        stop.wait(0.35)


def test_monitor_flags_camera_bump(sim_config, tmp_path, loopback):
    cfg = sim_config(loopback(5))
    data = cfg.model_dump()
    data["monitor"].update(still_s=0.05, poll_s=0.01, max_samples=BUMP_AT + 14, duration_s=90.0, reestimate_samples=2,
                           arm_samples=8, keep_samples=10, keep_recent=4, alarm_hook=f"touch {tmp_path / 'hook-ran'}",
                           # A copy of the file as the hook found it, by why it was written.
                           calibration_hook=f"sh -c 'cp \"$HANDEYE_CALIBRATION\" \"{tmp_path}/$HANDEYE_REASON.yaml\"'")
    cfg = Config.model_validate(data)
    rng = np.random.default_rng(5)
    stop = threading.Event()
    with devices.open_robot(cfg, read_only=True) as robot, devices.open_camera(cfg, robot) as camera:
        with pytest.raises(DeviceError):  # read-only really means read-only
            robot.move_to(robot.read().T_base_flange)
        T_true = np.array(camera.config.T_base_cam)
        # 1 cm and 1 degree: a camera knocked on its tripod.
        T_bumped = tf.from_rotvec_translation([0.0, np.deg2rad(1.0), 0.0], [0.01, 0.0, 0.0]) @ T_true
        n_seen = []

        def on_sample(obs):
            n_seen.append(obs.index)
            if len(n_seen) == BUMP_AT:
                camera.config.T_base_cam = T_bumped.tolist()

        mover = threading.Thread(target=_mover, args=(robot.sim, robot.read().T_base_flange,
                                                      np.array(cfg.robot.initial_q), cfg.calibrate, stop, rng))
        mover.start()
        try:
            writer = SessionWriter.create(cfg.session.root, cfg.setup, truth=devices.truth(camera))
            with writer, devices.make_viz(cfg, writer.path) as viz:
                report = run_monitor(robot, camera, devices.make_measure(cfg), devices.make_engine(cfg),
                                     devices.make_solve(cfg.calibrate, cfg.setup, rng), writer, cfg.monitor, viz,
                                     on_sample=on_sample)
        finally:
            stop.set()
            mover.join()

    assert len(report.alarms) == 1, report.alarms
    alarm = report.alarms[0]
    first_after_bump = n_seen[BUMP_AT]  # session index of the first sample rendered with the bumped camera
    assert first_after_bump <= alarm.sample_index <= first_after_bump + 6
    assert (tmp_path / "hook-ran").exists()
    # re-estimated from post-move samples only: finds the bumped camera, not the old one
    assert report.reestimate is not None
    rot, trans = tf.pose_error(report.reestimate.T_base_cam, T_bumped)
    assert trans < 4e-3 and np.rad2deg(rot) < 0.4, (trans, np.rad2deg(rot))
    # the bounded sample set: at most keep_samples, all taken after the move (the detecting one on), the newest
    # always among them
    after = [i for i in n_seen if i >= alarm.sample_index]
    assert len(report.kept) == min(10, len(after)) and min(report.kept) >= alarm.sample_index
    assert report.kept[-4:] == sorted(report.kept)[-4:] and report.kept[-1] == n_seen[-1]
    session = read_session(report.session)
    assert session.events[-1]["event"] == "sample_set" and session.events[-1]["indices"] == report.kept
    events = [e["event"] for e in session.events]
    core = [e for e in events if e in ("armed", "alarm", "relearnt")]
    assert core[:2] == ["armed", "alarm"]       # armed from its first samples, then the move
    # version 1 in use once armed, version 2 proposed by the re-learn
    assert events.index("armed") < events.index("calibration_version_in_use") < events.index("alarm") \
        < events.index("calibration_version_proposed")
    assert "relearnt" in events
    assert len(session.observations) == report.n_samples
    assert (report.session / "recording.rrd").exists()
    # The calibration hook ran once the engine armed itself (version 1, in the file when it ran). The re-learnt
    # camera is version 2, settling when the run ends: the file holds it pending (the bumped camera) beside
    # version 1 in use, and says MOVED; the hook is told of a version only once it is in use.
    handed = {p.stem: yaml.safe_load(p.read_text()) for p in tmp_path.glob("*.yaml")}
    assert set(handed) == {"armed"}, set(handed)
    assert handed["armed"]["calibration_version"] == 1
    assert tf.pose_error(np.array(handed["armed"]["camera_transform"]["matrix"]), T_true)[1] < 4e-3
    doc = yaml.safe_load((report.session / "calibration_in_use.yaml").read_text())
    assert doc["calibration_version"] == 1 and doc["pending"]["version"] == 2, doc.get("pending")
    assert doc["status"]["level"] == "moved" and "re-learnt as version 2" in doc["status"]["message"]
    relearnt = np.array(doc["pending"]["result"]["camera_transform"]["matrix"])
    assert tf.pose_error(relearnt, T_bumped)[1] < 4e-3
    np.testing.assert_allclose(doc["camera_transform"]["matrix"], handed["armed"]["camera_transform"]["matrix"])
    # What the hook in docs/formats.md starts: the publisher of the version in use (its raw-points transform).
    line = handed["armed"]["ros2_static_transform_publisher"].split()
    assert line[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]


class _StillRobot:
    """A read-only robot that stands still at each of ``poses`` for ``reads`` reads in turn."""

    def __init__(self, poses, reads: int = 6):
        self.poses, self.reads, self.n = poses, reads, 0

    def pose(self):
        return self.poses[(self.n // self.reads) % len(self.poses)]

    def read(self):
        import time

        from handeye.drivers.robot.base import RobotState

        T = self.pose()
        self.n += 1
        return RobotState(time.time(), 0.0, T, np.zeros(6), np.zeros(6), 7, 1)

    def pose_at(self, t_host):
        return self.pose()


def _refusing_engine():
    """An armed monitoring engine that refuses every sample (as `MonitorEngine.update` does a malformed one)."""
    from bench.shift import armed_cell
    from handeye.calib.errors import CalibrationError

    engine = armed_cell(0)[2]

    def update(*args):
        raise CalibrationError("malformed sample")

    engine.update = update
    return engine


def test_a_sample_the_engine_refuses_is_a_recorded_skip_and_the_run_goes_on(tmp_path):
    """`run_monitor` records the engine's refusal as a skip and keeps sampling (no alarm, nothing fused)."""
    from handeye.app.config import load_config
    from handeye.app.viz import Viz
    from handeye.drivers.camera.registry import CAMERAS

    cfg = load_config(None)
    c = cfg.camera
    T_cam_marker = tf.make_transform(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 0.6])
    T0 = np.asarray(c.T_base_cam) @ T_cam_marker @ tf.invert(np.asarray(c.T_flange_marker))
    poses = [tf.make_transform(np.eye(3), [0.03 * k, 0.0, 0.0]) @ T0 for k in range(3)]
    robot = _StillRobot(poses)
    mon = cfg.monitor.model_copy(update={"still_s": 0.0, "poll_s": 0.001, "max_samples": 3, "duration_s": 30.0,
                                         "keep_samples": 0})
    camera = CAMERAS.create(cfg.camera)
    camera.follow(robot.pose)
    updates = []
    with camera, SessionWriter.create(tmp_path, cfg.setup, name="s") as writer, Viz(cfg.setup, None) as viz:
        report = run_monitor(robot, camera, devices.make_measure(cfg), _refusing_engine(), None, writer, mon, viz,
                             on_update=lambda obs, update, rep: updates.append(update), say=lambda s: None)
    assert report.n_samples == 3 and updates == [None, None, None]
    # Nothing fused: the estimate is still the camera the engine was armed with.
    assert report.alarms == [] and report.last is None and report.estimate is not None
    skips = [s for s in read_session(tmp_path / "s").skipped if s["reason"] == "monitoring engine: malformed sample"]
    assert len(skips) == 3


def _poses_in_view(cfg, n: int = 40) -> list:
    """``n`` flange poses around one that puts the marker 0.6 m in front of the simulated camera."""
    c = cfg.camera
    T_cam_marker = tf.make_transform(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 0.6])
    T0 = np.asarray(c.T_base_cam) @ T_cam_marker @ tf.invert(np.asarray(c.T_flange_marker))
    rng = np.random.default_rng(3)
    return [tf.from_rotvec_translation(rng.normal(scale=0.15, size=3), rng.normal(scale=0.06, size=3)) @ T0
            for _ in range(n)]


def _knock_at(camera, engine, seen: list, update, n: int = 14):
    """``update`` (the engine's own) that records each update in ``seen`` and knocks the simulated camera by
    2 cm and about a degree once the armed engine has taken ``n``."""
    def knocking(*args):
        upd = update(*args)
        seen.append(upd)
        if engine.armed and len(seen) == n:
            camera.config.T_base_cam = (tf.from_rotvec_translation([0.0, 0.02, 0.0], [0.02, 0.0, 0.0])
                                        @ np.asarray(camera.config.T_base_cam)).tolist()
        return upd
    return knocking


def test_an_unexpected_error_ends_the_run_with_its_sample_and_alarm_kept(tmp_path, monkeypatch):
    """An error that is not a refused sample, at the sample after an alarm and at the alarm's own sample after it
    was raised: the run ends with `MonitorError` (one line, exit 1: a service restarts it), the sample, the alarm
    and the error are in the session, the alarm was published and its hook ran, the error was told
    (``on_error``: MQTT), and the calibration in use was kept for the next run."""
    from handeye.app import calibration_in_use
    from handeye.app.config import load_config
    from handeye.app.errors import MonitorError
    from handeye.app.viz import Viz
    from handeye.drivers.camera.registry import CAMERAS

    cfg = load_config(None)
    poses, rng = _poses_in_view(cfg), np.random.default_rng(3)
    for where in ("next sample", "alarm sample"):
        robot = _StillRobot(poses, reads=8)
        mon = cfg.monitor.model_copy(update={"still_s": 0.0, "poll_s": 0.001, "max_samples": 40, "duration_s": 60.0,
                                             "arm_samples": 8, "reestimate_samples": 2,
                                             "alarm_hook": f"touch {tmp_path / where.replace(' ', '_')}"})
        camera = CAMERAS.create(cfg.camera)
        camera.follow(robot.pose)
        engine = devices.make_engine(cfg)
        seen, told, errors = [], [], []
        knocking = _knock_at(camera, engine, seen, engine.update)

        def update(*args, knocking=knocking, seen=seen):
            if where == "next sample" and any(u.alarm for u in seen):
                raise RuntimeError("a bug in the engine")
            return knocking(*args)

        engine.update = update
        if where == "alarm sample":
            def failing(self, engine, update, t, real=calibration_in_use.InUseFile.update):
                real(self, engine, update, t)
                if update is not None and update.alarm:
                    raise RuntimeError("a bug after the alarm")

            monkeypatch.setattr(calibration_in_use.InUseFile, "update", failing)
        name = where.replace(" ", "-")
        with camera, SessionWriter.create(tmp_path, cfg.setup, name=name) as writer, Viz(cfg.setup, None) as viz:
            with pytest.raises(MonitorError, match="unexpected error at sample") as raised:
                run_monitor(robot, camera, devices.make_measure(cfg), engine,
                            devices.make_solve(cfg.calibrate, cfg.setup, rng), writer, mon, viz,
                            on_update=lambda obs, upd, rep: told.append(upd), say=lambda s: None,
                            on_error=lambda obs, message: errors.append((obs.index, message)))
        monkeypatch.undo()
        session = read_session(tmp_path / name)
        events = [e["event"] for e in session.events]
        assert "alarm" in events and events[-1] == "engine_error", events
        failed = session.events[-1]["sample_index"]
        assert failed == session.observations[-1].index          # the sample is kept
        assert errors and errors[0][0] == failed and str(failed) in str(raised.value)
        assert any(u is not None and u.alarm == "moved" for u in told)     # published
        assert (tmp_path / where.replace(" ", "_")).exists()            # the hook ran
        assert calibration_in_use.find(tmp_path / name) is not None


def test_a_ctrl_c_in_the_alarm_hook_ends_the_run_with_the_alarm_published(tmp_path, monkeypatch):
    """Ctrl-C while the moved alarm's hook runs: the run's normal end (the session's interrupted and sample_set
    events), and the alarm reaches what publishes it (MQTT) before it ends: it is not only in the session."""
    import handeye.app.runs.monitor as runs_monitor
    from handeye.app.config import load_config
    from handeye.app.viz import Viz
    from handeye.drivers.camera.registry import CAMERAS

    cfg = load_config(None)
    rng = np.random.default_rng(3)
    robot = _StillRobot(_poses_in_view(cfg), reads=8)
    mon = cfg.monitor.model_copy(update={"still_s": 0.0, "poll_s": 0.001, "max_samples": 40, "duration_s": 60.0,
                                         "arm_samples": 8, "reestimate_samples": 2, "alarm_hook": "true"})
    camera = CAMERAS.create(cfg.camera)
    camera.follow(robot.pose)
    engine = devices.make_engine(cfg)
    told = []
    engine.update = _knock_at(camera, engine, [], engine.update)

    def hook(command, env, *field):
        if env.get("HANDEYE_EVENT") == "camera_moved":
            raise KeyboardInterrupt

    monkeypatch.setattr(runs_monitor, "run_hook", hook)
    with camera, SessionWriter.create(tmp_path, cfg.setup, name="s") as writer, Viz(cfg.setup, None) as viz:
        report = run_monitor(robot, camera, devices.make_measure(cfg), engine,
                             devices.make_solve(cfg.calibrate, cfg.setup, rng), writer, mon, viz,
                             on_update=lambda obs, upd, rep: told.append(upd), say=lambda s: None)
    assert [a.kind for a in report.alarms] == ["moved"]
    assert told and told[-1].alarm == "moved"                       # published
    events = [e["event"] for e in read_session(tmp_path / "s").events]
    assert "alarm" in events and events[-2:] == ["interrupted", "sample_set"], events


def test_the_next_run_carries_the_relearnt_camera_over(sim_config, loopback):
    """``[monitor] carry_over``: a run bumped and re-learnt, then the next run on the same (bumped) camera
    continues from the first's calibration_in_use.yaml: it says so, raises no moved alarm, and its estimate is
    the moved camera; the first run armed itself from its own samples, the second's simulated camera starts
    knocked as the first left it."""
    from handeye.app import calibration_in_use
    from handeye.app.production import Bump
    from handeye.app.runs.demo import demo_monitor

    cfg = sim_config(loopback(31))
    data = cfg.model_dump()
    data["monitor"]["carry_over"] = True
    first = demo_monitor(Config.model_validate(data), bump=Bump(18), max_samples=30, progress=False)
    assert [a.kind for a in first.alarms if a.kind == "moved"] == ["moved"] and first.reestimate is not None
    kept = calibration_in_use.find(first.session)
    assert kept is not None and calibration_in_use.latest(first.session.parent, cfg.setup) == kept
    told = []
    import handeye.app.runs.monitor as runs_monitor

    real_say = runs_monitor.say
    runs_monitor.say = lambda text: (told.append(text), real_say(text))
    try:
        second = demo_monitor(Config.model_validate(data), bump=None, max_samples=14, progress=False)
    finally:
        runs_monitor.say = real_say
    assert any(text.startswith(f"continuing from {kept}") for text in told), told
    # The simulated camera stays where the bump left it (`handeye.app.production.carried_knocks`).
    assert f"simulated camera: knocked as {kept} left it (1 knock)" in told, told
    np.testing.assert_allclose(second.truth, first.truth, atol=1e-12)
    assert not second.moved_alarms, [a.info["message"] for a in second.alarms]
    rot, trans = tf.pose_error(second.estimate, first.truth)
    assert trans < 3e-3 and np.rad2deg(rot) < 0.2, (trans, np.rad2deg(rot))
