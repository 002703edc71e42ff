"""The consumers of the calibration in use: each is given the version in use and reports the version it has taken.

``[consumers]`` (`handeye.app.config.ConsumersConfig`) names them:

- ``robot_program``: the UR program over RTDE registers (`handeye.drivers.robot.ur_registers`; the URScript snippet in
  docs/monitor-service.md);
- ``mqtt``: ``<prefix>/calibration`` (retained), acknowledged on ``<prefix>/calibration/ack`` (`handeye.app.mqtt`);
- ``ros2``: ``/handeye/calibration`` (TransformStamped, its version in ``header.frame_id``'s companion topic),
  acknowledged on ``/handeye/calibration/ack`` (`handeye.app.ros2`).

`CalibrationLoop` keeps the versions (`handeye.app.calibration_versions.History`) and
the consumers together and says what the cell's state is (`status`): a camera
that moved is ``moved`` until its re-learnt version is approved where the
policy asks for it and taken by every consumer; a consumer that has not taken
the version in use ``ack_timeout_s`` after it was given is a ``warn`` with its
name. The run polls it at every step (`poll`: the approvals, then the
consumers' acknowledgements, at most every `POLL_S`).
"""

from __future__ import annotations

import abc
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from handeye.app.calibration_versions import Approvals, History, Version
from handeye.calib import transforms as tf
from handeye.calib.errors import HandeyeError
from handeye.drivers.errors import ConnectionLostError
from handeye.drivers.robot.ur_registers import URCalibrationRegisters

log = logging.getLogger(__name__)

#: Seconds between two polls of the consumers' acknowledgements, and between two attempts to reach one that is down.
POLL_S, RETRY_S = 0.5, 5.0


class Consumer(abc.ABC):
    """Something that uses the camera transform: `give` it a version, ask it which one it has `taken`."""

    name: str = "consumer"

    def open(self) -> None:
        """Connect (raises `HandeyeError` when it cannot: the loop tries again later)."""

    @abc.abstractmethod
    def give(self, version: Version) -> None:
        """Hand over ``version`` (raises `HandeyeError` when it cannot)."""

    @abc.abstractmethod
    def taken(self) -> int | None:
        """The version it reports having taken (None or 0: none yet)."""

    def close(self) -> None:
        """Disconnect; never raises."""


class RobotProgram(Consumer):
    """The UR robot program: the transform and its version in RTDE input registers, its acknowledgement in an
    output register (`handeye.drivers.robot.ur_registers`)."""

    name = "robot program"

    def __init__(self, host: str | Callable[[], str]):
        # A callable: the controller's address as the robot connection has it now (a simulated controller
        # may have moved to a free loopback address).
        self.host_of = host if callable(host) else (lambda: host)
        self.registers = URCalibrationRegisters(self.host_of())

    def open(self) -> None:
        self.registers.connect()

    def give(self, version: Version) -> None:
        if self.registers.host != self.host_of():
            self.registers.close()
            self.registers = URCalibrationRegisters(self.host_of())
        if not self.registers.is_connected:
            self.registers.connect()
        self.registers.write(version.number, tf.to_ur_pose(np.array(version.camera_transform)))

    def taken(self) -> int | None:
        return self.registers.taken() or None

    def close(self) -> None:
        self.registers.close()


class MqttConsumer(Consumer):
    """A consumer over MQTT named ``name``: given the version in use on ``<prefix>/calibration`` (retained), it
    acknowledges ``{"consumer": name, "version": n}`` on ``<prefix>/calibration/ack`` (`handeye.app.mqtt`)."""

    def __init__(self, publisher, name: str):
        self.publisher, self.name = publisher, name
        publisher.listen()

    def give(self, version: Version) -> None:
        # Held while the broker is away and sent on its return: a given version is never lost.
        self.publisher.publish_calibration(version.number, version.camera_transform, version.error_mm,
                                           version.applied or 0.0, version.applied_by or "")

    def taken(self) -> int | None:
        if not self.publisher.connected.is_set():
            raise ConnectionLostError("the MQTT broker is away")
        return self.publisher.acks.get(self.name)


