"""No alarm or outage message is lost while the broker is away: a real mosquitto restarted mid-run."""

import json
import socket
import subprocess
import threading
import time

import numpy as np
import pytest

from handeye.app.runs.monitor import Alarm, MonitorReport
from handeye.app.mqtt import MqttConfig, MqttPublisher
from handeye.app.outage import OutageEvent
from handeye.calib import transforms as tf
from handeye.calib.observation import Observation

from tests.app.conftest import MOSQUITTO

FRAMES = {"base": "base", "flange": "flange", "camera": "camera", "marker": "marker"}


class Broker:
    """mosquitto on a fixed port with persistence, so that a subscriber's session survives a restart."""

    def __init__(self, tmp_path):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.conf = tmp_path / "mosquitto.conf"
        self.conf.write_text(f"listener {self.port} 127.0.0.1\nallow_anonymous true\npersistence true\n"
                             f"persistence_location {tmp_path}/\nuser root\n")
        self.proc = None

    def start(self):
        self.proc = subprocess.Popen([MOSQUITTO, "-c", str(self.conf)], stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            assert self.proc.poll() is None, self.proc.stderr.read().decode()[-300:]
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                return
            except OSError:
                time.sleep(0.05)
        pytest.fail("mosquitto did not listen within 10 s")

    def stop(self):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(5)


@pytest.fixture
def broker(tmp_path):
    b = Broker(tmp_path)
    b.start()
    yield b
    b.stop()


def subscriber(port, inbox):
    """A persistent-session QoS 1 subscriber that reconnects every second."""
    import paho.mqtt.client as mqtt

    ready = threading.Event()
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="plant-scada", clean_session=False,
                    protocol=mqtt.MQTTv311)
    c.reconnect_delay_set(1, 1)
    c.on_connect = lambda cl, u, f, rc, p: cl.subscribe("cell/#", qos=1)
    c.on_subscribe = lambda *a: ready.set()
    c.on_message = lambda cl, u, m: inbox.append((m.topic, json.loads(m.payload), time.monotonic()))
    c.connect("127.0.0.1", port)
    c.loop_start()
    assert ready.wait(10)
    return c


def _sample(pub, tmp_path, index: int, alarm: bool, engine_update):
    T = tf.from_rotvec_translation([0.1, -0.2, 0.3], [0.7, -0.6, 0.85 + index * 1e-4])
    report = MonitorReport(tmp_path, n_samples=index, n_skipped=0, estimate=T, estimate_cov=np.eye(6) * 1e-6,
                           estimate_sigma=(1e-3, 2e-3), drift=(0.01 * index, 0.001), samples_until_armed=0)
    if alarm:
        report.alarms.append(Alarm(float(index), index, {"alarm": "moved", "statistic": 100.0 + index}))
    pub(Observation(index, float(index), np.eye(4), np.zeros(3)), engine_update(index, T, report.estimate_cov, alarm),
        report)


def _wait(cond, timeout=15.0):
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        time.sleep(0.05)
    return cond()


