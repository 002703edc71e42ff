"""Versions of the calibration in use: which camera transform the cell's consumers are to use, since when, why.

The arming calibration is version 1 (or the version a continued run was
using). A re-learn after a *moved* alarm proposes the next version with its
evidence (the alarm's sample, how far the camera moved, the samples it was
re-learnt from, its predicted error); it follows the estimate while the
re-learnt camera settles, and is then *settled*. The cell's policy
(``[monitor] apply``) says what happens next: ``"auto"`` puts a settled
version in use at once, ``"approve"`` holds it until a person approves it
(`approve`; ``handeye approve <run>`` writes the approval into the run's
``approvals.jsonl``, which the run reads at every sample). A version that a
newer one replaces before it was in use is *superseded*. Only a version in
use is given to the consumers (`handeye.app.consumers`).

`History` is plain data: it goes into ``calibration_in_use.yaml``
(``calibration_history``), so that a run continued from it (a restart, the
next shift) keeps every version, the one in use and the one pending.
"""

from __future__ import annotations

import getpass
import json
import logging
import os
import socket
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

from handeye.app.errors import SessionError

log = logging.getLogger(__name__)

APPROVALS_FILE = "approvals.jsonl"
#: The policies of ``[monitor] apply``.
Policy = Literal["auto", "approve"]
#: Versions kept in full in the history (the newest): months of re-learns stay bounded.
MAX_VERSIONS = 200


@dataclass
class Version:
    """One version of the calibration in use.

    ``camera_transform``: 4x4 (m), ``T_base_cam`` eye-to-hand, ``T_flange_cam``
    eye-in-hand; ``error_mm``: its predicted error over the workspace
    (1-sigma); ``evidence``: why it exists (the alarm's sample, the move,
    the samples it was re-learnt from); ``state``: ``settling``, ``settled``
    (waiting for approval), ``in_use``, ``superseded`` or ``replaced``
    (was in use, a newer one is)."""

    number: int
    created: float
    why: str
    camera_transform: list
    error_mm: float
    evidence: dict = field(default_factory=dict)
    state: str = "settling"
    settled: float | None = None
    approved_by: str | None = None
    approved: float | None = None
    applied: float | None = None
    applied_by: str | None = None

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class History:
    """Every version, the policy, and what is in use and pending (module docstring)."""

    policy: Policy = "approve"
    versions: list[Version] = field(default_factory=list)

    # -------------------------------------------------------------- queries

    @property
    def in_use(self) -> Version | None:
        return next((v for v in reversed(self.versions) if v.state == "in_use"), None)

    @property
    def pending(self) -> Version | None:
        """The newest version not in use yet (settling or waiting for approval), or None."""
        v = self.versions[-1] if self.versions else None
        return v if v is not None and v.state in ("settling", "settled") else None

    @property
    def waiting_for_approval(self) -> Version | None:
        v = self.pending
        return v if v is not None and v.state == "settled" and self.policy == "approve" else None

    def version(self, number: int) -> Version | None:
        return next((v for v in self.versions if v.number == number), None)

    # -------------------------------------------------------------- changes

    def first(self, camera_transform, error_mm: float, t: float, why: str) -> Version:
        """The calibration the run is armed from: in use at once (a person gave it: a calibration, or the
        version a continued run was using)."""
        v = self._new(camera_transform, error_mm, t, why, {})
        self._apply(v, t, "armed")
        return v

    def propose(self, camera_transform, error_mm: float, t: float, why: str, evidence: dict) -> Version:
        """A re-learnt calibration: the next version, settling; a pending one it replaces is superseded."""
        old = self.pending
        if old is not None:
            old.state = "superseded"
        return self._new(camera_transform, error_mm, t, why, evidence)

    def follow(self, camera_transform, error_mm: float) -> None:
        """The settling version follows the estimate as the stops refine it."""
        v = self.pending
        if v is not None and v.state == "settling":
            v.camera_transform, v.error_mm = _matrix(camera_transform), float(error_mm)

    def settle(self, camera_transform, error_mm: float, t: float) -> Version | None:
        """The settling version has settled: in use now with ``auto`` (or once approved), else it waits.
        Returns the version put in use, or None."""
        v = self.pending
        if v is None or v.state != "settling":
            return None
        self.follow(camera_transform, error_mm)
        v.state, v.settled = "settled", float(t)
        if self.policy == "auto":
            return self._apply(v, t, "auto (apply = \"auto\")")
        if v.approved is not None:
            return self._apply(v, t, f"approved by {v.approved_by}")
        return None

    def approve(self, number: int, by: str, t: float, now: float | None = None) -> Version | None:
        """A person approved version ``number`` at ``t``: in use from ``now`` (default ``t``) if settled, else once
        settled. Returns the version put in use, or None. An approval of a version that is not pending (in use
        already, superseded, unknown) changes nothing and is logged."""
        v = self.version(number)
        if v is None or v.state not in ("settling", "settled"):
            log.info("approval of version %d by %s: nothing to do, it is %s", number, by,
                     "unknown" if v is None else v.state.replace("_", " "))
            return None
        v.approved_by, v.approved = by, float(t)
        return self._apply(v, t if now is None else now, f"approved by {by}") if v.state == "settled" else None

    def _new(self, camera_transform, error_mm, t, why, evidence) -> Version:
        number = self.versions[-1].number + 1 if self.versions else 1
        v = Version(number, float(t), why, _matrix(camera_transform), float(error_mm), dict(evidence))
        self.versions.append(v)
        del self.versions[:-MAX_VERSIONS]
        return v

    def _apply(self, v: Version, t: float, by: str) -> Version:
        for old in self.versions:
            if old.state == "in_use":
                old.state = "replaced"
        v.state, v.applied, v.applied_by = "in_use", float(t), by
        return v

    # -------------------------------------------------------------- plain data

    def to_dict(self) -> dict:
        in_use, pending = self.in_use, self.pending
        return {"policy": self.policy, "in_use": None if in_use is None else in_use.number,
                "pending": None if pending is None else pending.number,
                "versions": [v.to_dict() for v in self.versions]}

    @classmethod
    def from_dict(cls, data: dict, policy: Policy | None = None) -> "History":
        """From `to_dict`'s form; ``policy`` (the cell's config now) takes the place of the one written.

        Raises
        ------
        SessionError
            A malformed history (the field named).
        """
        try:
            versions = [Version(**v) for v in data.get("versions", [])]
            return cls(policy or data.get("policy", "approve"), versions)
        except (TypeError, AttributeError) as e:
            raise SessionError(f"calibration_history: {e}") from None


