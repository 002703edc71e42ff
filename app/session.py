"""The session store: the contract between recording and replay.

A session is a directory (layout documented in ``docs/session-format.md``)::

    session.json     format name + version, setup, frames, config, intrinsics, created
    samples.jsonl    one JSON object per line, appended and fsync'ed as taken
    frames/          NNNNNN_color.png (8-bit BGR) and NNNNNN_depth.png (16-bit, mm)

Each line of ``samples.jsonl`` has a ``kind``: ``"sample"`` (an accepted
measurement), ``"skip"`` (a frame or pose that gave no measurement, with the
reason) or ``"event"`` (alarm, stop, note). Frames are written before the line
that names them, so a line never points at a missing file; a run killed
mid-write leaves at most a torn last line, which `read_session` ignores with a
warning. Poses and points alone make a valid session (frames are optional), so
other programs can write sessions for ``handeye replay``.
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import math
import os
import tempfile
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from handeye.app.errors import SessionError
from handeye.app.files import inside, read_regular_file
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError
from handeye.calib.observation import Observation
from handeye.calib.setup import Setup, check_setup
from handeye.drivers.camera.depth import depth_from_mm, depth_to_mm

log = logging.getLogger(__name__)

FORMAT_NAME = "handeye-session"
FORMAT_VERSION = 1

FRAMES = {s.value: {"A": "T_base_flange", "B": "T_cam_marker", "X": s.x_name, "Y": s.y_name, "equation": s.equation}
          for s in Setup}


def _fsync_write(path: Path, data: bytes) -> None:
    """Write a whole file durably (tmp + fsync + rename) so readers never see half of it."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _jsonable(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    return x


