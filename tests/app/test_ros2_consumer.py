"""A ROS 2 consumer of the calibration in use over real DDS (loopback, the tests' own domain id): the version and
the transform latched on ~/calibration_version and ~/calibration, the acknowledgement on ~/calibration_ack; a
consumer that joins late gets the version in use; one that keeps an old version keeps the cell moved."""

import time

import numpy as np
import pytest

from handeye.app.calibration_versions import History
from handeye.app.consumers import CalibrationLoop, Ros2Consumer
from handeye.app.ros2 import DiagnosticsPublisher, Ros2Config
from handeye.calib import transforms as tf
from handeye.calib.setup import Setup
from handeye.drivers.ros2 import Ros2Node, messages

pytestmark = pytest.mark.slow

FRAMES = {"base": "base", "flange": "tool0", "camera": "camera", "marker": "marker"}
NODE = "handeye_consumer_test"


class RosConsumer:
    """A node that takes the version (and its transform) and acknowledges it, or keeps its first (``stuck``)."""

    def __init__(self, name: str, stuck: bool = False):
        self.name, self.stuck, self.taken, self.transform = name, stuck, None, None
        self.node = Ros2Node(name).open()
        TransformStamped, Header, self.KeyValue = (messages("geometry_msgs", "TransformStamped")[0],
                                                   messages("std_msgs", "Header")[0],
                                                   messages("diagnostic_msgs", "KeyValue")[0])
        self.ack = self.node.publisher(self.KeyValue, f"/{NODE}/calibration_ack")
        self.version = self.latest = None
        self.node.node.create_subscription(Header, f"/{NODE}/calibration_version", self.on_version,
                                           _latched_qos())
        self.node.node.create_subscription(TransformStamped, f"/{NODE}/calibration", self.on_transform,
                                           _latched_qos())

    def on_version(self, msg):
        self.version = msg
        self.take()

    def on_transform(self, msg):
        self.latest = msg
        self.take()

    def take(self):
        """The version with the transform of the same stamp (the two topics arrive in either order)."""
        if self.version is None or self.latest is None or (self.stuck and self.taken is not None):
            return
        if self.version.stamp != self.latest.header.stamp:
            return
        self.taken, self.transform = int(self.version.frame_id), self.latest
        self.ack.publish(self.KeyValue(key=self.name, value=str(self.taken)))

    def close(self):
        self.node.close()


def _latched_qos():
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def test_ros2_consumers_take_the_version_in_use_and_a_stuck_one_keeps_the_cell_moved(ros2_graph, poll_until):
    diagnostics = DiagnosticsPublisher(Ros2Config(diagnostics=True, node_name=NODE), Setup.EYE_TO_HAND,
                                       FRAMES).open()
    consumers = [RosConsumer("vision"), RosConsumer("planner", stuck=True)]
    try:
        diagnostics.listen_calibration()
        loop = CalibrationLoop.of(History("auto"), [Ros2Consumer(diagnostics, c.name) for c in consumers])
        T1 = tf.from_rotvec_translation([2.0, -0.4, 0.3], [0.7, -0.6, 0.85])
        loop.applied(loop.history.first(T1, 0.4, time.time(), "armed"), time.time())
        poll_until(loop, lambda: loop.in_use_by() == {"vision": 1, "planner": 1})
        t = consumers[0].transform.transform.translation
        np.testing.assert_allclose([t.x, t.y, t.z], T1[:3, 3], atol=1e-12)
        assert consumers[0].transform.header.frame_id == "base" and consumers[0].transform.child_frame_id == "camera"
        T2 = tf.from_rotvec_translation([0.0, 0.01, 0.0], [0.01, 0.0, 0.0]) @ T1
        loop.history.propose(T2, 0.5, time.time(), "re-learnt after the move at sample 29", {})
        loop.applied(loop.history.settle(T2, 0.4, time.time()), time.time())
        poll_until(loop, lambda: loop.in_use_by()["vision"] == 2)
        level, sentence = loop.status(time.time())
        assert level == "moved" and "the planner still uses version 1" in sentence
        late = RosConsumer("late")          # joins now: the latched version in use reaches it
        try:
            poll_until(loop, lambda: late.taken == 2)
        finally:
            late.close()
    finally:
        for c in consumers:
            c.close()
        diagnostics.close()


def test_a_pending_version_approved_over_ros2_goes_into_use_with_who_approved_it(ros2_graph, tmp_path):
    """apply = "approve": version 2 waits; a KeyValue (who, version) on ~/calibration_approve is recorded in the
    run's approvals file as ``handeye approve`` records it, and the loop puts version 2 in use, approved by that
    name; a malformed one is logged and dropped."""
    from handeye.app.calibration_versions import Approvals

    diagnostics = DiagnosticsPublisher(Ros2Config(diagnostics=True, node_name=NODE), Setup.EYE_TO_HAND,
                                       FRAMES).open()
    operator = Ros2Node("operator").open()
    try:
        diagnostics.listen_approvals()
        diagnostics.session = str(tmp_path)
        loop = CalibrationLoop.of(History("approve"), [], run=tmp_path, approvals=Approvals([tmp_path]))
        T1 = tf.from_rotvec_translation([2.0, -0.4, 0.3], [0.7, -0.6, 0.85])
        loop.applied(loop.history.first(T1, 0.4, time.time(), "armed"), time.time())
        T2 = tf.from_rotvec_translation([0.0, 0.01, 0.0], [0.01, 0.0, 0.0]) @ T1
        loop.history.propose(T2, 0.5, time.time(), "re-learnt after the move at sample 29", {})
        loop.applied(loop.history.settle(T2, 0.4, time.time()), time.time())
        assert loop.history.in_use.number == 1
        (KeyValue,) = messages("diagnostic_msgs", "KeyValue")
        approve = operator.publisher(KeyValue, f"/{NODE}/calibration_approve", depth=10)
        deadline = time.monotonic() + 15.0
        while loop.history.in_use.number != 2:
            assert time.monotonic() < deadline, loop.history.in_use
            approve.publish(KeyValue(key="shift lead", value="two"))
            approve.publish(KeyValue(key="shift lead", value="2"))
            time.sleep(0.2)
            loop.polled_t = -np.inf
            loop.poll(time.time())
        assert loop.history.in_use.approved_by == "shift lead (ros2)"
    finally:
        operator.close()
        diagnostics.close()
