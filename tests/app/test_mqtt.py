"""MQTT alarms through a real mosquitto broker on loopback: estimate, drift, alarm, status, credentials, TLS."""

import subprocess
import time

import numpy as np
import pytest

from handeye.app.config import config_from_dict
from handeye.app.errors import ConfigError
from handeye.app.runs.monitor import Alarm, MonitorReport
from handeye.app.mqtt import PASSWORD_ENV, USERNAME_ENV, MqttConfig, MqttPublisher
from handeye.calib import transforms as tf
from handeye.calib.observation import Observation

FRAMES = {"base": "base_link", "flange": "tool0", "camera": "cam_optical", "marker": "marker"}


def _wait_for(inbox, n, timeout=10.0):
    deadline = time.monotonic() + timeout
    while len(inbox) < n and time.monotonic() < deadline:
        time.sleep(0.02)
    return inbox


def _feed(pub, tmp_path, alarm: bool, engine_update):
    """One sample through the publisher as run_monitor's on_update would hand it."""
    T = tf.from_rotvec_translation([0.1, -0.2, 0.3], [0.7, -0.6, 0.85])
    report = MonitorReport(tmp_path, n_samples=7, n_skipped=0, estimate=T, estimate_cov=np.diag([1e-6] * 3 + [4e-6] * 3),
                           estimate_sigma=(1e-3, 2e-3), drift=(1.5, 0.1), samples_until_armed=0)
    if alarm:
        report.alarms.append(Alarm(1.0, 7, {"alarm": "moved", "statistic": 123.4}))
    obs = Observation(7, 1.0, np.eye(4), np.zeros(3))
    pub(obs, engine_update(7, T, report.estimate_cov, alarm), report)
    return T


def test_estimate_drift_alarm_and_status_through_a_real_broker(mosquitto, mqtt_inbox, tmp_path, engine_update):
    port = mosquitto()
    inbox = mqtt_inbox(port, "cell1/#")
    cfg = MqttConfig(enabled=True, port=port, topic_prefix="cell1", topics={"alarm": "cell1/alarms/camera"}, qos=1)
    with MqttPublisher(cfg, "eye_to_hand", FRAMES, environ={}) as pub:
        assert pub.connected.is_set()
        T = _feed(pub, tmp_path, alarm=False, engine_update=engine_update)
        _feed(pub, tmp_path, alarm=True, engine_update=engine_update)
    msgs = _wait_for(inbox, 7)
    by_topic = {}
    for topic, payload, _ in msgs:
        by_topic.setdefault(topic, []).append(payload)
    assert [m["state"] for m in by_topic["cell1/status"]] == ["online", "offline"]
    est = by_topic["cell1/estimate"][0]
    assert est["schema"] == "handeye/estimate/1" and est["transform"] == "T_base_cam"
    assert est["parent_frame"] == "base_link" and est["child_frame"] == "cam_optical"
    xyz, q = tf.to_xyz_quat(T)
    np.testing.assert_allclose(est["translation_m"], xyz)
    np.testing.assert_allclose(est["quaternion_xyzw"], q)
    assert est["sigma_mm"] == pytest.approx(2.0) and est["sigma_deg"] == pytest.approx(np.rad2deg(1e-3))
    drift = by_topic["cell1/drift"][0]
    assert drift["translation_mm"] == 1.5 and drift["rate_mm_h"] == 0.5 and drift["hours_to_tolerance"] == 3.0
    (alarm,) = by_topic["cell1/alarms/camera"]
    assert alarm["schema"] == "handeye/alarm/1" and alarm["event"] == "camera_moved"
    assert alarm["sample"] == 7 and alarm["statistic"] == 123.4 and alarm["session"] == str(tmp_path)
    # A dashboard that subscribes later gets the last estimate and the status (retained).
    late = _wait_for(mqtt_inbox(port, "cell1/#"), 2)
    assert {t for t, _, retained in late if retained} == {"cell1/status", "cell1/estimate"}


def test_credentials_come_from_the_environment_only(mosquitto, mqtt_inbox, tmp_path, engine_update):
    pw = tmp_path / "passwd"
    subprocess.run(["mosquitto_passwd", "-b", "-c", str(pw), "plant", "s3cret"], check=True, capture_output=True)
    port = mosquitto(f"allow_anonymous false\npassword_file {pw}")
    inbox = mqtt_inbox(port, "handeye/alarm", username="plant", password="s3cret")
    cfg = MqttConfig(enabled=True, port=port, connect_timeout_s=1.0)
    with MqttPublisher(cfg, "eye_in_hand", FRAMES, environ={}) as pub:   # no credentials: refused, not fatal
        assert not pub.connected.is_set()
    env = {USERNAME_ENV: "plant", PASSWORD_ENV: "s3cret"}
    with MqttPublisher(cfg, "eye_in_hand", FRAMES, environ=env) as pub:
        assert pub.connected.is_set()
        _feed(pub, tmp_path, alarm=True, engine_update=engine_update)
    (msg,) = _wait_for(inbox, 1)
    assert msg[1]["setup"] == "eye_in_hand"
    with pytest.raises(ConfigError, match=USERNAME_ENV):
        MqttConfig.from_dict({"enabled": True, "password": "s3cret"})
    with pytest.raises(ConfigError, match="mqtt.qos"):
        MqttConfig.from_dict({"qos": 3})
    with pytest.raises(ConfigError, match=PASSWORD_ENV):   # the same through a config file's [mqtt] table
        config_from_dict({"mqtt": {"enabled": True, "username": "plant"}})


def test_tls(mosquitto, mqtt_inbox, tmp_path, engine_update):
    def ssl(*args):
        subprocess.run(["openssl", *args], check=True, capture_output=True, cwd=tmp_path)

    ssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj", "/CN=test-ca",
        "-keyout", "ca.key", "-out", "ca.pem")
    ssl("req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=localhost", "-keyout", "srv.key", "-out", "srv.csr")
    (tmp_path / "ext").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    ssl("x509", "-req", "-in", "srv.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial", "-days", "1",
        "-extfile", "ext", "-out", "srv.pem")
    port = mosquitto(f"allow_anonymous true\ncafile {tmp_path / 'ca.pem'}\ncertfile {tmp_path / 'srv.pem'}\n"
                     f"keyfile {tmp_path / 'srv.key'}")
    inbox = mqtt_inbox(port, "handeye/drift", ca_file=str(tmp_path / "ca.pem"))
    cfg = MqttConfig(enabled=True, host="localhost", port=port, tls=True, ca_file=str(tmp_path / "ca.pem"))
    with MqttPublisher(cfg, "eye_to_hand", FRAMES, environ={}) as pub:
        assert pub.connected.is_set()
        _feed(pub, tmp_path, alarm=False, engine_update=engine_update)
    (msg,) = _wait_for(inbox, 1)
    assert msg[1]["rotation_deg"] == 0.1


def test_unreachable_broker_is_a_warning(caplog, tmp_path, engine_update):
    cfg = MqttConfig(enabled=True, port=1, connect_timeout_s=0.5)
    with MqttPublisher(cfg, "eye_to_hand", FRAMES, environ={}) as pub:
        _feed(pub, tmp_path, alarm=True, engine_update=engine_update)
    assert any("not reachable" in r.getMessage() for r in caplog.records)
