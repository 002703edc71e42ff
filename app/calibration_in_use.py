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
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import yaml

from handeye.app.errors import SessionError
from handeye.app.files import read_text_file
from handeye.app.formats.export import result_to_dict
from handeye.calib.errors import CalibrationError
from handeye.calib.monitor import EngineState, MonitorEngine, MonitorUpdate
from handeye.calib.monitor.snapshot import Snapshot, snapshot_from_dict, snapshot_to_dict
from handeye.calib.setup import Setup

log = logging.getLogger(__name__)

FILE_NAME = "calibration_in_use.yaml"
#: Largest such file read (bytes): the state of 24 kinematic parameters and 200 workspace points is ~40 kB.
MAX_BYTES = 4 * 1024 * 1024


def local_time(t: float) -> str:
    """Local ISO 8601 time with its offset, to the second (what people read)."""
    return _dt.datetime.fromtimestamp(t).astimezone().isoformat(timespec="seconds")


def document(engine: MonitorEngine, frames: dict | None, *, why: str, t: float) -> dict:
    """The file's content: the live calibration as a result, when and why, and the engine's snapshot."""
    doc = result_to_dict(engine.result(), frames)
    mm, deg = engine.moved_since(engine.origin)
    doc["calibration_in_use"] = {
        "written": local_time(t),
        "why": why,
        "relearns": int(engine.relearns),
        "moved_since_first_calibration": {"mm": round(mm, 3), "deg": round(deg, 4),
                                          "note": "RMS over the workspace of the live camera transform against the "
                                                  "cell's first calibration, each with its camera correction"},
        "continue_with": "handeye monitor --reference <this directory> (or [monitor] carry_over = true)",
    }
    doc["monitor_state"] = snapshot_to_dict(engine.snapshot())
    return doc


def write(directory: Path, engine: MonitorEngine, frames: dict | None, *, why: str, t: float) -> Path:
    """Write (atomically) ``directory/calibration_in_use.yaml`` for ``engine``'s calibration in use."""
    path = Path(directory) / FILE_NAME
    text = (f"# handeye: the calibration in use of a monitoring run ({engine.reference.setup}); camera_transform = "
            f"{Setup(engine.reference.setup).camera_name}, the live estimate.\n"
            "# The next run continues from monitor_state: handeye monitor --reference <this directory>.\n"
            + yaml.safe_dump(document(engine, frames, why=why, t=t), sort_keys=False, width=1000))
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


def find(path: Path) -> Path | None:
    """The ``calibration_in_use.yaml`` that ``path`` names: the file, or the one in the directory; else None."""
    path = Path(path)
    if path.name == FILE_NAME and path.is_file():
        return path
    candidate = path / FILE_NAME
    return candidate if path.is_dir() and candidate.is_file() else None


def read(path: Path, setup: Setup) -> Snapshot:
    """The snapshot of a ``calibration_in_use.yaml`` for a run of ``setup``.

    Raises
    ------
    SessionError
        Unreadable, not YAML, without a valid ``monitor_state`` (the field named), or of another setup.
    """
    text = read_text_file(path, SessionError, max_bytes=MAX_BYTES)
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise SessionError(f"{path}: not YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(doc, dict) or "monitor_state" not in doc:
        raise SessionError(f"{path}: no monitor_state (written by an older handeye, or not a monitor's file)")
    try:
        snapshot = snapshot_from_dict(doc["monitor_state"])
    except CalibrationError as e:
        raise SessionError(f"{path}: {e}") from None
    if snapshot.reference.setup != Setup(setup):
        raise SessionError(f"{path} is {snapshot.reference.setup}, the config is {Setup(setup)}")
    return snapshot


def latest(root: Path, setup: Setup) -> Path | None:
    """The newest ``calibration_in_use.yaml`` of ``setup`` among the session directories below ``root`` (by the
    time it was written), or None."""
    root = Path(root)
    if not root.is_dir():
        return None
    found = [p for p in root.glob(f"*_{Setup(setup).value}/{FILE_NAME}") if p.is_file()]
    return max(found, key=lambda p: p.stat().st_mtime, default=None)


#: Why a calibration in use is written when it is a new one (`InUseFile.on_new` is told); the end of a run and
#: an error only record the live estimate.
NEW_CALIBRATION = ("armed", "re-learnt", "settled after a re-learn")


@dataclass
class InUseFile:
    """Keeps ``calibration_in_use.yaml`` in a directory (`handeye.app.calibration_in_use`): written when the engine is
    armed, at every re-learn, when a re-learnt camera has settled, and at the end. ``on_new(path, why, t)`` is
    called after each write of a new calibration in use (`NEW_CALIBRATION`), once the file is in place."""

    directory: Path
    frames: dict | None = None
    written: object = None           # the calibration in use last written (`handeye.calib.monitor.InUse`)
    on_new: Callable[[Path, str, float], None] | None = None

    def write(self, engine: MonitorEngine, t: float, why: str) -> None:
        try:
            path = write(self.directory, engine, self.frames, why=why, t=t)
        except OSError as e:
            log.error("%s not written (%s); the next run cannot continue from this one",
                      FILE_NAME, e.strerror or e)
            path = None
        self.written = engine.in_use
        if path is not None and why in NEW_CALIBRATION and self.on_new is not None:
            self.on_new(path, why, t)

    def armed(self, engine: MonitorEngine, t: float) -> None:
        if engine.armed:
            self.write(engine, t, "armed")

    def update(self, engine: MonitorEngine, update: MonitorUpdate | None, t: float) -> None:
        """After a sample: a re-learn, or the end of its settling, is a new calibration in use."""
        if update is None or engine.in_use is self.written:
            return
        if update.message.startswith("re-learnt") or "; re-learnt" in update.message:
            self.write(engine, t, "re-learnt")
        elif update.state in (EngineState.ARMED, EngineState.WARMING):
            self.write(engine, t, "settled after a re-learn")

    def end(self, engine: MonitorEngine, t: float) -> None:
        if engine.armed:
            self.write(engine, t, "end of the run")
