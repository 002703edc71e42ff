"""The simulated cell behind ROS 2 (config/sim_ros2.toml): calibrate with frames through DDS, monitor with
frames and poses through DDS, /diagnostics seen by another process. Real DDS on loopback, a test-only domain."""

import json
import subprocess
import sys
import time

import numpy as np
import pytest

from handeye.app.config import config_from_dict, load_config
from handeye.app.production import Bump
from handeye.app.runs.calibrate import calibrate
from handeye.app.runs.demo import demo_monitor
from handeye.app.session import read_session
from handeye.calib import transforms as tf
from handeye.calib.change import ChangeDetector
from handeye.calib.vision.extract import extract
from handeye.mocks.render.camera import RenderedCamera
from tests.simulated_ur import process_net

pytestmark = pytest.mark.slow
BUMP_AFTER = 3


def sim_ros2(root, slot: int, **calibrate):
    data = load_config("config/sim_ros2.toml").model_dump()
    host = f"{process_net()}.{slot}"
    data["robot"]["host"] = data["camera"]["robot_host"] = host
    data["calibrate"].update(calibrate)
    data["session"]["root"] = str(root)
    data["viz"]["enabled"] = False
    return config_from_dict(data, "sim_ros2 test")


@pytest.fixture(scope="module")
def calibrated(ros2_graph, tmp_path_factory):
    """calibrate on the simulated cell with its frames through ROS 2 (6 planned poses)."""
    cfg = sim_ros2(tmp_path_factory.mktemp("sessions"), 170, samples=6, min_samples=6)
    return cfg, calibrate(cfg, progress=False)


def test_calibrate_with_frames_from_ros2_is_the_rendered_cameras_calibration(calibrated):
    """Every sample's frame came through DDS pixel for pixel as the in-process rendered camera draws it
    (the k-th read, the k-th noise draw): the same marker points, so the same calibration as ``make demo``'s
    camera gives at these poses."""
    cfg, out = calibrated
    session = read_session(out.report.session)
    assert out.report.n_samples == 6 and out.report.result is not None
    poses = iter([o.T_base_flange for o in session.observations])
    rendered = RenderedCamera(cfg.camera.rendered(), lambda: next(poses))
    rendered.connect()
    for obs in session.observations:
        frame = rendered.read()
        m = extract(frame.color, frame.depth, frame.intrinsics, cfg.marker)
        np.testing.assert_allclose(obs.point_cam, m.point_cam, atol=1e-8)
    rot, trans = tf.pose_error(out.report.result.T_base_cam, out.truth)
    assert trans < 5e-3 and np.rad2deg(rot) < 0.5


