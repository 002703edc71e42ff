"""The state of a monitored cell as its newest run left it on disk: for ``handeye status`` and ``handeye approve``.

A run (a monitor session, or a ``replay --monitor --out`` directory) keeps
``calibration_in_use.yaml`` (rewritten at every version change, approval,
acknowledgement, *moved* alarm and at its end: `handeye.app.calibration_in_use`),
``alarms.yaml`` and ``approvals.jsonl`` (`handeye.app.calibration_versions`). What to
look at is named by the run's directory, its ``calibration_in_use.yaml``, or
a cell config (its newest run of the setup under ``session.root``;
none: the embedded simulated cell's).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import yaml

from handeye.app import calibration_in_use
from handeye.app.calibration_versions import Approvals, History, Version, write_approval
from handeye.app.errors import SessionError
from handeye.app.files import read_text_file
from handeye.app.shift_record import ALARMS_FILE


def resolve_run(target: Path | None) -> Path:
    """The run directory ``target`` names (module docstring).

    Raises
    ------
    SessionError, ConfigError
        No monitoring run there, or a config that cannot be read.
    """
    if target is not None and not str(target).endswith(".toml"):
        found = calibration_in_use.find(Path(target))
        if found is None:
            raise SessionError(f"{target}: no {calibration_in_use.FILE_NAME} (not a monitoring run, or one that was "
                               "never armed)")
        return found.parent
    from handeye.app.config import load_config

    cfg = load_config(target)
    found = calibration_in_use.latest(Path(cfg.session.root), cfg.setup)
    if found is None:
        raise SessionError(f"no monitoring run of {cfg.setup} under {cfg.session.root} "
                           f"({'the embedded cell' if target is None else target}'s session.root)")
    return found.parent


@dataclass
class CellState:
    """What a run's files say: the document of its ``calibration_in_use.yaml``, its history, its alarms, and
    the approvals written since its last write."""

    run: Path
    doc: dict
    history: History
    alarms: list
    approvals: list

    @classmethod
    def read(cls, run: Path) -> "CellState":
        path = Path(run) / calibration_in_use.FILE_NAME
        doc = calibration_in_use.load(path)
        if "calibration_history" not in doc:
            raise SessionError(f"{path}: written before calibration versions (no calibration_history): run the "
                               "monitor once more with this handeye")
        history = History.from_dict(doc["calibration_history"])
        alarms = []
        if (Path(run) / ALARMS_FILE).is_file():
            try:
                alarms = (yaml.safe_load(read_text_file(Path(run) / ALARMS_FILE, SessionError)) or {}).get("alarms")
            except yaml.YAMLError:
                alarms = []
        return cls(Path(run), doc, history, alarms or [], Approvals([Path(run)]).new())

    @property
    def ended(self) -> bool:
        return self.doc.get("calibration_in_use", {}).get("why") == "end of the run"

    def approved_not_applied(self) -> dict | None:
        """An approval of the pending version that the run has not applied yet (it reads them at every poll;
        a run that has ended leaves it to the run that continues from it)."""
        pending = self.history.pending
        if pending is None:
            return None
        return next((a for a in reversed(self.approvals) if a["version"] == pending.number), None)

    def lines(self) -> list[str]:
        """One screen: the status, the calibration in use, who uses which version, what is pending, the last
        alarm, the history."""
        status = self.doc.get("status") or {}
        level = str(status.get("level", "unknown")).upper()
        lines = [f"{level}: {status.get('message', 'no status written (a run of an older handeye)')}"]
        meta = self.doc.get("calibration_in_use", {})
        lines.append(f"  run: {self.run} ({'ended' if self.ended else 'running or stopped unexpectedly'}; "
                     f"last written {meta.get('written')}: {meta.get('why')})")
        in_use = self.history.in_use
        if in_use is not None:
            lines.append(f"  calibration in use: version {in_use.number}, predicted error {in_use.error_mm:.2f} mm, "
                         f"{in_use.why}, in use since {calibration_in_use.local_time(in_use.applied)} "
                         f"({in_use.applied_by})")
        users = self.doc.get("in_use_by") or {}
        lines.append("  in use by: " + (", ".join(f"{name}: " + (f"version {v}" if v else "no version reported")
                                                  for name, v in users.items())
                                        or "no consumer configured ([consumers]): calibration_in_use.yaml is "
                                           "handed on by hand or the calibration hook"))
        lines += self._pending_lines()
        if self.alarms:
            a = self.alarms[-1]
            lines.append(f"  last alarm: {a.get('alarm')} at {a.get('time')} (sample {a.get('sample')}): "
                         f"{str(a.get('message', '')).split('; re-learn')[0]}")
        else:
            lines.append("  last alarm: none")
        lines.append("  history: " + "; ".join(_version_words(v) for v in self.history.versions[-6:]))
        return lines

    def _pending_lines(self) -> list[str]:
        pending = self.history.pending
        if pending is None:
            return ["  pending: none"]
        ev = pending.evidence
        why = (f"the camera moved {ev.get('moved_mm')} mm / {ev.get('moved_deg')} deg from version "
               f"{ev.get('moved_from_version')} (alarm at {ev.get('alarm_time')}, sample {ev.get('alarm_sample')}); "
               f"{ev.get('relearnt', '')}")
        lines = [f"  pending: version {pending.number}, predicted error {pending.error_mm:.2f} mm, {pending.state}: "
                 f"{why}"]
        approval = self.approved_not_applied()
        if approval is not None:
            lines.append(f"    approved by {approval['by']} at {calibration_in_use.local_time(approval['t'])}: "
                         + ("the run that continues from this one puts it in use at its start" if self.ended
                            else "the run puts it in use at its next poll"))
        elif self.history.policy == "approve":
            lines.append(f"    to put it in use: handeye approve {self.run}")
        return lines


def _version_words(v: Version) -> str:
    return f"v{v.number} {v.state.replace('_', ' ')} ({v.why}, {v.error_mm:.2f} mm)"


def approve(run: Path, version: int | None, by: str, t: float) -> tuple[Version, CellState]:
    """Approve the pending version of ``run`` (``version``: must be it, when given): appended to its
    ``approvals.jsonl``; returns the version and the state read before.

    Raises
    ------
    SessionError
        Nothing pending, or ``version`` is not the pending one.
    """
    state = CellState.read(run)
    pending = state.history.pending
    in_use = state.history.in_use
    if pending is None:
        raise SessionError(f"{run}: nothing to approve: version {in_use.number if in_use else '?'} is in use and no "
                           "re-learnt version is pending")
    if version is not None and version != pending.number:
        raise SessionError(f"{run}: version {version} is not pending; version {pending.number} is ({pending.state})")
    write_approval(run, pending.number, by, t)
    return pending, state
