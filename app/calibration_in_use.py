"""The calibration in use, carried across monitoring runs: ``calibration_in_use.yaml``.

``handeye monitor`` keeps it in its session directory and ``replay
--monitor`` in its ``--out`` directory. It is a result in the
``result.yaml`` format (the live camera transform: ``T_base_cam``
eye-to-hand, ``T_flange_cam`` eye-in-hand, with the engine's covariance and
camera correction, and every line to paste), plus ``calibration_in_use``
(when and why it was written, re-learns, the camera's move since the cell's
first calibration) and ``monitor_state`` (`handeye.calib.monitor.snapshot`: what the
next run arms from). It is rewritten atomically (a temporary file renamed
over it) when the engine is armed, at every re-learn, when a re-learnt camera
has settled, and at the end of the run, so that a run killed at any moment
leaves the last of them whole.

The next run continues from it: ``--reference`` of a monitor session or of a
``replay --monitor --out`` directory (or of the file itself), or
``[monitor] continue = true``, which takes the newest one under
``session.root`` of the same setup (`latest`).
"""

from __future__ import annotations

import datetime as _dt
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from handeye.app.errors import SessionError
from handeye.app.files import read_text_file
from handeye.app.formats.export import result_to_dict
from handeye.app.calibration_versions import History
from handeye.app.consumers import CalibrationLoop
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError
from handeye.calib.monitor import AlarmLevel, EngineState, MonitorEngine, MonitorUpdate, workspace_distance
from handeye.calib.monitor.snapshot import Snapshot, snapshot_from_dict, snapshot_to_dict
from handeye.calib.setup import Setup

log = logging.getLogger(__name__)

FILE_NAME = "calibration_in_use.yaml"
#: Largest such file read (bytes): the state of 24 kinematic parameters and 200 workspace points is ~40 kB.
MAX_BYTES = 4 * 1024 * 1024


def local_time(t: float) -> str:
    """Local ISO 8601 time with its offset, to the second (what people read)."""
    return _dt.datetime.fromtimestamp(t).astimezone().isoformat(timespec="seconds")


#: The keys of the file besides the result of the version in use.
OWN_KEYS = ("status", "calibration_version", "in_use_by", "calibration_in_use", "pending", "calibration_history",
            "monitor_state")


def document(engine: MonitorEngine, frames: dict | None, *, why: str, t: float, loop=None,
             result: dict | None = None, pending: dict | None = None, status: tuple | None = None) -> dict:
    """The file's content: the calibration in use as a result (``result``, the version in use's; default the
    live estimate), its version and who uses which (``loop``: `handeye.app.consumers.CalibrationLoop`), the cell's
    status (``(level, sentence)``), when and why, the version pending, the history, and the engine's
    snapshot."""
    doc = dict(result) if result is not None else result_to_dict(engine.result(), frames)
    if status is not None:
        doc["status"] = {"level": status[0], "message": status[1]}
    mm, deg = engine.moved_since(engine.origin)
    history = None if loop is None else loop.history
    in_use = None if history is None else history.in_use
    if in_use is not None:
        doc["calibration_version"] = in_use.number
        doc["in_use_by"] = loop.in_use_by()
    doc["calibration_in_use"] = {
        "written": local_time(t),
        "why": why,
        **({} if in_use is None else {"version": in_use.number, "since": local_time(in_use.applied),
                                      "applied_by": in_use.applied_by, "predicted_error_mm": round(in_use.error_mm, 3)}),
        "relearns": int(engine.relearns),
        "moved_since_first_calibration": {"mm": round(mm, 3), "deg": round(deg, 4),
                                          "note": "RMS over the workspace of the live camera transform against the "
                                                  "cell's first calibration, each with its camera correction"},
        "continue_with": "handeye monitor --reference <this directory> (or [monitor] carry_over = true)",
    }
    waiting = None if history is None else history.pending
    if waiting is not None:
        doc["pending"] = {"version": waiting.number, "state": waiting.state,
                          "predicted_error_mm": round(waiting.error_mm, 3), "evidence": waiting.evidence,
                          **({"approve_with": f"handeye approve {loop.run}"} if waiting.state == "settled"
                             and history.policy == "approve" and loop.run is not None else {}),
                          "result": pending}
    if history is not None:
        doc["calibration_history"] = history.to_dict()
    doc["monitor_state"] = snapshot_to_dict(engine.snapshot())
    return doc


def write(directory: Path, engine: MonitorEngine, frames: dict | None, *, why: str, t: float, **kw) -> Path:
    """Write (atomically) ``directory/calibration_in_use.yaml`` for ``engine``'s calibration in use (``kw``: as
    `document`)."""
    path = Path(directory) / FILE_NAME
    text = (f"# handeye: the calibration in use of a monitoring run ({engine.reference.setup}); camera_transform = "
            f"{Setup(engine.reference.setup).camera_name}, its version calibration_version.\n"
            "# The next run continues from monitor_state: handeye monitor --reference <this directory>.\n"
            + yaml.safe_dump(document(engine, frames, why=why, t=t, **kw), sort_keys=False, width=1000))
    tmp = path.with_name(f".{FILE_NAME}.tmp")
    with open(tmp, "w") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    try:
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError:
        pass                # a directory that cannot be fsync'ed (some network filesystems): the rename stands
    return path