def test_monitor_from_ros2_turns_diagnostics_to_error_for_another_process(calibrated, tmp_path):
    """monitor reads frames and poses from ROS 2 (the simulated driver nodes), armed from the calibration;
    the camera is knocked after 3 samples: the moved alarm comes within 5 samples, and a subscriber in
    another process sees /diagnostics go OK -> ERROR with the move's figures."""
    cfg, out = calibrated
    cfg = sim_ros2(cfg.session.root, 171)
    inbox = tmp_path / "diagnostics.jsonl"
    listener = subprocess.Popen([sys.executable, "-m", "tests.app.diagnostics_listener", str(inbox), "300"],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert listener.stdout.readline().strip() == "listening"
        report = demo_monitor(cfg, bump=Bump(BUMP_AFTER, 10.0, 0.5), reference=out.report.session,
                              max_samples=BUMP_AFTER + 6, progress=False)
        time.sleep(1.0)
    finally:
        listener.stdin.close()
        listener.wait(10)
    session = read_session(report.session)
    bumped = next(e for e in session.events if e["event"] == "simulated_bump")["sample_index"]
    moved = [a for a in report.alarms if a.kind == "moved"]
    assert moved, report.alarms
    after = [o.index for o in session.observations if bumped < o.index <= moved[0].sample_index]
    assert 1 <= len(after) <= 5, after
    statuses = [json.loads(line) for line in inbox.read_text().splitlines()]
    levels = [s["level"] for s in statuses]
    assert 0 in levels and 2 in levels[levels.index(0):], levels
    # The alarm's own status carries the move's figures (a timer's status a moment before it may already read the
    # cell's record: "camera moved at <time> (sample n); re-learning ...").
    error = next(s for s in statuses[levels.index(0):]
                 if s["level"] == 2 and "camera moved: the marker" in s["message"])
    # (the sample the test fires at may sit where the knock partly cancels: its own figure is no bound)
    assert float(error["values"]["statistic"]) > ChangeDetector().threshold and float(error["values"]["verify_mm"]) > 0
    assert error["values"]["last_alarm"].startswith(f"moved at sample {moved[0].sample_index}")
    assert {"error_mm", "drift_mm_h", "sigma_mm", "verify_mm", "last_alarm", "samples"} <= set(error["values"])
    assert statuses[-1]["level"] == 3 and statuses[-1]["message"].startswith("monitor stopped")


def _report(n: int, estimate=None, alarms=()):
    from handeye.app.runs.monitor import MonitorReport

    return MonitorReport(session="s", n_samples=n, n_skipped=0, alarms=list(alarms), estimate=estimate,
                         samples_until_armed=0 if estimate is not None else 4)


def test_the_diagnostics_level_says_quiet_drifting_moved_or_away(engine_update):
    """OK calibrated and quiet; WARN drifting or not calibrated yet; ERROR moved (with the move's figures)
    until the level clears, or a device away (until it is back). The verdict is kept without a node (nothing is
    published before `open`)."""
    from types import SimpleNamespace

    from handeye.app.outage import OutageEvent
    from handeye.app.ros2 import ERROR, OK, WARN, DiagnosticsPublisher, Ros2Config
    from handeye.app.runs.monitor import Alarm

    pub = DiagnosticsPublisher(Ros2Config(diagnostics=True), "eye_to_hand", load_config(None).frames.model_dump())
    assert pub.status()[0] == WARN  # no sample yet
    quiet = engine_update(5, np.eye(4), np.eye(6) * 1e-8, alarm=False)
    pub(SimpleNamespace(index=5, t=0.0), quiet, _report(1))
    assert pub.status()[:2] == (WARN, "not calibrated yet: collecting samples (4 more before the moved test runs)")
    pub(SimpleNamespace(index=6, t=0.0), quiet, _report(2, np.eye(4)))
    level, message, values = pub.status()
    assert level == OK and message.startswith("calibrated: predicted error 2.000 mm")
    assert values["error_mm"] == "2.000" and values["verify_mm"] == "0.400" and values["samples"] == "2"
    moved = engine_update(7, np.eye(4), np.eye(6) * 1e-8, alarm=True)
    alarm = Alarm(0.0, 7, {"alarm": "moved", "statistic": 123.4})
    pub(SimpleNamespace(index=7, t=0.0), moved, _report(3, np.eye(4), [alarm]))
    level, message, values = pub.status()
    assert level == ERROR and "the marker 0.4 mm from where the calibration puts it at sample 7" in message
    assert values["last_alarm"].startswith("moved at sample 7") and values["alarms"] == "1"
    relearning = moved._replace(alarm="", level="", state="relearning")
    pub(SimpleNamespace(index=8, t=0.0), relearning, _report(4, np.eye(4), [alarm]))
    assert pub.status()[0] == ERROR  # until the stops have re-learnt the camera
    drifting = moved._replace(alarm="", level="drifting", message="drifting 0.5 mm/h")
    pub(SimpleNamespace(index=8, t=0.0), drifting, _report(4, np.eye(4), [alarm]))
    assert pub.status()[:2] == (WARN, "camera drifting: drifting 0.5 mm/h")
    pub.outage(OutageEvent("camera", "outage_start", 0.0, "no publisher on /camera", 0, 0.0))
    assert pub.status()[:2] == (ERROR, "camera away: no publisher on /camera")
    pub.outage(OutageEvent("camera", "outage_end", 0.0, "", 1, 2.0))
    assert pub.status()[0] == WARN and pub.status()[2]["outage"] == "none"
