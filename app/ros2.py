"""The monitor's health where ROS 2 users look: ``/diagnostics`` and the live camera transform.

Configured by ``[ros2]`` (`Ros2Config`; off by default). While ``monitor``
runs, a node (``node_name``, `handeye.drivers.ros2`: rclpy, imported when it starts)
publishes:

- ``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics`` every ``period_s``
  (1 s), whatever the samples do (an outage shows while nothing arrives): one
  ``DiagnosticStatus`` named ``handeye: camera calibration``, ``hardware_id``
  the camera frame, its level

  - ``OK``: calibrated and quiet, the version in use taken by every consumer,
  - ``WARN``: drifting (the predicted error heads for the tolerance), not
    calibrated yet (collecting the first samples), or a consumer that has
    not confirmed the version in use,
  - ``ERROR``: the camera moved (until its re-learnt version is approved where
    ``[monitor] apply`` asks for it and in use by every consumer), or a device
    is away,
  - ``STALE``: the monitor stopped (its last message);

  its message the verdict and its reason in words, and key-value pairs:
  ``error_mm``, ``drift_mm_h``, ``sigma_mm``, ``verify_mm``, ``last_alarm``,
  ``samples`` (and ``state``, ``drift_mm``, ``drift_deg``, ``statistic``,
  ``alarms``, ``last_relearn``: how far the camera moved, ``outage``); numbers
  as text, ``nan`` where not known yet;
- ``geometry_msgs/TransformStamped`` on ``~/camera_transform`` (``/handeye/camera_transform``)
  after every sample with an estimate: ``T_base_cam`` (eye-to-hand) or
  ``T_flange_cam`` (eye-in-hand) of the camera's optical frame, named from
  ``[frames]``, stamped with the sample's time; reliable and transient-local,
  so a node that starts later still gets the newest one.

There is no ``tf2_msgs`` wheel for rclpy, so this node does not publish on
``/tf``; docs/formats.md says how the transform gets there.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import numpy as np

from handeye.app.calibration_in_use import local_time
from handeye.app.calibration_versions import write_approval
from handeye.app.outage import OutageEvent
from handeye.calib import transforms as tf
from handeye.calib.params import Bool, Params, PositiveFloat, Str
from handeye.calib.setup import Setup
from handeye.drivers.errors import ConnectionLostError
from handeye.drivers.ros2 import NodeName, Ros2Node, messages, set_stamp

log = logging.getLogger(__name__)

STATUS_NAME = "handeye: camera calibration"
TRANSFORM_TOPIC = "~/camera_transform"
#: The calibration in use for ROS 2 consumers (`DiagnosticsPublisher.listen_calibration`).
CALIBRATION_TOPIC = "~/calibration"
#: ``diagnostic_msgs/DiagnosticStatus`` levels.
OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}


class Ros2Config(Params):
    """``[ros2]``: what ``monitor`` publishes in ROS 2 (the module docstring).

    Attributes
    ----------
    diagnostics : bool
        Publish ``/diagnostics`` and ``~/camera_transform`` while monitoring.
    node_name : str
    hardware_id : str
        The status's ``hardware_id``; empty: the camera frame of ``[frames]``.
    period_s : float
        ``/diagnostics`` is published this often, s.
    """

    diagnostics: Bool = False
    node_name: NodeName = "handeye"
    hardware_id: Str = ""
    period_s: PositiveFloat = 1.0


def _number(x, fmt: str = ".3f") -> str:
    return "nan" if x is None or not np.isfinite(x) else format(float(x), fmt)


class DiagnosticsPublisher:
    """Publishes the monitor's health on ``/diagnostics`` and its estimate on ``~/camera_transform``; a
    context manager, called like `handeye.app.mqtt.MqttPublisher` (``(obs, update, report)`` and `outage`).

    Parameters
    ----------
    config : Ros2Config
    setup : Setup
    frames : dict
        ``base``, ``flange``, ``camera``, ``marker`` names (``[frames]``).
    """

    def __init__(self, config: Ros2Config, setup: Setup, frames: dict):
        self.config, self.setup, self.frames = config, Setup(setup), dict(frames)
        self.node = Ros2Node(config.node_name)
        self._lock = threading.Lock()
        self._update = None
        self._report = None
        self._outages: dict[str, str] = {}
        self._moved = ""    # the last moved alarm's figures, and the last re-learn
        self._relearnt = ""
        self.published = 0

    # ------------------------------------------------------------ lifecycle
    def open(self) -> "DiagnosticsPublisher":
        self.node.open()
        self.DiagnosticArray, self.DiagnosticStatus, self.KeyValue = messages(
            "diagnostic_msgs", "DiagnosticArray", "DiagnosticStatus", "KeyValue")
        (self.TransformStamped,) = messages("geometry_msgs", "TransformStamped")
        self.diagnostics = self.node.publisher(self.DiagnosticArray, "/diagnostics")
        self.transform = self.node.publisher(self.TransformStamped, TRANSFORM_TOPIC, depth=1, latched=True)
        self.timer = self.node.timer(self.config.period_s, self.publish_status)
        self.publish_status()
        return self

    def listen_calibration(self) -> None:
        """The calibration in use for ROS 2 consumers: ``~/calibration`` (TransformStamped) and
        ``~/calibration_version`` (std_msgs/Header: ``frame_id`` the version's number, ``stamp`` the stamp of its
        transform, which pairs them: DDS does not order two topics), both latched, and their acknowledgements on
        ``~/calibration_ack`` (diagnostic_msgs/KeyValue: ``key`` the consumer's name, ``value`` the version it
        has taken) into `acks`."""
        (self.Header,) = messages("std_msgs", "Header")
        self.calibration = self.node.publisher(self.TransformStamped, CALIBRATION_TOPIC, depth=1, latched=True)
        self.calibration_version = self.node.publisher(self.Header, CALIBRATION_TOPIC + "_version", depth=1,
                                                       latched=True)
        self.acks: dict[str, int] = {}
        self.node.subscribe(self.KeyValue, CALIBRATION_TOPIC + "_ack", self._on_ack, depth=50)

    def listen_approvals(self) -> None:
        """Approvals of a pending version on ``~/calibration_approve`` (diagnostic_msgs/KeyValue: ``key`` who
        approves, ``value`` the version), appended to the run's approvals file as ``handeye approve`` does (`session`:
        the run's directory, set once it exists; before that an approval is logged and dropped)."""
        self.session: str | None = None
        self.node.subscribe(self.KeyValue, CALIBRATION_TOPIC + "_approve", self._on_approve, depth=10)

    def _on_approve(self, msg) -> None:
        try:
            version = int(msg.value)
        except ValueError:
            log.warning("%s_approve: %r is not a version (from %r)", CALIBRATION_TOPIC, msg.value, msg.key)
            return
        if self.session is None:
            log.warning("%s_approve: version %d from %r before the run's session exists: not taken",
                        CALIBRATION_TOPIC, version, msg.key)
            return
        try:
            write_approval(Path(self.session), version, f"{msg.key or 'unknown'} (ros2)", time.time())
        except OSError as e:
            log.warning("%s_approve: version %d from %r not recorded (%s)", CALIBRATION_TOPIC, version, msg.key, e)

    def _on_ack(self, msg) -> None:
        try:
            self.acks[msg.key] = int(msg.value)
        except ValueError:
            log.warning("%s_ack: %r is not a version (from %r)", CALIBRATION_TOPIC, msg.value, msg.key)

    def publish_calibration(self, number: int, T, t: float) -> None:
        """Version ``number`` of the calibration in use (``t``: when it was put in use, its stamp): its transform
        and its version (latched)."""
        if self.node.node is None:
            raise ConnectionLostError("the ROS 2 node is not open")
        msg = self._transform_message(np.asarray(T, dtype=float), t)
        version = self.Header(frame_id=str(int(number)))
        version.stamp = msg.header.stamp
        self.calibration.publish(msg)
        self.calibration_version.publish(version)

    def close(self) -> None:
        """The last status (``STALE``: the monitor stopped), then the node goes."""
        if self.node.node is None:
            return
        self.node.cancel_timer(self.timer)
        level, message, values = self.status()
        self._publish(STALE, f"monitor stopped; last: {LEVEL_NAMES[level]} {message}", values)
        time.sleep(0.1)  # let a reliable subscriber take the last message before the node goes
        self.node.close()

    def __enter__(self) -> "DiagnosticsPublisher":
        return self.open()

    def __exit__(self, *exc) -> bool:
        self.close()
        return False

    # -------------------------------------------------------------- inputs
    def __call__(self, obs, update, report) -> None:
        """`handeye.app.runs.monitor`'s ``publish``: keep the figures for the next status, publish the transform."""
        with self._lock:
            if update is not None:
                self._update = update
                if update.alarm == "moved":
                    self._moved = (f"the marker {update.verify_mm:.1f} mm from where the calibration puts it at "
                                   f"sample {obs.index} (GLR statistic {update.statistic:.0f})")
                if "re-learnt" in update.message:
                    self._relearnt = update.message.split("; ")[-1]
            self._report = report
        if report.estimate is not None:
            self._publish_transform(report.estimate, obs.t)
        if update is not None and update.alarm:
            self.publish_status()  # an alarm is not held back for the next period

    def outage(self, event: OutageEvent) -> None:
        """A device away (``ERROR`` until it is back) or back."""
        with self._lock:
            if event.event == "outage_end":
                self._outages.pop(event.device, None)
            else:
                self._outages[event.device] = event.error
        self.publish_status()

    # ------------------------------------------------------------- outputs
    def status(self) -> tuple[int, str, dict]:
        """(level, message, values) of the monitor now."""
        with self._lock:
            upd, report, outages = self._update, self._report, dict(self._outages)
        values = self._values(upd, report, outages)
        if outages:
            device, error = next(iter(outages.items()))
            return ERROR, f"{device} away: {error}", values
        if upd is not None and (upd.level == "moved" or upd.state == "relearning"):  # until it is re-learnt
            return ERROR, f"camera moved: {self._moved}; re-learning it from the next stops", values
        said = cell_status(report)
        if said is not None and said[0] in ("moved", "warn"):
            # Re-learnt, until the version is approved where that is required and in use by every consumer.
            return (ERROR if said[0] == "moved" else WARN), said[1], values
        if upd is not None and upd.level == "drifting":
            return WARN, f"camera drifting: {upd.message or 'predicted error ' + values['error_mm'] + ' mm'}", values
        if report is None:
            return WARN, "waiting for the first sample (the robot's next standstill with the marker in view)", values
        if report.estimate is None:
            return WARN, (f"not calibrated yet: collecting samples ({report.samples_until_armed} more before the "
                          "moved test runs)"), values
        return OK, (f"calibrated: predicted error {values['error_mm']} mm, last check {values['verify_mm']} mm"
                    if upd is not None else "calibrated"), values

    def _values(self, upd=None, report=None, outages=None) -> dict:
        alarm = "none"
        if report is not None and report.alarms:
            a = report.alarms[-1]
            alarm = f"{a.kind} at sample {a.sample_index}, {local_time(a.t)}" + (f": {self._moved}" if a.kind == "moved" else
                                                                       f": {a.info.get('message', '')}")
        return {
            "state": "" if upd is None else upd.state,
            "error_mm": _number(None if upd is None else upd.error_mm),
            "drift_mm_h": _number(None if upd is None else upd.drift_rate_mm_h),
            "sigma_mm": _number(None if upd is None else upd.sigma_mm),
            "verify_mm": _number(None if upd is None else upd.verify_mm),
            "drift_mm": _number(None if upd is None else upd.drift_mm),
            "drift_deg": _number(None if upd is None else upd.drift_deg, ".4f"),
            "statistic": _number(None if upd is None else upd.statistic, ".1f"),
            "last_alarm": alarm,
            "alarms": str(0 if report is None else len(report.alarms)),
            "samples": str(0 if report is None else report.n_samples),
            "last_relearn": self._relearnt or "none",
            "outage": ", ".join(f"{d}: {e}" for d, e in (outages or {}).items()) or "none",
            **version_values(report),
        }

    def publish_status(self) -> None:
        """One ``DiagnosticArray`` with the status now (the timer's callback)."""
        self._publish(*self.status())

    def _publish(self, level: int, message: str, values: dict) -> None:
        if self.node.node is None:  # not open (or closed): nothing goes out, the verdict is still kept
            return
        status = self.DiagnosticStatus(level=bytes([level]), name=STATUS_NAME, message=message,
                                       hardware_id=self.config.hardware_id or self.frames["camera"],
                                       values=[self.KeyValue(key=k, value=v) for k, v in values.items()])
        array = self.DiagnosticArray(status=[status])
        set_stamp(array.header, time.time())
        self.diagnostics.publish(array)
        self.published += 1

    def _publish_transform(self, T: np.ndarray, t: float) -> None:
        if self.node.node is None:
            return
        self.transform.publish(self._transform_message(T, t))

    def _transform_message(self, T: np.ndarray, t: float):
        msg = self.TransformStamped()
        set_stamp(msg.header, t)
        msg.header.frame_id = self.frames["flange"] if self.setup.camera_on_flange else self.frames["base"]
        msg.child_frame_id = self.frames["camera"]
        xyz, q = tf.to_xyz_quat(T)
        tr, rot = msg.transform.translation, msg.transform.rotation
        tr.x, tr.y, tr.z = (float(v) for v in xyz)
        rot.x, rot.y, rot.z, rot.w = (float(v) for v in q)
        return msg


def cell_status(report) -> tuple[str, str] | None:
    """``(level, sentence)`` of the cell (`handeye.app.shift_record.ShiftRecord.status`) once a run has versions of
    its calibration (`handeye.app.consumers`), else None."""
    record = getattr(report, "record", None)
    if record is None or getattr(record, "loop", None) is None or record.loop.history.in_use is None:
        return None
    return record.status(time.time())


def version_values(report) -> dict:
    """``calibration_version``, ``in_use_by`` and ``pending`` as key-values (empty before versions)."""
    loop = getattr(report, "loop", None)
    in_use = None if loop is None else loop.history.in_use
    if in_use is None:
        return {}
    pending = loop.history.pending
    return {"calibration_version": str(in_use.number),
            "in_use_by": ", ".join(f"{name}: {v or 'none'}" for name, v in loop.in_use_by().items()) or "none",
            "pending": "none" if pending is None else f"version {pending.number} ({pending.state})"}


def make_diagnostics(config: Ros2Config, setup: Setup, frames: dict) -> DiagnosticsPublisher | None:
    """A publisher for ``[ros2] diagnostics = true``, else None."""
    return DiagnosticsPublisher(config, setup, frames) if config.diagnostics else None
