"""The simulated cell behind ROS 2 (config/sim_ros2.toml): calibrate with frames through DDS, monitor with
frames and poses through DDS, /diagnostics seen by another process. Real DDS on loopback, a test-only domain."""

import json
import subprocess
import sys
import time

import numpy as np
import pytest

from app.config import config_from_dict, load_config
from app.production import Bump
from app.runs.calibrate import calibrate
from app.runs.demo import demo_monitor
from app.session import read_session
from calib import transforms as tf
from calib.vision.extract import extract
from mocks.render.camera import RenderedCamera
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
    cfg = sim_ros2(tmp_path_factory.mktemp("sessions"), 160, samples=6, min_samples=6)
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
    cfg = sim_ros2(cfg.session.root, 161)
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
    error = statuses[levels.index(2, levels.index(0))]
    assert "camera moved: the marker" in error["message"] and float(error["values"]["verify_mm"]) > 3.0
    assert error["values"]["last_alarm"].startswith(f"moved at sample {moved[0].sample_index}")
    assert {"error_mm", "drift_mm_h", "sigma_mm", "verify_mm", "last_alarm", "samples"} <= set(error["values"])
    assert statuses[-1]["level"] == 3 and statuses[-1]["message"].startswith("monitor stopped")