PENDING_FILE = "calibration_pending.yaml"


def write_pending(directory: Path, result: dict | None) -> None:
    """``directory/calibration_pending.yaml``: the version pending as a result (``handeye verify --result`` checks
    it on fresh poses before it is approved), written atomically; removed when nothing is pending."""
    path = Path(directory) / PENDING_FILE
    if result is None:
        path.unlink(missing_ok=True)
        return
    tmp = path.with_name(f".{PENDING_FILE}.tmp")
    tmp.write_text("# handeye: the re-learnt calibration pending (not in use yet); calibration_in_use.yaml holds the "
                   "version in use.\n" + yaml.safe_dump(result, sort_keys=False, width=1000))
    os.replace(tmp, path)


def find(path: Path) -> Path | None:
    """The ``calibration_in_use.yaml`` that ``path`` names: the file, or the one in the directory; else None."""
    path = Path(path)
    if path.name == FILE_NAME and path.is_file():
        return path
    candidate = path / FILE_NAME
    return candidate if path.is_dir() and candidate.is_file() else None


def load(path: Path) -> dict:
    """The document of a ``calibration_in_use.yaml`` (`SessionError`: unreadable, not YAML, no ``monitor_state``)."""
    text = read_text_file(path, SessionError, max_bytes=MAX_BYTES)
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise SessionError(f"{path}: not YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(doc, dict) or "monitor_state" not in doc:
        raise SessionError(f"{path}: no monitor_state (written by an older handeye, or not a monitor's file)")
    return doc


def read(path: Path, setup: Setup) -> Snapshot:
    """The snapshot of a ``calibration_in_use.yaml`` for a run of ``setup``.

    Raises
    ------
    SessionError
        Unreadable, not YAML, without a valid ``monitor_state`` (the field named), or of another setup.
    """
    doc = load(path)
    try:
        snapshot = snapshot_from_dict(doc["monitor_state"])
    except CalibrationError as e:
        raise SessionError(f"{path}: {e}") from None
    if snapshot.reference.setup != Setup(setup):
        raise SessionError(f"{path} is {snapshot.reference.setup}, the config is {Setup(setup)}")
    return snapshot


def read_versions(path: Path, policy: str) -> tuple[History | None, dict, dict | None]:
    """``(history, result of the version in use, result of the version pending)`` of a
    ``calibration_in_use.yaml``; the history is None in a file written before versions (`SessionError` as
    `load`)."""
    doc = load(path)
    if "calibration_history" not in doc:
        return None, {k: v for k, v in doc.items() if k not in OWN_KEYS}, None
    history = History.from_dict(doc["calibration_history"], policy)
    pending = (doc.get("pending") or {}).get("result")
    return history, {k: v for k, v in doc.items() if k not in OWN_KEYS}, pending


def latest(root: Path, setup: Setup) -> Path | None:
    """The newest ``calibration_in_use.yaml`` of ``setup`` among the session directories below ``root`` (by the
    time it was written), or None."""
    root = Path(root)
    if not root.is_dir():
        return None
    found = [p for p in root.glob(f"*_{Setup(setup).value}/{FILE_NAME}") if p.is_file()]
    return max(found, key=lambda p: p.stat().st_mtime, default=None)


#: Why a calibration in use is written when a version is put in use (`InUseFile.on_new` is told); the other
#: writes record a proposed version, an acknowledgement, the end of a run or an error.
NEW_CALIBRATION = ("armed", "version in use")


@dataclass
class InUseFile:
    """Keeps ``calibration_in_use.yaml`` in a directory (`handeye.app.calibration_in_use`) and the versions of the
    calibration in use (``loop``: `handeye.app.consumers.CalibrationLoop`; default: ``apply = "auto"`` and no
    consumer, as ``replay --monitor`` runs): written when the engine is armed, when a re-learn proposes a
    version, when a version is put in use (settled with ``auto``, or approved), when a consumer reports a
    version, and at the end. ``on_new(path, why, t)`` is called after each write of a version put in use
    (`NEW_CALIBRATION`), once the file is in place."""

    directory: Path
    frames: dict | None = None
    written: object = None           # the engine's calibration in use last seen (`handeye.calib.monitor.InUse`)
    on_new: Callable[[Path, str, float], None] | None = None
    loop: CalibrationLoop = field(default_factory=lambda: CalibrationLoop(History("auto")))
    result: dict | None = None       # the version in use as a result (`handeye.app.formats.export.result_to_dict`)
    pending: dict | None = None      # the version pending, likewise
    said: tuple = ()                 # the versions and acknowledgements the file holds (`_said`)
    status: Callable[[], tuple] | None = None   # the cell's (level, sentence) now (`handeye.app.shift_record`)

    def write(self, engine: MonitorEngine, t: float, why: str) -> None:
        try:
            path = write(self.directory, engine, self.frames, why=why, t=t, loop=self.loop, result=self.result,
                         pending=self.pending, status=None if self.status is None else self.status())
            write_pending(self.directory, self.pending if self.loop.history.pending is not None else None)
        except OSError as e:
            log.error("%s not written (%s); the next run cannot continue from this one",
                      FILE_NAME, e.strerror or e)
            path = None
        self.written, self.said = engine.in_use, self._said()
        if path is not None and why in NEW_CALIBRATION and self.on_new is not None:
            self.on_new(path, why, t)

    def resume(self, path: Path) -> None:
        """Continue the versions of the run that wrote ``path`` (its history; the approvals of its directory
        are read too). A file without versions starts at version 1 (`armed`)."""
        history, result, pending = read_versions(path, self.loop.history.policy)
        if history is not None and history.in_use is not None:
            self.loop.history, self.result, self.pending = history, result, pending
        if self.loop.approvals is not None:
            self.loop.approvals.directories.append(Path(path).parent)

    def armed(self, engine: MonitorEngine, t: float) -> None:
        if not engine.armed:
            return
        history = self.loop.history
        if history.in_use is None:
            self.result = result_to_dict(engine.result(), self.frames)
            self.loop.applied(history.first(engine.camera_transform, engine.in_use.sigma_mm, t, "armed"), t)
        self.write(engine, t, "armed")

    def update(self, engine: MonitorEngine, update: MonitorUpdate | None, t: float) -> None:
        """After a sample: a re-learn proposes a version, the end of its settling settles it (in use with
        ``auto``); while it settles it follows the estimate."""
        relearnt = update is not None and (update.message.startswith("re-learnt") or "; re-learnt" in update.message)
        if update is not None and update.alarm == AlarmLevel.MOVED and not relearnt:
            self.write(engine, t, "camera moved: re-learning it")     # the status it holds says so
            return
        if update is None or engine.in_use is self.written:
            return
        if relearnt:
            self._propose(engine, update, t)
            self.write(engine, t, "re-learnt: version proposed")
        elif update.state in (EngineState.ARMED, EngineState.WARMING):
            settling = self.loop.history.pending
            if settling is None or settling.state != "settling":
                self.write(engine, t, "settled after a re-learn")
                return
            self.pending = result_to_dict(engine.result(), self.frames)
            version = self.loop.history.settle(engine.camera_transform, engine.in_use.sigma_mm, t)
            self.loop.event(t, "calibration_version_settled", version=settling.number)
            self._in_use(engine, version, t, "settled after a re-learn")
        else:      # settling: the version follows the estimate (the file is written when it has settled)
            self.loop.history.follow(engine.camera_transform, engine.in_use.sigma_mm)

    def _propose(self, engine: MonitorEngine, update: MonitorUpdate, t: float) -> None:
        history = self.loop.history
        old = history.in_use
        C, move = engine.camera_transform, self.loop.last_move or {}
        mm = deg = None
        if old is not None:
            T_old = np.array(old.camera_transform)
            mm = workspace_distance(C, T_old, engine.reference.workspace) * 1e3
            deg = float(np.rad2deg(tf.rotation_angle(C[:3, :3] @ T_old[:3, :3].T)))
            move["mm"] = mm
        evidence = {"alarm_sample": move.get("sample"), "alarm_time": move.get("time"),
                    "moved_from_version": None if old is None else old.number,
                    "moved_mm": None if mm is None else round(mm, 3), "moved_deg": None if deg is None else round(deg, 4),
                    "relearnt": update.message.split("; ")[-1]}
        v = history.propose(C, engine.in_use.sigma_mm, t, f"re-learnt after the move at sample {move.get('sample')}",
                            evidence)
        self.pending = result_to_dict(engine.result(), self.frames)
        self.loop.event(t, "calibration_version_proposed", version=v.number, **evidence)

    def _in_use(self, engine: MonitorEngine, version, t: float, why: str) -> None:
        """``version`` (None: nothing new) is in use: the file holds it, the consumers are given it."""
        if version is None:
            self.write(engine, t, why)
            return
        self.result = self.pending if self.pending is not None else result_to_dict(engine.result(), self.frames)
        self.pending = None
        self.loop.applied(version, t)
        self.write(engine, t, "version in use")

    def poll(self, engine: MonitorEngine, t: float) -> None:
        """Approvals and acknowledgements (`handeye.app.consumers.CalibrationLoop.poll`); the file follows them."""
        in_use = self.loop.history.in_use
        self.loop.poll(t)
        if not engine.armed or self._said() == self.said:
            return
        if self.loop.history.in_use is not in_use:
            self._in_use(engine, self.loop.history.in_use, t, "approved")
        else:
            self.write(engine, t, "a consumer reported its version")

    def end(self, engine: MonitorEngine, t: float) -> None:
        if engine.armed:
            self.write(engine, t, "end of the run")

    def _said(self) -> tuple:
        h = self.loop.history
        pending = h.pending
        return (h.in_use and h.in_use.number, pending and (pending.number, pending.state),
                tuple(self.loop.in_use_by().items()))
