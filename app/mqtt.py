"""Alarms a plant can hear: the monitor's live estimate, drift and alarms as JSON over MQTT.

Configured by the ``[mqtt]`` table (`MqttConfig`); credentials come only
from the environment (``HANDEYE_MQTT_USERNAME``, ``HANDEYE_MQTT_PASSWORD``),
never from the config file, which is often committed or copied around.

Topics (``<prefix>`` = ``topic_prefix``, each overridable in ``[mqtt.topics]``)
and messages, every one a JSON object with ``schema`` naming it (the full
schema is in docs/mqtt.md)::

    <prefix>/status    retained  {"schema": "handeye/status/1", "state": "online" | "offline", "level": "ok" |
                                  "moved" | "warn" | "drifting", "message", "calibration_version", "in_use_by",
                                  "pending", ...} (the cell's status: republished when it changes)
    <prefix>/estimate  retained  {"schema": "handeye/estimate/1", "translation_m", "quaternion_xyzw", "sigma_mm", ...}
    <prefix>/drift               {"schema": "handeye/drift/1", "translation_mm", "rotation_deg", ...}
    <prefix>/alarm               {"schema": "handeye/alarm/1", "event": "camera_moved", "sample", "statistic", ...}
    <prefix>/outage              {"schema": "handeye/outage/1", "device", "event": "outage_start" | "outage_end", ...}

The estimate is ``T_base_cam`` (eye-to-hand) or ``T_flange_cam``
(eye-in-hand) of the camera's optical frame (z forward, x right, y down),
named by ``parent_frame`` / ``child_frame`` from ``[frames]``.

A broker that cannot be reached costs a warning, not the monitoring run:
paho keeps reconnecting in its network thread (backoff from
``reconnect_min_s`` to ``reconnect_max_s``). While it is away nothing is handed
to paho; `MqttPublisher` holds the messages itself, bounded: every alarm and
the newest `MAX_HELD_OUTAGES` outage messages, in the order they happened
(they go with QoS >= 1 so paho re-sends one the broker did not acknowledge),
and only the newest message of each other topic (status, estimate and drift
are coalesced). On reconnect the alarms and outages go first, then the newest
retained status and estimate (a restarted broker without persistence has lost
them), then the newest drift. The broker's own absence is an outage too
(device ``mqtt``): its start and end are published once it is back.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import logging
import os
import socket
import threading
import time
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, Field, ValidationError, model_validator

from handeye.app.errors import ConfigError
from handeye.app.calibration_versions import write_approval
from handeye.app.outage import OutageEvent
from handeye.calib.params import Bool, Float, Int, NonEmptyStr, Params, Str, describe
from handeye.calib import transforms as tf
from handeye.calib.setup import Setup

log = logging.getLogger(__name__)

USERNAME_ENV = "HANDEYE_MQTT_USERNAME"
PASSWORD_ENV = "HANDEYE_MQTT_PASSWORD"
SCHEMA_VERSION = 1
TOPICS = ("status", "estimate", "drift", "alarm", "outage", "calibration", "calibration_ack", "calibration_approve")
#: Topics whose every message is held for an absent broker (the others are coalesced to the newest).
KEPT = ("alarm", "outage")
#: Outage messages held for an absent broker at most (a device flapping for hours); the oldest go first.
MAX_HELD_OUTAGES = 1000
_SECRET_KEYS = ("username", "password", "user", "passwd", "token")


def _topic(name: str) -> str:
    if any(c in name for c in "+#"):
        raise ValueError(f"a topic to publish on has no wildcards, got {name!r}")
    return name


Topic = Annotated[NonEmptyStr, AfterValidator(_topic)]


class MqttConfig(Params):
    """``[mqtt]``: where and how the monitor publishes.

    Attributes
    ----------
    enabled : bool
    host : str
        Broker address.
    port : int
        1883 (plain) or 8883 (TLS) by convention.
    client_id : str
        Empty: ``handeye-<hostname>-<pid>``.
    topic_prefix : str
        Topics are ``<prefix>/status``, ``/estimate``, ``/drift``, ``/alarm``, ``/outage``.
    topics : dict
        Per-topic overrides, keys from ``status, estimate, drift, alarm, outage``.
    qos : int
        0, 1 or 2, for every message.
    keepalive_s : int
    connect_timeout_s : float
        How long the start waits for the broker before going on without it
        (and the end, for held alarms, before giving up on them).
    reconnect_min_s, reconnect_max_s : int
        paho's reconnect backoff after the broker went away, s.
    tls : bool
        TLS with the system's CAs, or ``ca_file``.
    ca_file, certfile, keyfile : str
        PEM files (client certificate optional).
    """

    enabled: Bool = False
    host: NonEmptyStr = "127.0.0.1"
    port: Annotated[Int, Field(ge=1, le=65535)] = 1883
    client_id: Str = ""
    topic_prefix: Topic = "handeye"
    topics: dict[Literal[TOPICS], Topic] = Field(default_factory=dict)
    qos: Literal[0, 1, 2] = 1
    keepalive_s: Annotated[Int, Field(ge=5)] = 30
    connect_timeout_s: Annotated[Float, Field(ge=0, le=60)] = 5.0
    reconnect_min_s: Annotated[Int, Field(ge=1, le=3600)] = 1
    reconnect_max_s: Annotated[Int, Field(ge=1, le=3600)] = 30
    tls: Bool = False
    ca_file: Str = ""
    certfile: Str = ""
    keyfile: Str = ""

    @model_validator(mode="before")
    @classmethod
    def _no_credentials(cls, data):
        if isinstance(data, dict):
            for key in data:
                if key in _SECRET_KEYS:
                    raise ValueError(f"{key}: credentials are never read from the config file; "
                                     f"set {USERNAME_ENV} and {PASSWORD_ENV} in the environment")
        return data

    @model_validator(mode="after")
    def _client_cert_needs_tls(self):
        if (self.certfile or self.keyfile) and not self.tls:
            raise ValueError("certfile/keyfile need tls = true")
        if self.reconnect_min_s > self.reconnect_max_s:
            raise ValueError(f"reconnect_min_s ({self.reconnect_min_s}) must be <= reconnect_max_s "
                             f"({self.reconnect_max_s})")
        return self

    @classmethod
    def from_dict(cls, data: dict) -> "MqttConfig":
        """Validate an ``[mqtt]`` table; `ConfigError` naming ``mqtt.<field>`` (credentials refused)."""
        try:
            return cls.model_validate(data)
        except ValidationError as e:
            raise ConfigError(describe(e, "mqtt", model=cls)) from None

    def topic(self, kind: str) -> str:
        return self.topics.get(kind) or f"{self.topic_prefix}/{kind.replace('_', '/')}"


class MqttPublisher:
    """Publishes the monitor's state (see the module docstring); use as a context manager.

    Parameters
    ----------
    config : MqttConfig
    setup : Setup
    frames : dict
        ``base``, ``flange``, ``camera``, ``marker`` names (``[frames]``).
    environ : mapping, optional
        Where the credentials are read (default ``os.environ``).
    """

    def __init__(self, config: MqttConfig, setup: Setup, frames: dict, *, environ=None):
        self.config, self.setup, self.frames = config, Setup(setup), dict(frames)
        self.environ = os.environ if environ is None else environ
        self.connected = threading.Event()
        self.client = None
        self.session: str | None = None
        #: The cell's status last published (`publish_cell_status`).
        self.cell: dict = {}
        #: The calibration consumers' acknowledgements (``calibration_ack``: consumer -> version), once
        #: `listen` was called; approvals (``calibration_approve``) go into the run's approvals file.
        self.acks: dict[str, int] = {}
        self.listening = False
        self._last_error = ""
        # Held while the broker is away (see the module docstring): (kind, payload) of every alarm and
        # outage in order, the newest of the rest.
        self._lock = threading.Lock()
        self._held_kept: collections.deque = collections.deque()
        self._held: dict[str, tuple[dict, bool]] = {}
        self._retained: dict[str, dict] = {}
        self._broker_lost: float | None = None   # monotonic time the broker went away
        #: Alarms held for an absent broker and published once it was back.
        self.alarms_delivered_late = 0
        #: Outage messages held for an absent broker and published once it was back.
        self.outages_delivered_late = 0
        #: Outage messages dropped from the hold (more than `MAX_HELD_OUTAGES`).
        self.outages_dropped = 0
        #: The broker's own outage steps (`handeye.app.outage.OutageEvent`, device ``mqtt``), appended from paho's network
        #: thread for the caller to record in its own (`handeye.app.runs.monitor` drains it into the session).
        self.broker_outages: collections.deque = collections.deque()

    # ------------------------------------------------------------ connection
    def connect(self) -> "MqttPublisher":
        import paho.mqtt.client as mqtt

        c = self.config
        client_id = c.client_id or f"handeye-{socket.gethostname()}-{os.getpid()}"
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id)
        user = self.environ.get(USERNAME_ENV)
        if user:
            client.username_pw_set(user, self.environ.get(PASSWORD_ENV))
        if c.tls:
            try:
                client.tls_set(ca_certs=c.ca_file or None, certfile=c.certfile or None, keyfile=c.keyfile or None)
            except (OSError, ValueError) as e:
                raise ConfigError(f"mqtt TLS files: {e}") from None
        # A monitor that dies leaves "offline" behind (last will), so a dashboard never trusts a stale estimate.
        client.will_set(c.topic("status"), json.dumps(self._status("offline")), qos=c.qos, retain=True)
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        client.max_queued_messages_set(10000)
        client.reconnect_delay_set(c.reconnect_min_s, c.reconnect_max_s)
        self.client = client
        try:
            client.connect_async(c.host, c.port, keepalive=c.keepalive_s)
        except (OSError, ValueError) as e:
            raise ConfigError(f"mqtt broker {c.host}:{c.port}: {e}") from None
        client.loop_start()
        if not self.connected.wait(c.connect_timeout_s):
            log.warning("MQTT broker %s:%d not reachable%s; monitoring goes on and keeps retrying",
                        c.host, c.port, f" ({self._last_error})" if self._last_error else "")
        self.publish("status", self._status("online"), retain=True)
        return self

    def _on_connect(self, client, userdata, flags, reason_code, properties):
        if reason_code.is_failure:
            self._last_error = str(reason_code)
            return
        if self.listening:     # again at every (re)connect: a clean session forgets subscriptions
            client.subscribe([(self.config.topic("calibration_ack"), 1), (self.config.topic("calibration_approve"), 1)])
        back = None
        # Under the lock with the state change, so that a message published meanwhile goes after the outage's end
        # and never between the held ones and it.
        with self._lock:
            lost, self._broker_lost = self._broker_lost, None
            if lost is not None:
                away = time.monotonic() - lost
                back = self._broker_outage(OutageEvent("mqtt", "outage_end", time.time(), "", 0, away),
                                           f"MQTT broker back after {away:.1f} s")
            self.connected.set()
            kept, held = list(self._held_kept), dict(self._held)
            self._held_kept.clear()
            self._held.clear()
            for kind, payload in kept:
                self._send(kind, payload, False)
            n_alarms = sum(kind == "alarm" for kind, _ in kept)
            self.alarms_delivered_late += n_alarms
            self.outages_delivered_late += len(kept) - n_alarms
            for kind, payload in self._retained.items():
                self._send(kind, payload, True)
            for kind, (payload, retain) in held.items():
                if not retain:
                    self._send(kind, payload, False)
        if back is not None:
            self._log_broker_outage(*back)
        if kept:
            log.info("MQTT broker back: published %d alarm(s) and %d outage message(s) held while it was away",
                     n_alarms, len(kept) - n_alarms)

    def _on_disconnect(self, client, userdata, flags, reason_code, properties):
        lost = None
        # Under the lock with the state change, so that an alarm published as the broker goes is held after the
        # outage's start (the order a plant reads them in), however the threads are scheduled.
        with self._lock:
            was_connected = self.connected.is_set()
            self.connected.clear()
            if reason_code.is_failure:
                self._last_error = str(reason_code)
                if was_connected and self._broker_lost is None:
                    # The broker went away (not our own disconnect at the end): an outage, published once it is back.
                    self._broker_lost = time.monotonic()
                    lost = self._broker_outage(
                        OutageEvent("mqtt", "outage_start", time.time(), str(reason_code), 0, 0.0),
                        f"MQTT broker lost: {reason_code}; holding alarms until it is back")
        if lost is not None:
            self._log_broker_outage(*lost)

    def _broker_outage(self, event: OutageEvent, message: str) -> tuple[OutageEvent, str]:
        """Hold the broker's own outage step for publishing once it is back (under the lock); returns it for
        `_log_broker_outage`, outside the lock."""
        self._hold_kept("outage", self._outage_payload(event, message))
        return event, message

    def _log_broker_outage(self, event: OutageEvent, message: str) -> None:
        """Log the broker's outage step and keep it for the caller's session."""
        log.warning("%s (%s:%d)", message, self.config.host, self.config.port)
        self.broker_outages.append(event)

    def close(self) -> None:
        """Publish ``offline`` (retained), wait briefly for the queue to drain, disconnect.

        Alarms still held for an absent broker get ``connect_timeout_s`` for it to come back; any left
        then are logged as undelivered (the session's events still hold them)."""
        if self.client is None:
            return
        if self._held_kept and not self.connected.wait(self.config.connect_timeout_s):
            log.error("MQTT broker %s:%d away at the end: %d alarm(s) and outage message(s) not delivered (they "
                      "are in the session)", self.config.host, self.config.port, len(self._held_kept))
        info = self.publish("status", self._status("offline"), retain=True)
        if self.connected.is_set() and info is not None:
            try:
                info.wait_for_publish(timeout=3.0)
            except (RuntimeError, ValueError):
                pass
        self.client.disconnect()
        self.client.loop_stop()
        self.client = None

    def __enter__(self):
        return self.connect()

    def __exit__(self, *exc):
        self.close()
        return False

    # -------------------------------------------------------------- the calibration in use
    def listen(self) -> None:
        """Take the calibration consumers' acknowledgements and approvals (`handeye.app.consumers.MqttConsumer`)."""
        self.listening = True
        self.client.on_message = self._on_message
        if self.connected.is_set():
            self.client.subscribe([(self.config.topic("calibration_ack"), 1),
                                   (self.config.topic("calibration_approve"), 1)])

    def publish_calibration(self, number: int, T, error_mm: float, applied: float, applied_by: str) -> None:
        """The version in use on ``<prefix>/calibration`` (retained; held for an absent broker and sent on its
        return): its number, the camera transform as the estimate is, its predicted error, since when, by whom."""
        xyz, q = tf.to_xyz_quat(np.asarray(T, dtype=float))
        parent = self.frames["flange"] if self.setup.camera_on_flange else self.frames["base"]
        self.publish("calibration", {**self._base("calibration"), "calibration_version": int(number),
                                     "transform": self.setup.camera_name, "parent_frame": parent,
                                     "child_frame": self.frames["camera"], "translation_m": xyz.tolist(),
                                     "quaternion_xyzw": q.tolist(), "predicted_error_mm": float(error_mm),
                                     "applied": float(applied), "applied_by": applied_by,
                                     "acknowledge_on": self.config.topic("calibration_ack")}, retain=True)

    def _on_message(self, client, userdata, message) -> None:
        """An acknowledgement ``{"consumer": name, "version": n}`` or an approval ``{"version": n, "by": who}``
        (paho's thread); anything else is logged and dropped."""
        try:
            data = json.loads(message.payload)
            version = int(data["version"])
            if message.topic == self.config.topic("calibration_ack"):
                self.acks[str(data.get("consumer", "mqtt"))] = version
            elif self.session is not None:
                write_approval(Path(self.session), version, f"{data.get('by', 'unknown')} (mqtt)", time.time())
        except (ValueError, KeyError, TypeError, OSError) as e:
            log.warning("MQTT %s: a message not taken (%s): %r", message.topic, e, message.payload[:200])

    # -------------------------------------------------------------- messages
    def publish(self, kind: str, payload: dict, *, retain: bool = False):
        """Publish one JSON message on the topic of ``kind``; returns paho's MQTTMessageInfo, or None when the
        message is held for an absent broker (published on reconnect: alarms and outages all, the rest
        coalesced)."""
        if self.client is None:
            return None
        with self._lock:
            if retain:
                self._retained[kind] = payload
            if not self.connected.is_set():
                if kind in KEPT:
                    self._hold_kept(kind, payload)
                else:
                    self._held[kind] = (payload, retain)
                return None
            return self._send(kind, payload, retain)

    @property
    def held(self) -> int:
        """Messages held for an absent broker (alarms and outages + one per other topic)."""
        return len(self._held_kept) + len(self._held)

    def _hold_kept(self, kind: str, payload: dict) -> None:
        """Hold an alarm or outage message (under the lock); past `MAX_HELD_OUTAGES` outage messages the oldest
        outage message goes (alarms are never dropped)."""
        self._held_kept.append((kind, payload))
        if kind == "outage" and sum(k == "outage" for k, _ in self._held_kept) > MAX_HELD_OUTAGES:
            oldest = next(i for i, (k, _) in enumerate(self._held_kept) if k == "outage")
            del self._held_kept[oldest]
            self.outages_dropped += 1
            if self.outages_dropped == 1:
                log.warning("MQTT broker away: more than %d outage messages held, dropping the oldest",
                            MAX_HELD_OUTAGES)

    def _send(self, kind: str, payload: dict, retain: bool):
        # An alarm or an outage goes at least once: with QoS 1 paho keeps it until the broker acknowledges it and
        # sends it again after a reconnect.
        qos = max(self.config.qos, 1) if kind in KEPT else self.config.qos
        return self.client.publish(self.config.topic(kind), json.dumps(payload), qos=qos, retain=retain)

    def _base(self, schema: str) -> dict:
        return {"schema": f"handeye/{schema}/{SCHEMA_VERSION}", "t": time.time(), "setup": str(self.setup),
                "session": self.session}

    def _status(self, state: str) -> dict:
        return {**self._base("status"), "state": state, **self.cell}

    def publish_cell_status(self, report) -> None:
        """The cell's status on the retained status topic when it changes: ``level`` (ok, moved, warn, drifting),
        ``message``, ``calibration_version``, ``in_use_by`` and ``pending`` (`handeye.app.shift_record`)."""
        loop = getattr(report, "loop", None)
        record = getattr(report, "record", None)
        if loop is None or record is None or loop.history.in_use is None:
            return
        level, message = record.status(time.time())
        pending = loop.history.pending
        cell = {"level": level, "message": message, "calibration_version": loop.history.in_use.number,
                "in_use_by": loop.in_use_by(),
                "pending": None if pending is None else {"version": pending.number, "state": pending.state}}
        if cell != self.cell:
            self.cell = cell
            self.publish("status", self._status("online"), retain=True)

    def _outage_payload(self, event: OutageEvent, message: str) -> dict:
        """An outage message: the event's fields, ``t`` the time it happened, ``since`` the outage's start."""
        return {**self._base("outage"), **dataclasses.asdict(event), "since": event.t - event.outage_s,
                "message": message}

    def outage(self, event: OutageEvent) -> None:
        """Publish the start or end of a device outage (its failed reconnect attempts are not published); held
        for an absent broker like an alarm."""
        if event.event in ("outage_start", "outage_end"):
            self.publish("outage", self._outage_payload(event, event.message()))

    def error(self, sample: int, message: str) -> None:
        """An unexpected error that ends the run (`handeye.app.runs.monitor.run_monitor`'s ``on_error``): on the alarm
        topic, ``event`` ``"monitor_error"``, held for an absent broker like an alarm."""
        self.publish("alarm", {**self._base("alarm"), "event": "monitor_error", "sample": sample, "message": message})

    def __call__(self, obs, update, report) -> None:
        """`handeye.app.runs.monitor.run_monitor`'s ``on_update``: the status (retained, when it changes),
        estimate (retained), drift, and the alarm if one fired."""
        self.session = str(report.session)
        self.publish_cell_status(report)
        if report.estimate is not None:
            xyz, q = tf.to_xyz_quat(report.estimate)
            parent = self.frames["flange"] if self.setup.camera_on_flange else self.frames["base"]
            msg = {**self._base("estimate"), "sample": obs.index, "transform": self.setup.camera_name,
                   "parent_frame": parent, "child_frame": self.frames["camera"],
                   "translation_m": xyz.tolist(), "quaternion_xyzw": q.tolist(),
                   "sigma_mm": None, "sigma_deg": None, "n_samples": report.n_samples,
                   "samples_until_armed": report.samples_until_armed, "alarms": len(report.alarms)}
            if report.estimate_sigma is not None:
                msg["sigma_deg"] = float(np.rad2deg(report.estimate_sigma[0]))
                msg["sigma_mm"] = report.estimate_sigma[1] * 1e3
            self.publish("estimate", msg, retain=True)
        if report.drift is not None:
            msg = {**self._base("drift"), "sample": obs.index, "translation_mm": report.drift[0],
                   "rotation_deg": report.drift[1]}
            if update is not None:
                msg.update(rate_mm_h=update.drift_rate_mm_h, rate_deg_h=update.drift_rate_deg_h,
                           level=str(update.level), verify_mm=update.verify_mm, error_mm=update.error_mm,
                           hours_to_tolerance=update.hours_to_tolerance)
            self.publish("drift", msg)
        if update is not None and update.alarm:
            a = report.alarms[-1]
            self.publish("alarm", {**self._base("alarm"), "event": "camera_" + a.kind, "sample": a.sample_index,
                                   "statistic": a.info.get("statistic"), "alarm_count": len(report.alarms),
                                   "drift_mm": None if report.drift is None else report.drift[0],
                                   "drift_deg": None if report.drift is None else report.drift[1],
                                   "drift_rate_mm_h": update.drift_rate_mm_h,
                                   "hours_to_tolerance": update.hours_to_tolerance, "message": update.message})


def make_publisher(mqtt: MqttConfig, setup: Setup, frames: dict) -> MqttPublisher | None:
    """A publisher for an enabled ``[mqtt]`` table, else None."""
    return MqttPublisher(mqtt, setup, frames) if mqtt.enabled else None