class Ros2Consumer(Consumer):
    """A ROS 2 consumer named ``name``: given the version in use on ``/handeye/calibration`` (TransformStamped)
    and ``/handeye/calibration_version`` (UInt32), both latched, it acknowledges on
    ``/handeye/calibration_ack`` (KeyValue ``key`` its name, ``value`` the version) (`handeye.app.ros2`)."""

    def __init__(self, diagnostics, name: str):
        self.diagnostics, self.name = diagnostics, name

    def give(self, version: Version) -> None:
        self.diagnostics.publish_calibration(version.number, version.camera_transform, version.applied or 0.0)

    def taken(self) -> int | None:
        return self.diagnostics.acks.get(self.name)


@dataclass
class Link:
    """What the loop knows of one consumer: the version given, when, the version it reported, why it is out of
    reach (None: reachable)."""

    consumer: Consumer
    given: int | None = None
    given_t: float | None = None
    taken: int | None = None
    taken_t: float | None = None
    error: str | None = None
    tried_t: float = -math.inf

    @property
    def name(self) -> str:
        return self.consumer.name


@dataclass
class CalibrationLoop:
    """The versions and the consumers of one run (module docstring).

    ``run``: its session directory (what ``handeye approve`` names);
    ``approvals``: where approvals are read from (the run's, and that of
    the run it continues); ``on_event(t, kind, fields)``: told of every
    version change, approval and acknowledgement (the session's events)."""

    history: History
    links: list[Link] = field(default_factory=list)
    run: Path | None = None
    approvals: Approvals | None = None
    ack_timeout_s: float = 60.0
    on_event: object = None
    polled_t: float = -math.inf
    #: The newest *moved* alarm: (local time, sample, mm) for the status sentence.
    last_move: dict | None = None

    @classmethod
    def of(cls, history: History, consumers: list[Consumer], **kw) -> "CalibrationLoop":
        return cls(history, [Link(c) for c in consumers], **kw)

    # -------------------------------------------------------------- changes

    def event(self, t: float, kind: str, **fields) -> None:
        log.info("%s: %s", kind.replace("_", " "), fields)
        if self.on_event is not None:
            self.on_event(t, kind, fields)

    def applied(self, version: Version | None, t: float) -> None:
        """A version was put in use: recorded, and given to every consumer."""
        if version is None:
            return
        self.event(t, "calibration_version_in_use", version=version.number, by=version.applied_by,
                   error_mm=round(version.error_mm, 3))
        for link in self.links:
            self._give(link, version, t)

    def _give(self, link: Link, version: Version, t: float) -> None:
        link.tried_t = t
        try:
            link.consumer.give(version)
        except HandeyeError as e:
            if link.error is None:
                log.warning("%s: version %d not given: %s", link.name, version.number, e)
                self.event(t, "consumer_unreachable", consumer=link.name, version=version.number, error=str(e))
            link.error = str(e)
            return
        if link.error is not None:
            self.event(t, "consumer_reachable", consumer=link.name)
        link.error, link.given, link.given_t = None, version.number, t

    def approve(self, number: int, by: str, approved_t: float, t: float) -> None:
        """An approval of version ``number`` (`History.approve`), recorded; the version given out if in use now."""
        version = self.history.version(number)
        before = None if version is None else version.approved
        applied = self.history.approve(number, by, approved_t, t)
        if version is not None and version.approved != before:
            self.event(t, "calibration_approved", version=number, by=by)
        self.applied(applied, t)

    def poll(self, t: float) -> None:
        """New approvals, then each consumer: given the version in use if it has not been (or was out of reach),
        asked which version it has taken. At most every `POLL_S`."""
        if t - self.polled_t < POLL_S:
            return
        self.polled_t = t
        for a in self.approvals.new() if self.approvals is not None else []:
            self.approve(a["version"], a["by"], a["t"], t)
        in_use = self.history.in_use
        if in_use is None:
            return          # nothing to give yet (the engine arms itself from the first samples)
        for link in self.links:
            if link.given != in_use.number or link.error is not None:
                if t - link.tried_t >= (RETRY_S if link.error is not None else 0.0):
                    self._give(link, in_use, t)
                if link.error is not None:
                    continue
            self._ask(link, t)

    def _ask(self, link: Link, t: float) -> None:
        try:
            taken = link.consumer.taken()
        except HandeyeError as e:
            if link.error is None:
                log.warning("%s: cannot ask which version it uses: %s", link.name, e)
                self.event(t, "consumer_unreachable", consumer=link.name, error=str(e))
            link.error, link.tried_t = str(e), t
            return
        if taken and taken != link.taken:
            link.taken, link.taken_t = int(taken), t
            self.event(t, "calibration_taken", consumer=link.name, version=int(taken))

    def close(self) -> None:
        for link in self.links:
            link.consumer.close()

    # -------------------------------------------------------------- what it says

    def in_use_by(self) -> dict:
        """``{consumer: the version it reported (None: none yet)}``."""
        return {link.name: link.taken for link in self.links}

    def behind(self) -> list[Link]:
        """The consumers that do not report the version in use."""
        in_use = self.history.in_use
        return [] if in_use is None else [link for link in self.links if link.taken != in_use.number]

    def silent(self, t: float) -> list[Link]:
        """The consumers behind for more than ``ack_timeout_s`` since the version in use was given, or out of
        reach."""
        behind = self.behind()
        return [link for link in self.links if link.error is not None
                or (link in behind and (link.given_t is None or t - link.given_t > self.ack_timeout_s))]

    def uses(self) -> str:
        """Who uses which version, in words: ``the robot program uses version 2, mqtt has not reported one``."""
        parts = []
        for link in self.links:
            what = f"uses version {link.taken}" if link.taken else "has reported no version"
            parts.append(f"the {link.name} {what}" + (f" (out of reach: {link.error})" if link.error else ""))
        return ", ".join(parts)

    def status(self, t: float, relearning: bool = False) -> tuple[str, str] | None:
        """``(level, sentence)`` of the loop: ``moved`` while a move is not closed (re-learning, a version
        pending, a consumer behind a re-learnt version in use), ``warn`` when a consumer is silent, None when
        every consumer uses the version in use (the engine's figures say the rest)."""
        h, in_use, pending = self.history, self.history.in_use, self.history.pending
        move = self._move_words()
        if relearning:
            return "moved", f"{move}; re-learning it from the production stops" + self._still(in_use)
        if pending is not None:
            if pending.state == "settling":
                what = f"re-learnt as version {pending.number} ({pending.error_mm:.1f} mm), settling"
            else:
                what = (f"re-learnt as version {pending.number} ({pending.error_mm:.1f} mm), waiting for approval: "
                        f"{approve_command(self.run)}")
            return "moved", f"{move}; {what}" + self._still(in_use)
        behind = self.behind()
        if in_use is not None and behind and in_use.number > 1 and in_use.why.startswith("re-learnt"):
            return "moved", f"{move}; re-learnt as version {in_use.number} ({in_use.error_mm:.1f} mm){self._still(in_use)}"
        silent = self.silent(t)
        if silent:
            names = ", ".join(f"the {link.name}" for link in silent)
            return "warn", f"version {in_use.number} is in use, but {names} has not confirmed it: {self.uses()}"
        return None

    def _move_words(self) -> str:
        m = self.last_move
        if m is None:
            return "camera moved"
        mm = "" if m.get("mm") is None else f" {m['mm']:.1f} mm"
        return f"camera moved{mm} at {m['time']} (sample {m['sample']})"

    def _still(self, in_use: Version | None) -> str:
        """``; the robot program still uses version 1, ...``: who uses which version while a move is open."""
        if not self.links:
            return "; no consumer is configured ([consumers]): hand calibration_in_use.yaml on"
        newer = self.history.pending is not None
        words = []
        for link in self.links:
            if not link.taken:
                words.append(f"the {link.name} has reported no version")
            else:
                still = "still " if newer or (in_use is not None and link.taken < in_use.number) else ""
                words.append(f"the {link.name} {still}uses version {link.taken}")
        return "; " + ", ".join(words)


def approve_command(run: Path | None) -> str:
    return f"handeye approve {run}" if run is not None else "handeye approve <run>"