@dataclass
class Session:
    """A session read back from disk.

    Attributes
    ----------
    path : Path
    header : dict
        ``session.json`` as written (format, version, setup, frames, config, ...).
    observations : list[Observation]
        Accepted samples in recorded order.
    skipped : list[dict]
        ``{"index", "t", "reason", ...}`` of every skipped frame or pose.
    events : list[dict]
        Alarms, stops and notes, in order.
    """

    path: Path
    header: dict
    observations: list[Observation] = field(default_factory=list)
    skipped: list[dict] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)

    @property
    def setup(self) -> Setup:
        return Setup(self.header["setup"])

    @property
    def truth(self) -> dict:
        """True transforms (4x4 arrays) recorded by simulated sources, else empty (checked by `read_session`)."""
        return {k: np.asarray(v, dtype=float) for k, v in (self.header.get("truth") or {}).items()}

    @property
    def interrupted(self) -> bool:
        """True when this calibration session's last run was stopped by Ctrl-C and no later run completed it
        (of its ``interrupted`` and ``stopped`` events, the last is ``interrupted``): ``--resume`` continues it.
        A monitor's Ctrl-C is its normal end: False for other sources than ``handeye`` (calibrate, demo)."""
        if self.header.get("source") != "handeye":
            return False
        ends = [e.get("event") for e in self.events if e.get("event") in ("interrupted", "stopped")]
        return bool(ends) and ends[-1] == "interrupted"

    def load_frames(self, obs: Observation) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Color (H, W, 3) uint8 BGR and depth (H, W) float32 m of a sample, or None if not stored
        (or pruned by a monitor's ``keep_frames`` budget)."""
        import cv2  # only needed when frames are asked for

        def load(key, flags):
            # Frame names come from the session's own lines: read them only inside the session.
            where = f"{self.path / 'samples.jsonl'} sample {obs.index}: {key}"
            file = inside(self.path, obs.meta[key], SessionError, what=where)
            if not file.exists():
                return None
            try:
                data = read_regular_file(file, SessionError)
            except SessionError as e:  # e.g. a name of "." or "frames": say which sample named it
                raise SessionError(f"{where}: {e}") from None
            try:
                img = cv2.imdecode(np.frombuffer(data, np.uint8), flags) if data else None
            except cv2.error:
                img = None
            if img is None:
                raise SessionError(f"{where}: {obs.meta[key]!r} is not an image")
            return img

        color = load("color", cv2.IMREAD_COLOR) if obs.meta.get("color") else None
        depth = load("depth", cv2.IMREAD_UNCHANGED) if obs.meta.get("depth") else None
        if depth is not None:
            depth = depth_from_mm(depth)
        return color, depth


class SessionWriter:
    """Append samples to a session directory, durably, one at a time.

    Use as a context manager. ``SessionWriter.create(root, setup, ...)`` makes a
    new timestamped directory; ``SessionWriter.resume(path)`` continues an
    existing one (sample indices continue after the last recorded one).
    """

    def __init__(self, path: Path, header: dict, next_index: int = 0, *, keep_frames: int | None = None):
        self.path = Path(path)
        self.header = header
        self.next_index = next_index
        # Disk budget (monitor): frames of only the last keep_frames samples/skips stay on disk.
        self.keep_frames = keep_frames
        self._frame_files: deque[int] = deque()  # indices whose frames are on disk, oldest first
        self.frames_pruned = 0
        self.n_samples = 0
        self.skip_reasons: Counter[str] = Counter()  # of this writer's run, for the summary
        self._lines = open(self.path / "samples.jsonl", "ab")

    @classmethod
    def create(
        cls,
        root: str | Path,
        setup: str,
        *,
        config: dict | None = None,
        intrinsics: dict | None = None,
        truth: dict | None = None,
        name: str | None = None,
        source: str = "handeye",
        keep_frames: int | None = None,
        devices: dict | None = None,
    ) -> "SessionWriter":
        """Create ``root/<name or UTC timestamp>_<setup>/`` with ``session.json``.

        Parameters
        ----------
        setup : {"eye_to_hand", "eye_in_hand"}
        config : dict, optional
            The configuration used, stored verbatim.
        intrinsics : dict, optional
            ``width, height, fx, fy, cx, cy, dist`` of the color camera.
        truth : dict of (4, 4) arrays, optional
            Known true transforms (simulated cells), e.g. ``T_base_cam``.
        keep_frames : int, optional
            Keep the frame PNGs of only the last this many samples and skips
            (older ones are deleted as new ones are written; their lines stay).
            None keeps every frame.
        devices : dict, optional
            What identifies the robot and the camera (`handeye.app.provenance.device_identity`).
        """
        setup = check_setup(setup, error=SessionError)
        now = _dt.datetime.now(_dt.timezone.utc)
        path = Path(root) / (name or f"{now:%Y%m%d-%H%M%S-%f}_{setup}")
        try:
            path.mkdir(parents=True, exist_ok=False)
        except FileExistsError:
            raise SessionError(f"session directory already exists: {path}") from None
        (path / "frames").mkdir()
        header = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "setup": setup.value,
            "frames": FRAMES[setup],
            "units": {"translation": "m", "rotation": "rad", "time": "s", "depth_png": "mm"},
            "created": now.isoformat(),
            "source": source,
            "intrinsics": intrinsics,
            "truth": _jsonable(truth) if truth else None,
            "config": _jsonable(config) if config else None,
        }
        if devices:
            header["devices"] = _jsonable(devices)
        _fsync_write(path / "session.json", json.dumps(header, indent=2).encode())
        return cls(path, header, keep_frames=keep_frames)

    @classmethod
    def resume(cls, path: str | Path) -> "SessionWriter":
        """Reopen an existing session for appending; indices continue after the last one."""
        session = read_session(path)
        last = [o.index for o in session.observations] + [s["index"] for s in session.skipped if "index" in s]
        _drop_torn_tail(Path(path) / "samples.jsonl")
        w = cls(Path(path), session.header, next_index=max(last, default=-1) + 1)
        w.n_samples = len(session.observations)
        return w

    def _append(self, record: dict) -> None:
        self._lines.write((json.dumps(_jsonable(record)) + "\n").encode())
        self._lines.flush()
        os.fsync(self._lines.fileno())

    def _write_frames(self, index: int, color, depth) -> dict:
        import cv2

        files = {}
        if color is not None:
            name = f"frames/{index:06d}_color.png"
            ok, buf = cv2.imencode(".png", color)
            if not ok:
                raise SessionError(f"could not encode color frame {index}")
            _fsync_write(self.path / name, buf.tobytes())
            files["color"] = name
        if depth is not None:
            name = f"frames/{index:06d}_depth.png"
            ok, buf = cv2.imencode(".png", depth_to_mm(depth))
            if not ok:
                raise SessionError(f"could not encode depth frame {index}")
            _fsync_write(self.path / name, buf.tobytes())
            files["depth"] = name
        if files and self.keep_frames is not None:
            self._frame_files.append(index)
            while len(self._frame_files) > self.keep_frames:
                self.drop_frames(self._frame_files.popleft())
        return files

    def drop_frames(self, index: int) -> None:
        """Delete the frame PNGs of sample/skip ``index`` (disk budget; its line stays and names them)."""
        removed = False
        for kind in ("color", "depth"):
            f = self.path / f"frames/{index:06d}_{kind}.png"
            if f.exists():
                f.unlink()
                removed = True
        self.frames_pruned += removed

    def add_sample(self, obs: Observation, *, color=None, depth=None) -> Observation:
        """Record an accepted sample (frames first, then its line). Returns it with its index and file names.

        ``obs.index`` is replaced by the session's next index.
        """
        index = self.next_index
        files = self._write_frames(index, color, depth)
        meta = {**obs.meta, **files}
        self._append({
            "kind": "sample",
            "index": index,
            "t": float(obs.t),
            "T_base_flange": obs.T_base_flange,
            "point_cam": obs.point_cam,
            "point_cov": obs.point_cov,
            "T_cam_marker": obs.T_cam_marker,
            "pose_cov": obs.pose_cov,
            "joints": obs.joints,
            "meta": meta,
        })
        self.next_index += 1
        self.n_samples += 1
        return Observation(index, obs.t, obs.T_base_flange, obs.point_cam, obs.point_cov,
                           obs.T_cam_marker, obs.pose_cov, meta, obs.joints)

    def add_skip(self, t: float, reason: str, *, T_base_flange=None, color=None, depth=None, **extra) -> int:
        """Record a frame or pose that produced no sample, with the reason (never dropped silently)."""
        index = self.next_index
        files = self._write_frames(index, color, depth)
        self.skip_reasons[reason] += 1
        self._append({"kind": "skip", "index": index, "t": float(t), "reason": reason,
                      "T_base_flange": T_base_flange, **files, **extra})
        self.next_index += 1
        return index

    def add_event(self, t: float, event: str, **data) -> None:
        """Record an alarm, stop or note (``event`` is a short name like ``"alarm"``)."""
        self._append({"kind": "event", "t": float(t), "event": event, **data})

    def close(self) -> None:
        if not self._lines.closed:
            self._lines.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def new_output_dir(root, setup, kind: str) -> Path:
    """A new directory ``<root>/<UTC time>_<setup>_<kind>`` beside the sessions, for a run that writes files
    but records no samples (a plan, an offline verification); `SessionError` naming ``session.root``."""
    now = _dt.datetime.now(_dt.timezone.utc)
    path = Path(root) / f"{now:%Y%m%d-%H%M%S-%f}_{setup}_{kind}"
    try:
        path.mkdir(parents=True)
    except OSError as e:
        raise SessionError(f"session.root: cannot create {path} ({e.strerror})") from None
    return path