def test_alarms_and_outages_raised_while_the_broker_restarts_are_all_delivered_and_status_is_coalesced(
        broker, tmp_path, engine_update):
    inbox = []
    sub = subscriber(broker.port, inbox)
    cfg = MqttConfig(enabled=True, port=broker.port, topic_prefix="cell", qos=1, reconnect_min_s=1,
                     reconnect_max_s=1, connect_timeout_s=5.0)
    try:
        with MqttPublisher(cfg, "eye_to_hand", FRAMES, environ={}) as pub:
            _sample(pub, tmp_path, 1, alarm=True, engine_update=engine_update)
            assert _wait(lambda: any(t == "cell/alarm" for t, _, _ in inbox))
            broker.stop()
            assert _wait(lambda: not pub.connected.is_set(), 10)
            down = time.monotonic()
            for i in range(2, 32):  # 30 samples while the broker is away, three of them alarms
                _sample(pub, tmp_path, i, alarm=i in (5, 17, 30), engine_update=engine_update)
                if i == 10:   # and a robot outage, whose failed attempt is not published
                    now = time.time()
                    for event, attempt, away in (("outage_start", 0, 0.0), ("reconnect_failed", 1, 0.5),
                                                 ("outage_end", 2, 1.25)):
                        error = "" if event == "outage_end" else "connection lost"
                        pub.outage(OutageEvent("robot", event, now + away, error, attempt, away))
            # Bounded: the broker's outage start, the three alarms, the robot's outage start and end, and the newest
            # estimate and drift.
            assert pub.held == 1 + 3 + 2 + 2
            broker.start()
            assert _wait(lambda: pub.connected.is_set())
            assert _wait(lambda: sum(t == "cell/alarm" for t, _, _ in inbox) >= 4)
            assert _wait(lambda: sum(t == "cell/outage" for t, _, _ in inbox) >= 4)
            assert _wait(lambda: any(t == "cell/drift" and m["sample"] == 31 for t, m, _ in inbox))
            assert pub.held == 0 and pub.alarms_delivered_late == 3 and pub.outages_delivered_late == 4
            up = time.monotonic()
            _sample(pub, tmp_path, 32, alarm=False, engine_update=engine_update)
            assert _wait(lambda: any(t == "cell/estimate" and m["sample"] == 32 for t, m, _ in inbox))
    finally:
        sub.disconnect()
        sub.loop_stop()
    alarms = [m["sample"] for t, m, _ in inbox if t == "cell/alarm"]
    assert list(dict.fromkeys(alarms)) == [1, 5, 17, 30]   # every alarm, in order (QoS 1: at least once)
    # The outages in the order they happened, between the alarms of the samples around them, the broker's own
    # around everything held.
    held = [(m["device"], m["event"]) if t == "cell/outage" else m["sample"] for t, m, _ in inbox
            if t in ("cell/alarm", "cell/outage")]
    held = list(dict.fromkeys(held[held.index(("mqtt", "outage_start")):]))
    assert held == [("mqtt", "outage_start"), 5, ("robot", "outage_start"), ("robot", "outage_end"), 17, 30,
                    ("mqtt", "outage_end")], held
    outages = {(m["device"], m["event"]): m for t, m, _ in inbox if t == "cell/outage"}
    robot_end, broker_end = outages["robot", "outage_end"], outages["mqtt", "outage_end"]
    assert robot_end["schema"] == "handeye/outage/1" and robot_end["outage_s"] == 1.25 and robot_end["attempt"] == 2
    assert robot_end["since"] == pytest.approx(outages["robot", "outage_start"]["t"])
    assert outages["robot", "outage_start"]["error"] == "connection lost" and "back after 1.2" in robot_end["message"]
    # The broker was away from its stop until the publisher's reconnect (paho retries every second).
    assert up - down - 2.0 < broker_end["outage_s"] < up - down + 1.0, (broker_end["outage_s"], up - down)
    after = [(t, m) for t, m, at in inbox if at > down]
    # The outage's drifts and estimates coalesced to the newest (a redelivered sample 1 is QoS 1's right).
    outage = set(range(2, 31))
    drifts = {m["sample"] for t, m in after if t == "cell/drift"}
    assert 31 in drifts and not drifts & outage, drifts
    estimates = {m["sample"] for t, m in after if t == "cell/estimate"}
    assert {31, 32} <= estimates and not estimates & outage, estimates
    # The restarted broker learns the retained status again.
    assert any(t == "cell/status" and m["state"] == "online" for t, m in after)


def test_an_alarm_raised_as_the_broker_goes_is_published_after_the_outages_start(broker, tmp_path, engine_update):
    """The monitor's thread may publish at the very moment paho's thread notices the broker gone: the alarm goes
    after the broker's ``outage_start``, as it happened, however the two threads are scheduled."""
    import logging

    inbox = []
    sub = subscriber(broker.port, inbox)
    cfg = MqttConfig(enabled=True, port=broker.port, topic_prefix="cell", qos=1, reconnect_min_s=1,
                     reconnect_max_s=1, connect_timeout_s=5.0)

    class AlarmAtTheLoss(logging.Handler):
        def emit(self, record):
            if record.getMessage().startswith("MQTT broker lost"):
                _sample(pub, tmp_path, 2, alarm=True, engine_update=engine_update)

    handler = AlarmAtTheLoss()
    logging.getLogger("handeye.app.mqtt").addHandler(handler)
    try:
        with MqttPublisher(cfg, "eye_to_hand", FRAMES, environ={}) as pub:
            _sample(pub, tmp_path, 1, alarm=True, engine_update=engine_update)
            assert _wait(lambda: any(t == "cell/alarm" for t, _, _ in inbox))
            broker.stop()
            assert _wait(lambda: pub.held == 1 + 1 + 2)   # the outage's start, the alarm, the estimate, the drift
            broker.start()
            assert _wait(lambda: any(t == "cell/outage" and m["event"] == "outage_end" for t, m, _ in inbox))
    finally:
        logging.getLogger("handeye.app.mqtt").removeHandler(handler)
        sub.disconnect()
        sub.loop_stop()
    order = [(m["device"], m["event"]) if t == "cell/outage" else m["sample"] for t, m, _ in inbox
             if t in ("cell/alarm", "cell/outage")]
    order = list(dict.fromkeys(order[order.index(("mqtt", "outage_start")):]))
    assert order == [("mqtt", "outage_start"), 2, ("mqtt", "outage_end")], order
