"""MQTT consumers of the calibration in use, through a real mosquitto: the version in use retained on
<prefix>/calibration, acknowledged on <prefix>/calibration/ack, approved on <prefix>/calibration/approve; a consumer
that acknowledges an old version keeps the cell moved; a broker that is away holds the version given."""

import json
import threading
import time

import numpy as np
import paho.mqtt.client as mqtt

from handeye.app.calibration_versions import Approvals, History
from handeye.app.consumers import CalibrationLoop, MqttConsumer
from handeye.app.mqtt import MqttConfig, MqttPublisher
from handeye.calib import transforms as tf
from handeye.calib.setup import Setup

FRAMES = {"base": "base", "flange": "tool0", "camera": "camera", "marker": "marker"}


class VisionPC:
    """A consumer on the bus: takes each version on cell1/calibration and acknowledges it (or, ``stuck``, keeps
    acknowledging the first it took)."""

    def __init__(self, port: int, name: str, stuck: bool = False):
        self.name, self.stuck, self.taken, self.seen = name, stuck, None, []
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=name)
        self.client.on_connect = lambda c, u, f, rc, p: c.subscribe("cell1/calibration", 1)
        self.client.on_message = self.on_message
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()

    def on_message(self, client, userdata, message):
        data = json.loads(message.payload)
        self.seen.append(data)
        if self.taken is None or not self.stuck:
            self.taken = data["calibration_version"]
        client.publish("cell1/calibration/ack", json.dumps({"consumer": self.name, "version": self.taken}), qos=1)

    def close(self):
        self.client.loop_stop()
        self.client.disconnect()


def test_mqtt_consumers_take_each_version_an_mqtt_approval_applies_it_and_a_stuck_one_keeps_the_cell_moved(
        mosquitto, tmp_path, poll_until):
    port = mosquitto()
    publisher = MqttPublisher(MqttConfig(enabled=True, port=port, topic_prefix="cell1", qos=1), Setup.EYE_TO_HAND,
                              FRAMES).connect()
    publisher.session = str(tmp_path)
    pcs = [VisionPC(port, "vision-pc"), VisionPC(port, "plc", stuck=True)]
    loop = CalibrationLoop.of(History("approve"), [MqttConsumer(publisher, p.name) for p in pcs], run=tmp_path,
                              approvals=Approvals([tmp_path]), ack_timeout_s=5.0)
    try:
        T1 = tf.from_rotvec_translation([2.0, -0.4, 0.3], [0.7, -0.6, 0.85])
        loop.applied(loop.history.first(T1, 0.4, time.time(), "armed"), time.time())
        poll_until(loop, lambda: loop.in_use_by() == {"vision-pc": 1, "plc": 1})
        assert loop.status(time.time()) is None
        np.testing.assert_allclose(pcs[0].seen[-1]["translation_m"], T1[:3, 3])
        T2 = tf.from_rotvec_translation([0.0, 0.01, 0.0], [0.01, 0.0, 0.0]) @ T1
        loop.history.propose(T2, 0.5, time.time(), "re-learnt after the move at sample 29", {})
        loop.history.settle(T2, 0.4, time.time())
        # A person approves on the bus: the approval reaches the run's approvals file and the loop.
        approver = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="hmi")
        approver.connect("127.0.0.1", port)
        approver.loop_start()
        approver.publish("cell1/calibration/approve", json.dumps({"version": 2, "by": "ann"}), qos=1).wait_for_publish(5)
        approver.publish("cell1/calibration/approve", "not json", qos=1).wait_for_publish(5)      # dropped, logged
        approver.loop_stop()
        approver.disconnect()
        poll_until(loop, lambda: loop.history.in_use.number == 2)
        assert loop.history.in_use.applied_by == "approved by ann (mqtt)"
        poll_until(loop, lambda: loop.in_use_by()["vision-pc"] == 2)
        time.sleep(0.5)
        loop.poll(time.time() + 10)
        assert loop.in_use_by() == {"vision-pc": 2, "plc": 1}
        level, sentence = loop.status(time.time() + 10)
        assert level == "moved" and "the plc still uses version 1" in sentence and "the vision-pc uses version 2" \
            in sentence
        # The version in use is retained: a consumer that starts now gets it at once.
        late = VisionPC(port, "late")
        deadline = time.monotonic() + 5
        while late.taken is None and time.monotonic() < deadline:
            time.sleep(0.05)
        late.close()
        assert late.taken == 2
    finally:
        for p in pcs:
            p.close()
        publisher.close()


def test_a_broker_that_is_away_is_a_warning_and_the_version_given_is_held(mosquitto, tmp_path):
    port = mosquitto()
    publisher = MqttPublisher(MqttConfig(enabled=True, port=port + 1, topic_prefix="cell1", qos=1,
                                         connect_timeout_s=0.3), Setup.EYE_TO_HAND, FRAMES).connect()
    publisher.session = str(tmp_path)
    loop = CalibrationLoop.of(History("auto"), [MqttConsumer(publisher, "vision-pc")], run=tmp_path,
                              approvals=Approvals([tmp_path]), ack_timeout_s=0.2)
    try:
        before = publisher.held
        loop.applied(loop.history.first(np.eye(4), 0.4, time.time(), "armed"), time.time())
        loop.poll(time.time())
        level, sentence = loop.status(time.time())
        assert level == "warn" and "vision-pc" in sentence and "broker is away" in sentence
        assert publisher.held == before + 1      # the version given is held for the broker's return
    finally:
        publisher.close()