def check_writable_root(root) -> Path:
    """Make sure sessions can be written below ``root`` (created if missing), before any device opens.

    Creates and removes a probe file, which also catches read-only mounts and
    full disks where permission bits alone would not (and root ignores them).

    Raises
    ------
    SessionError
        Naming ``root`` and why it is not writable.
    """
    root = Path(root)
    try:
        root.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".handeye-write-probe-", dir=root)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise SessionError(f"cannot write sessions below {root}: {e.strerror or e}") from None
    return root


def _drop_torn_tail(path: Path) -> None:
    """Truncate a torn (unterminated) last line so appends start on a fresh line."""
    if not path.exists():
        return
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        with open(path, "r+b") as f:
            f.truncate(data.rfind(b"\n") + 1)


def read_session(path: str | Path) -> Session:
    """Read a session directory written by `SessionWriter` or another program.

    Reads regular files only (a FIFO named ``samples.jsonl`` is refused, not
    waited on) and every field is checked where it is read.

    Raises
    ------
    SessionError
        Naming the file and line: ``session.json`` missing, not a JSON
        object, of another format or a newer version, or with a malformed
        ``truth``; a line of ``samples.jsonl`` (other than a torn last one)
        that is not a JSON object, has a missing or non-numeric field, a
        ragged or wrongly shaped matrix, or a sample index used twice.
        A torn last line (a run killed mid-write) is ignored with a warning.
    """
    path = Path(path)
    header_path = path / "session.json"
    if not header_path.exists():
        raise SessionError(f"not a session (no session.json): {path}")
    # The session's own files, too, must not be symlinks out of it.
    header_path = inside(path, "session.json", SessionError, what=str(path))
    header = _json(read_regular_file(header_path, SessionError, max_bytes=MAX_HEADER_BYTES), header_path)
    if not isinstance(header, dict):
        raise SessionError(f"{header_path}: expected a JSON object, got {type(header).__name__}")
    if header.get("format") != FORMAT_NAME:
        raise SessionError(f"{path}: format is {header.get('format')!r:.60}, expected {FORMAT_NAME!r}")
    version = header.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or version > FORMAT_VERSION or version < 1:
        raise SessionError(f"{path}: unsupported session version {version!r:.40} (this handeye reads <= {FORMAT_VERSION})")
    check_setup(header.get("setup"), f"{path}: setup", SessionError)
    _check_truth(header.get("truth"), header_path)

    session = Session(path, header)
    lines_path = path / "samples.jsonl"
    if not lines_path.exists() and not lines_path.is_symlink():
        return session
    raw = read_regular_file(inside(path, "samples.jsonl", SessionError, what=str(path)), SessionError).split(b"\n")
    # A file ending with "\n" splits into a final empty chunk; anything else there is a torn write.
    if raw and raw[-1] == b"":
        raw.pop()
        torn_tail = False
    else:
        torn_tail = bool(raw)
    seen: dict[int, int] = {}  # sample/skip index -> line
    for i, line in enumerate(raw, start=1):
        if not line.strip():
            continue
        where = f"{lines_path} line {i}"
        try:
            rec = _json(line, where)
        except SessionError:
            if torn_tail and i == len(raw):
                log.warning("%s: ignoring torn last line %d (run interrupted mid-write)", lines_path, i)
                break
            raise
        if not isinstance(rec, dict):
            raise SessionError(f"{where}: expected a JSON object, got {type(rec).__name__}")
        kind = rec.get("kind", "sample")
        if kind == "sample":
            obs = _observation(rec, where)
            _unique(seen, obs.index, i, where)
            session.observations.append(obs)
        elif kind == "skip":
            if "index" in rec:
                _unique(seen, _int(rec["index"], f"{where}: index"), i, where)
            if "t" in rec:
                _real(rec["t"], f"{where}: t")
            session.skipped.append(rec)
        elif kind == "event":
            session.events.append(rec)
        else:
            raise SessionError(f"{where}: unknown kind {kind!r:.40}")
    return session