def _matrix(T) -> list:
    return [[float(x) for x in row] for row in T]


# ------------------------------------------------------------------ approvals


def who() -> str:
    """``user@host`` of the person running this process (what an approval records)."""
    try:
        user = getpass.getuser()
    except (KeyError, OSError):
        user = str(os.getuid())
    return f"{user}@{socket.gethostname()}"


def write_approval(run: Path, version: int, by: str, t: float) -> Path:
    """Append an approval of ``version`` to ``run/approvals.jsonl`` (one line, flushed and synced): the run reads
    it at its next sample, a run continued from ``run`` at its start."""
    path = Path(run) / APPROVALS_FILE
    with open(path, "a") as fh:
        fh.write(json.dumps({"version": int(version), "by": by, "t": float(t)}) + "\n")
        fh.flush()
        os.fsync(fh.fileno())
    return path


@dataclass
class Approvals:
    """Reads the approvals appended to ``approvals.jsonl`` in some run directories since the last read."""

    directories: list[Path]
    offsets: dict = field(default_factory=dict)

    def new(self) -> list[dict]:
        """The approvals appended since the last call (a torn last line is read at the next call)."""
        found = []
        for d in self.directories:
            path = Path(d) / APPROVALS_FILE
            try:
                with open(path, "rb") as fh:
                    fh.seek(self.offsets.get(path, 0))
                    data = fh.read()
            except OSError:
                continue
            end = data.rfind(b"\n") + 1
            self.offsets[path] = self.offsets.get(path, 0) + end
            for line in data[:end].splitlines():
                try:
                    item = json.loads(line)
                    found.append({"version": int(item["version"]), "by": str(item["by"]), "t": float(item["t"])})
                except (ValueError, KeyError, TypeError):
                    log.warning("%s: a malformed approval line skipped: %r", path, line[:200])
        return found