#: ``session.json`` is a few kB (config, intrinsics, truth).
MAX_HEADER_BYTES = 16 * 1024 * 1024


def _json(data: bytes, where) -> object:
    """Parsed JSON of ``data``; SessionError naming ``where`` on bad JSON, bad UTF-8 or absurd nesting."""
    try:
        return json.loads(data)
    except (ValueError, RecursionError) as e:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise SessionError(f"{where}: invalid JSON: {str(e)[:120]}") from None


def _unique(seen: dict, index: int, line: int, where: str) -> None:
    if index in seen:
        raise SessionError(f"{where}: index {index} is used twice (also on line {seen[index]}); "
                           "refusing to guess which sample it is")
    seen[index] = line


def _int(value, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise SessionError(f"{what} must be an integer >= 0, got {value!r:.40}")
    return value


def _real(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SessionError(f"{what} must be a finite number, got {value!r:.40}")
    return float(value)


def _array(value, shape, what: str):
    if value is None:
        return None
    try:
        a = tf.as_real_array(value, what, max_magnitude=None)
    except CalibrationError as e:
        raise SessionError(str(e)) from None
    if a.shape != shape:
        raise SessionError(f"{what} must have shape {shape}, got {a.shape}")
    return a


def _check_truth(truth, where: Path) -> None:
    """``truth`` of ``session.json``: absent/null, or a mapping of names to finite 4x4 transforms."""
    if truth is None:
        return
    if not isinstance(truth, dict):
        raise SessionError(f"{where}: truth must be an object of 4x4 transforms, got {type(truth).__name__}")
    for name, value in truth.items():
        try:
            tf.check_transform(value, f"truth.{name}", atol=1e-5)
        except CalibrationError as e:
            raise SessionError(f"{where}: {e}") from None


def _observation(rec: dict, where: str) -> Observation:
    for key in ("index", "t", "T_base_flange"):
        if key not in rec:
            raise SessionError(f"{where}: missing {key!r}")
    meta = rec.get("meta") or {}
    if not isinstance(meta, dict):
        raise SessionError(f"{where}: meta must be an object, got {type(meta).__name__}")
    joints = rec.get("joints")
    if joints is None and "q" in meta:
        # Sessions before the joints had a field of their own kept them in meta.
        meta = {k: v for k, v in meta.items() if k != "q"}
        joints = rec["meta"]["q"]
    obs = Observation(
        index=_int(rec["index"], f"{where}: index"),
        t=_real(rec["t"], f"{where}: t"),
        T_base_flange=_array(rec["T_base_flange"], (4, 4), f"{where}: T_base_flange"),
        point_cam=_array(rec.get("point_cam"), (3,), f"{where}: point_cam"),
        point_cov=_array(rec.get("point_cov"), (3, 3), f"{where}: point_cov"),
        T_cam_marker=_array(rec.get("T_cam_marker"), (4, 4), f"{where}: T_cam_marker"),
        pose_cov=_array(rec.get("pose_cov"), (6, 6), f"{where}: pose_cov"),
        meta=meta,
        joints=_array(joints, (6,), f"{where}: joints (rad)"),
    )
    if obs.point_cam is None and obs.T_cam_marker is None:
        raise SessionError(f"{where}: a sample needs point_cam or T_cam_marker")
    return obs
