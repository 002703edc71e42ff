"""Importer for ROS 2 bags (rosbag2 with sqlite3 or MCAP storage), read with the pure-Python ``rosbags``.

``handeye replay my_bag/`` takes the bag directory (``metadata.yaml`` and its
``.db3`` / ``.mcap`` files, as ``ros2 bag record`` writes it). No ROS install is
needed (``pip install 'handeye[ros]'``). What it reads, by message type:

- ``tf2_msgs/msg/TFMessage`` (``/tf`` and ``/tf_static``, any namespace): the
  robot. ``T_base_flange`` is composed along the tf tree from the ``base`` to
  the ``flange`` frame (``frames=``: ``--frames base=base_link,flange=tool0``
  or the config's ``[frames]``; default ``base`` / ``flange``, the UR ROS 2
  driver's names); each moving link is interpolated at the query time
  (`handeye.calib.timesync.interpolate_poses`: SLERP, linear translation).
- ``sensor_msgs/msg/Image`` (colour: ``bgr8 rgb8 bgra8 rgba8 mono8``; depth
  registered to it: ``16UC1`` / ``mono16`` in mm or ``32FC1`` in m) with the
  colour camera's ``sensor_msgs/msg/CameraInfo`` (``plumb_bob`` or
  ``rational_polynomial``), or ``sensor_msgs/msg/CompressedImage`` (``jpeg``,
  ``png``; depth as image_transport's ``16UC1; compressedDepth png``).
  The marker is measured in each chosen image as in a live run
  (`handeye.calib.vision.extract.extract` with the ``[marker]`` target): lifted from
  depth when there is a depth topic, from PnP otherwise.
- ``geometry_msgs/msg/PoseStamped`` of a marker detector (optional; the
  marker in the camera frame, ``T_cam_marker``): the measurements when the bag
  holds no images; with images, the stream the clock offset is estimated from.

Sampling: a sample is taken from a colour frame whose stamp (plus the clock
offset) finds the flange still for ``still_s`` before it (every tf sample in
that window within `STILL_MM` / `STILL_DEG` of the pose at the stamp), one
per standstill (the first of its frames whose marker is found, trying at most
`TRIES_PER_STANDSTILL`), as `handeye monitor` samples a robot that stops.
Frames taken while the robot moves, or where tf does not cover the stamp,
are not used (counted in ``meta["frames"]``); frames of a standstill where
the marker is not found are logged and listed in ``meta["skipped"]``.

Clock offset (``t_tf = t_camera + offset``): ``clock_offset_s=`` if given;
else, with a marker pose topic that moves, estimated by
`handeye.calib.timesync.estimate_clock_offset` (angular speeds of the flange and the
marker streams); else 0 (tf and images stamped by the same ROS clock).
Reported in ``meta["clock_offset_s"]``.

Damage is a `SessionError` naming the topic and the message index: a bag
rosbags cannot open, a message it cannot deserialize, a topic of the wrong
type, a message above `MAX_MESSAGE_BYTES`, an image whose size does not match
its data, missing frames. Only the files ``metadata.yaml`` names are read,
and only if they resolve inside the bag directory.

Setups: eye-to-hand (default) or eye-in-hand (``setup=``); either way the
samples carry ``A = T_base_flange`` and ``B = T_cam_marker``
(`handeye.app.formats.common`).
"""

from __future__ import annotations

import logging
import os
import sqlite3
import stat
import struct
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from handeye.app.errors import ConfigError, SessionError
from handeye.app.files import inside
from handeye.app.formats.common import DEFAULT_FRAMES, ImportedSamples, read_yaml
from handeye.app.formats.registry import register_import
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError, ExtractionError, HandeyeError, ParameterError
from handeye.calib.observation import Observation
from handeye.calib.setup import Setup, check_setup
from handeye.drivers.camera.ros_messages import MAX_SKEW_S, camera_intrinsics, color_image, depth_image

log = logging.getLogger(__name__)

TF = "tf2_msgs/msg/TFMessage"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POSE = "geometry_msgs/msg/PoseStamped"
#: Topic names (last component) that must carry tf.
TF_TOPICS = ("tf", "tf_static")

#: Largest message deserialized (bytes): a 4K RGB frame is 25 MB; anything far above is damage.
MAX_MESSAGE_BYTES = 64 * 1024 * 1024
#: Flange still: every tf pose in the window within this of the pose at the stamp (encoder noise is ~1e-3 mm).
STILL_MM, STILL_DEG = 0.1, 0.01
#: Default still window before a frame (s): `handeye.app.config.MonitorConfig.still_s`'s default.
STILL_S = 0.3
#: Frames of one standstill tried for the marker before the standstill is skipped.
TRIES_PER_STANDSTILL = 3
#: A tf link whose samples are further apart than this (s) around a stamp has dropped out there.
MAX_TF_GAP_S = 0.5
#: Clock-offset estimate used only above this correlation of the two angular-speed profiles.
MIN_OFFSET_SCORE = 0.8


#: What rosbags and its storage backends raise on damaged bytes: a deserializer reading past the end,
#: a corrupt sqlite page, a broken zstd/lz4 frame, a length field sending it astray.
_DAMAGE = (sqlite3.Error, struct.error, ValueError, KeyError, IndexError, TypeError, AttributeError,
           OverflowError, MemoryError, EOFError, OSError, RuntimeError, AssertionError, RecursionError,
           UnicodeDecodeError, NotImplementedError)


def _rosbags_errors() -> tuple[type[BaseException], ...]:
    import apsw  # rosbags' sqlite3 storage reads through it

    from rosbags.rosbag2 import ReaderError
    from rosbags.serde import SerdeError
    from rosbags.typesys import TypesysError

    return (ReaderError, SerdeError, TypesysError, apsw.Error, *_DAMAGE)


def is_ros2_bag(path: Path) -> bool:
    """A directory with a ``metadata.yaml`` (tried after every other importer; `load_ros2_bag` checks it is
    a rosbag2 one, and reads it only if it resolves inside the directory)."""
    return path.is_dir() and os.path.lexists(path / "metadata.yaml")


def parse_pairs(text: str | None, what: str, keys) -> dict[str, str]:
    """``"base=base_link,flange=tool0"`` -> ``{"base": "base_link", "flange": "tool0"}``, keys among ``keys``.

    For the command line's ``--frames`` / ``--topics``; `ConfigError` naming the bad part.
    """
    out: dict[str, str] = {}
    for part in (text or "").split(","):
        if not part.strip():
            continue
        key, sep, value = part.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or key not in keys or not value or any(c.isspace() for c in value):
            raise ConfigError(f"{what}: {part.strip()!r} is not KEY=NAME with KEY one of {', '.join(keys)}")
        out[key] = value
    return out


def _stamp(header) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def _bag_files(folder: Path) -> list[Path]:
    """The storage files ``metadata.yaml`` names, each a regular file inside the bag directory."""
    meta_path = inside(folder, "metadata.yaml", SessionError, what=f"{folder}: metadata.yaml")
    doc = read_yaml(meta_path)
    info = doc.get("rosbag2_bagfile_information")
    if not isinstance(info, dict):
        raise SessionError(f"{meta_path}: no rosbag2_bagfile_information mapping: not a ROS 2 bag")
    names = info.get("relative_file_paths")
    if not isinstance(names, list) or not names:
        raise SessionError(f"{meta_path}: relative_file_paths must list the bag's files, got {names!r:.80}")
    storage = info.get("storage_identifier")
    if storage not in ("sqlite3", "mcap"):
        raise SessionError(f"{meta_path}: storage_identifier {storage!r:.40} is not sqlite3 or mcap")
    files = []
    for name in names:
        p = inside(folder, name, SessionError, what=f"{meta_path}: relative_file_paths")
        try:
            mode = os.stat(p).st_mode
        except OSError as e:
            raise SessionError(f"{meta_path}: bag file {name!r:.80}: {e.strerror or e}") from None
        if not stat.S_ISREG(mode):
            raise SessionError(f"{meta_path}: bag file {name!r:.80} is not a regular file")
        files.append(p)
    return files


@dataclass
class _Topics:
    """The connections of each role, chosen from the bag's topics."""

    tf: list = field(default_factory=list)
    color: object = None
    depth: object = None
    info: object = None
    marker: object = None
    names: dict = field(default_factory=dict)


#: Where a bag has several topics of a role, the one whose name says so is taken (realsense2_camera
#: records colour, infra and compressed images, raw and aligned depth): a filter per role, in order.
PREFERRED = {"color": (lambda t: "color" in t or "rgb" in t, lambda t: not t.endswith("/compressed")),
             "depth": (lambda t: "aligned_depth_to_color" in t,)}


def _pick(conns, role: str, wanted: str | None, folder: Path):
    """The one connection of ``role`` among ``conns`` (or the one named ``wanted``)."""
    if wanted is not None:
        hits = [c for c in conns if c.topic == wanted]
        if not hits:
            raise SessionError(f"{folder}: topic {wanted!r} ({role}) is not in the bag with a fitting type "
                               f"(candidates: {sorted({c.topic for c in conns}) or 'none'})")
        return hits[0]
    for prefer in PREFERRED.get(role, ()):
        if len({c.topic for c in conns}) > 1 and any(prefer(c.topic.lower()) for c in conns):
            conns = [c for c in conns if prefer(c.topic.lower())]
    topics = sorted({c.topic for c in conns})
    if len(topics) > 1:
        raise SessionError(f"{folder}: several {role} topics ({', '.join(topics)}): name one with "
                           f"--topics {role}=<topic>")
    return conns[0] if conns else None


def _is_depth_topic(conn) -> bool:
    """A depth image topic by its name (``depth`` in it): the encoding is only known per message."""
    return "depth" in conn.topic.lower()


def _topics(reader, folder: Path, wanted: dict[str, str]) -> _Topics:
    by_type = defaultdict(list)
    for c in reader.connections:
        last = c.topic.rstrip("/").rsplit("/", 1)[-1]
        if last in TF_TOPICS and c.msgtype != TF:
            raise SessionError(f"{folder}: topic {c.topic} has type {c.msgtype}, expected {TF}")
        by_type[c.msgtype].append(c)
    t = _Topics(tf=by_type[TF])
    if not t.tf:
        raise SessionError(f"{folder}: no {TF} topic (/tf, /tf_static): the bag does not hold the robot's poses")
    images = by_type[IMAGE] + by_type[COMPRESSED]
    t.color = _pick([c for c in images if not _is_depth_topic(c)], "color", wanted.get("color"), folder)
    t.depth = _pick([c for c in images if _is_depth_topic(c)], "depth", wanted.get("depth"), folder)
    t.marker = _pick(by_type[POSE], "marker", wanted.get("marker"), folder)
    infos = by_type[CAMERA_INFO]
    if t.color is not None and wanted.get("info") is None:
        # The colour camera's info shares the image topic's namespace (/camera/color/{image_raw,camera_info}).
        ns = t.color.topic.rsplit("/", 1)[0]
        same_ns = [c for c in infos if c.topic.rsplit("/", 1)[0] == ns]
        infos = same_ns or infos
    t.info = _pick(infos, "info", wanted.get("info"), folder)
    if t.color is None and t.marker is None:
        raise SessionError(f"{folder}: no colour image ({IMAGE} or {COMPRESSED}) nor marker pose ({POSE}) topic")
    if t.color is not None and t.info is None:
        raise SessionError(f"{folder}: no {CAMERA_INFO} for {t.color.topic}: the marker cannot be measured "
                           "without the camera's intrinsics")
    t.names = {role: getattr(t, role).topic for role in ("color", "depth", "info", "marker")
               if getattr(t, role) is not None}
    return t


class _TfTree:
    """tf edges (parent -> child) with their samples; composes ``T_base_flange`` at any times."""

    def __init__(self):
        self.samples: dict[tuple[str, str], list[tuple[float, np.ndarray]]] = defaultdict(list)
        self.static: dict[tuple[str, str], np.ndarray] = {}
        self.parent: dict[str, str] = {}
        self._streams: dict = {}  # sorted samples per moving edge, built once all messages are in

    def add(self, msg, static: bool, where: str) -> None:
        for k, ts in enumerate(msg.transforms):
            parent, child = ts.header.frame_id.strip("/"), ts.child_frame_id.strip("/")
            w = f"{where} transform {k} ({parent or '?'} -> {child or '?'})"
            if not parent or not child or parent == child:
                raise SessionError(f"{w}: needs two different frame names")
            T = _checked_pose(ts.transform.translation, ts.transform.rotation, w, "")
            if self.parent.setdefault(child, parent) != parent:
                raise SessionError(f"{w}: {child} already has parent {self.parent[child]} (tf is a tree)")
            if static:
                self.static[(parent, child)] = T
            else:
                self.samples[(parent, child)].append((_stamp(ts.header), T))

    def _chain(self, frame: str, folder: Path) -> list[str]:
        """``frame`` and its ancestors up to the root."""
        chain = [frame]
        while chain[-1] in self.parent:
            chain.append(self.parent[chain[-1]])
            if len(chain) > len(self.parent) + 1:
                raise SessionError(f"{folder}: tf has a loop through {chain[-1]}")
        return chain

    def frames(self) -> list[str]:
        return sorted(set(self.parent) | set(self.parent.values()))

    def path(self, base: str, flange: str, folder: Path) -> list[tuple[str, str, bool]]:
        """Edges from ``base`` to ``flange``: ``(parent, child, forward)``; forward edges go down the tree."""
        for name, frame in (("base", base), ("flange", flange)):
            if frame not in self.parent and frame not in self.parent.values():
                raise SessionError(f"{folder}: frame {frame!r} ({name}) is not in /tf or /tf_static (frames: "
                                   f"{', '.join(self.frames()[:30])}); name them with --frames base=...,"
                                   f"flange=... or the config's [frames]")
        up_b, up_f = self._chain(base, folder), self._chain(flange, folder)
        common = next((f for f in up_b if f in up_f), None)
        if common is None:
            raise SessionError(f"{folder}: frames {base!r} and {flange!r} are in two unconnected tf trees")
        ups = up_b[:up_b.index(common)]    # base .. below common: traversed child -> parent
        downs = up_f[:up_f.index(common)][::-1]  # below common .. flange: parent -> child
        return [(self.parent[c], c, False) for c in ups] + [(self.parent[c], c, True) for c in downs]

    def stream(self, edge) -> tuple[np.ndarray, np.ndarray] | None:
        """A moving edge's samples sorted by time, duplicates dropped; None for a static edge."""
        if edge in self.static and edge not in self.samples:
            return None
        if edge not in self._streams:
            s = sorted(self.samples[edge], key=lambda x: x[0])
            t = np.array([x[0] for x in s])
            keep = np.concatenate([[True], np.diff(t) > 0]) if len(t) else np.zeros(0, bool)
            self._streams[edge] = (t[keep], np.array([x[1] for x in s]).reshape(-1, 4, 4)[keep])
        return self._streams[edge]

    def compose(self, edges, t_query: np.ndarray, folder: Path) -> tuple[np.ndarray, np.ndarray]:
        """``T_base_flange`` at ``t_query`` (M,): (M, 4, 4) and validity (M,) (every moving link covered)."""
        from handeye.calib.timesync import interpolate_poses

        T = np.broadcast_to(np.eye(4), (len(t_query), 4, 4)).copy()
        valid = np.ones(len(t_query), bool)
        for parent, child, forward in edges:
            s = self.stream((parent, child))
            if s is None:
                E = np.broadcast_to(self.static[(parent, child)], T.shape)
            elif len(s[0]) < 2:
                raise SessionError(f"{folder}: tf link {parent} -> {child} has {len(s[0])} sample(s) on /tf; "
                                   "a moving link needs a stream (or put it on /tf_static)")
            else:
                try:
                    E, ok = interpolate_poses(t_query, *s, max_gap=MAX_TF_GAP_S)
                except CalibrationError as e:
                    raise SessionError(f"{folder}: tf link {parent} -> {child}: {e}") from None
                valid &= ok
            T = T @ (E if forward else tf.invert(E))
        return T, valid

    def static_root_pose(self, frame: str) -> tuple[str, np.ndarray] | None:
        """``(root, T_root_frame)`` when every link from ``frame`` up to its tf root is static, else None."""
        if frame not in self.parent:
            return None
        T, child = np.eye(4), frame
        for _ in range(len(self.parent)):
            parent = self.parent.get(child)
            if parent is None:
                return child, T
            if (parent, child) not in self.static or self.samples.get((parent, child)):
                return None
            T, child = self.static[(parent, child)] @ T, parent
        return None

    def robot_times(self, edges) -> np.ndarray:
        """The stamps of every moving link on the path (where the composed pose can change)."""
        ts = [self.stream((p, c))[0] for p, c, _ in edges if self.stream((p, c)) is not None]
        return np.unique(np.concatenate(ts)) if ts else np.zeros(0)


def _why(e: BaseException) -> str:
    if isinstance(e, MemoryError):  # rosbags allocates what a length field says before reading
        return "a record length beyond memory: a damaged length field"
    return f"{type(e).__name__}: {str(e)[:160]}"


class _Bag:
    """The open bag: typestore and reader, with every rosbags failure turned into a `SessionError`."""

    def __init__(self, folder: Path):
        from rosbags.rosbag2 import Reader
        from rosbags.typesys import Stores, get_typestore

        self.folder = folder
        self.errors = _rosbags_errors()
        self.typestore = get_typestore(Stores.ROS2_HUMBLE)
        try:
            self.reader = Reader(folder)
            self.reader.open()
        except self.errors as e:
            raise SessionError(f"{folder}: not a readable ROS 2 bag ({_why(e)})") from None

    def close(self) -> None:
        try:
            self.reader.close()
        except self.errors:
            pass

    def messages(self, conns):
        """``(connection, index within its topic, raw bytes)`` in log order; damage names the topic."""
        counts: dict[int, int] = defaultdict(int)
        it = iter(self.reader.messages(connections=conns))
        while True:
            conn = None
            try:
                conn, _, raw = next(it)
            except StopIteration:
                return
            except self.errors as e:
                where = "" if conn is None else f" on {conn.topic}"
                raise SessionError(f"{self.folder}: cannot read the bag after "
                                   f"{sum(counts.values())} messages{where} ({_why(e)})") from None
            k = counts[conn.id]
            counts[conn.id] += 1
            if len(raw) > MAX_MESSAGE_BYTES:
                raise SessionError(f"{self.folder}: {conn.topic} message {k}: {len(raw)} bytes, above the "
                                   f"{MAX_MESSAGE_BYTES} bytes a message can be")
            yield conn, k, raw

    def decode(self, conn, k: int, raw):
        try:
            return self.typestore.deserialize_cdr(raw, conn.msgtype)
        except self.errors as e:
            raise SessionError(f"{self.folder}: {conn.topic} message {k} ({conn.msgtype}) cannot be "
                               f"deserialized ({_why(e)})") from None


@dataclass
class _Stream:
    """Stamps of one image or pose topic (first pass)."""

    t: list = field(default_factory=list)
    frame_id: str = ""


def _header_stamp(bag: _Bag, conn, k: int, raw) -> tuple[float, str, object]:
    """Stamp (s), ``frame_id`` and the deserialized message of a message with a ``header``."""
    msg = bag.decode(conn, k, raw)
    t = _stamp(msg.header)
    if not np.isfinite(t):
        raise SessionError(f"{bag.folder}: {conn.topic} message {k}: stamp is not finite")
    return t, msg.header.frame_id, msg


def _standstills(t_frames: np.ndarray, tree: _TfTree, edges, folder: Path, still_s: float):
    """For each frame time: the standstill it belongs to (-1: moving or tf not covering it), and its pose."""
    T_at, covered = tree.compose(edges, t_frames, folder)
    t_robot = tree.robot_times(edges)
    still = covered.copy()
    if len(t_robot):
        T_robot, ok_robot = tree.compose(edges, t_robot, folder)
        for i in np.flatnonzero(covered):
            lo, hi = np.searchsorted(t_robot, [t_frames[i] - still_s, t_frames[i]], side="left")
            # The window must reach back still_s: a stream starting after that has not seen the stop.
            if t_robot[0] > t_frames[i] - still_s:
                still[i] = False
                continue
            window = T_robot[lo:hi + 1][ok_robot[lo:hi + 1]]
            rot, trans = tf.pose_error(window, np.broadcast_to(T_at[i], window.shape)) if len(window) \
                else (np.zeros(1), np.zeros(1))
            still[i] = np.max(trans) <= STILL_MM * 1e-3 and np.rad2deg(np.max(rot)) <= STILL_DEG
    group = np.full(len(t_frames), -1)
    g, last = -1, None
    for i in range(len(t_frames)):
        if not still[i]:
            last = None
            continue
        if last is None or _moved(T_at[i], T_at[last]):
            g += 1
        group[i], last = g, i
    return group, T_at


def _moved(T1: np.ndarray, T2: np.ndarray) -> bool:
    rot, trans = tf.pose_error(T1[None], T2[None])
    return bool(trans[0] > STILL_MM * 1e-3 or np.rad2deg(rot[0]) > STILL_DEG)


def _nearest(t_sorted: np.ndarray, t: float) -> int | None:
    if not len(t_sorted):
        return None
    j = int(np.clip(np.searchsorted(t_sorted, t), 1, len(t_sorted) - 1)) if len(t_sorted) > 1 else 0
    if len(t_sorted) > 1 and abs(t_sorted[j - 1] - t) <= abs(t_sorted[j] - t):
        j -= 1
    return j if abs(t_sorted[j] - t) <= MAX_SKEW_S else None


def _offset(tree: _TfTree, edges, marker_t: np.ndarray, marker_T: np.ndarray, folder: Path) -> float | None:
    """`handeye.calib.timesync.estimate_clock_offset` of the flange and marker streams, if the data supports one."""
    from handeye.calib.timesync import estimate_clock_offset

    t_robot = tree.robot_times(edges)
    if len(t_robot) < 10 or len(marker_t) < 10:
        return None
    T_robot, ok = tree.compose(edges, t_robot, folder)
    order = np.argsort(marker_t)
    t_m, keep = np.unique(marker_t[order], return_index=True)
    try:
        est = estimate_clock_offset(t_robot[ok], T_robot[ok], t_m, marker_T[order][keep], max_offset=0.5,
                                    max_gap=MAX_TF_GAP_S)
    except HandeyeError as e:
        log.info("%s: no clock offset from the marker poses: %s", folder, e)
        return None
    return est.offset if est.score >= MIN_OFFSET_SCORE else None


def _checked_pose(p, q, where: str, what: str) -> np.ndarray:
    """4x4 from a message's position / translation ``p`` and quaternion ``q``: finite, bounded, unit (1e-3)."""
    v = np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w], dtype=float)
    if not np.isfinite(v).all() or np.abs(v).max() > tf.MAX_MAGNITUDE:
        raise SessionError(f"{where}: NaN, inf or a huge value in {what}{v.tolist()}")
    n = np.linalg.norm(v[3:])
    if abs(n - 1.0) > 1e-3:
        raise SessionError(f"{where}: quaternion norm is {n:.6f}, not 1")
    return tf.from_xyz_quat(v[:3], v[3:] / n)


def _marker_pose(msg, where: str) -> np.ndarray:
    return _checked_pose(msg.pose.position, msg.pose.orientation, where, "the pose ")


def _target(target, use_depth: bool):
    from handeye.calib.vision.extract import TargetConfig

    try:
        base = target if isinstance(target, TargetConfig) else TargetConfig(**(target or {}))
        return base.model_copy(update={"use_depth": use_depth})
    except (ParameterError, TypeError, ValueError) as e:
        raise ConfigError(f"marker target: {e}") from None


def _detect(path: Path, document) -> bool:
    return is_ros2_bag(Path(path))


@register_import("ros2_bag", _detect, open_setup=True, options=("frames", "topics", "target"))
def load_ros2_bag(path, setup: str | None = None, frames: dict | None = None, topics: dict | None = None,
                  target=None, clock_offset_s: float | None = None, still_s: float = STILL_S) -> ImportedSamples:
    """Samples of a ROS 2 bag: the marker measured at each standstill, paired with tf at the frame's stamp.

    Parameters
    ----------
    path : path of the bag directory
    setup : {"eye_to_hand", "eye_in_hand"}, optional
        Default eye-to-hand.
    frames : dict, optional
        ``base`` and ``flange`` tf frame names (`DEFAULT_FRAMES` otherwise); ``camera`` / ``marker``
        are only kept as names (the camera's default is the colour image's ``frame_id``).
    topics : dict, optional
        ``color``, ``depth``, ``info``, ``marker`` topics, where the bag has several of a kind.
    target : handeye.calib.vision.extract.TargetConfig or dict, optional
        The marker (the config's ``[marker]``; default a 5 cm DICT_4X4_50 ArUco, id 0).
    clock_offset_s : float, optional
        ``t_tf = t_camera + offset`` (s); estimated from a marker pose topic, or 0, if not given.
    still_s : float
        How long the flange must have been still before a frame (s).

    Returns
    -------
    ImportedSamples
        ``meta``: ``format``, ``source``, ``frames``, ``topics``, ``storage``, ``clock_offset_s``,
        ``intrinsics``, ``frames_read`` (colour frames by fate), ``skipped`` (standstills without a marker),
        and ``camera_tf`` (``root``, ``frame``, ``T_root_camera`` (4, 4)) when the bag's /tf_static holds
        the camera driver's links from a root (e.g. ``camera_link``) to the image's frame.
    """
    folder = Path(path)
    if not is_ros2_bag(folder):
        raise SessionError(f"{folder}: not a ROS 2 bag directory (no metadata.yaml)")
    setup = check_setup(setup or Setup.EYE_TO_HAND, error=SessionError)
    names = {**DEFAULT_FRAMES, **{k: v for k, v in (frames or {}).items() if v}}
    if not (isinstance(still_s, (int, float)) and 0 <= still_s < 60):
        raise ConfigError(f"still_s must be 0..60 s, got {still_s!r:.40}")
    files = _bag_files(folder)
    bag = _Bag(folder)
    try:
        roles = _topics(bag.reader, folder, {k: v for k, v in (topics or {}).items() if v})
        tree, streams, marker_T, infos = _first_pass(bag, roles, folder)
        edges = tree.path(names["base"], names["flange"], folder)
        marker_t = np.array(streams["marker"].t)
        offset, offset_how = _clock_offset(clock_offset_s, roles, tree, edges, marker_t, marker_T, folder)
        source = "color" if roles.color is not None else "marker"
        t_cam = np.array(streams[source].t)
        if not len(t_cam):
            raise SessionError(f"{folder}: {roles.names[source]} holds no messages")
        group, T_at = _standstills(t_cam + offset, tree, edges, folder, float(still_s))
        counts = {"read": int(len(t_cam)), "moving_or_no_tf": int(np.count_nonzero(group < 0)),
                  "standstills": int(group.max() + 1) if len(group) else 0}
        tries = _tries(group)
        skipped, intr = [], None
        if source == "marker":
            obs = _marker_samples(tries, t_cam, T_at, marker_T, roles)
        else:
            obs, skipped, intr = _image_samples(bag, roles, streams, infos, tries, t_cam, T_at, target, folder)
    finally:
        bag.close()
    counts["samples"] = len(obs)
    if not obs:
        raise SessionError(f"{folder}: no sample: {counts['read']} frames on {roles.names[source]}, "
                           f"{counts['standstills']} standstills of {names['flange']} in {names['base']}, "
                           f"{len(skipped)} without the marker")
    cam_frame = (frames or {}).get("camera") or streams[source].frame_id or names["camera"]
    meta = {"format": "ros2_bag", "source": str(folder), "time": "header stamps (s)",
            "storage": files[0].suffix.lstrip("."), "topics": roles.names,
            "frames": {**names, "camera": cam_frame},
            "clock_offset_s": float(offset), "clock_offset_from": offset_how, "frames_read": counts,
            "skipped": skipped}
    if intr is not None:
        meta["intrinsics"] = {"K": intr.K.tolist(), "dist": list(intr.dist)}
    # The camera driver's own tf (camera_link -> ... -> optical frame): a static transform for the
    # calibration must attach to its root, since a tf frame has one parent (docs/formats.md, "Use it in ROS 2").
    camera_tf = tree.static_root_pose(cam_frame)
    if camera_tf is not None:
        meta["camera_tf"] = {"root": camera_tf[0], "frame": cam_frame, "T_root_camera": camera_tf[1].tolist()}
    return ImportedSamples(obs, setup, meta)


def _first_pass(bag: _Bag, roles: _Topics, folder: Path):
    """Pass 1: tf, intrinsics, marker poses, and the stamps of the images (their pixels wait for pass 2).

    Returns ``(tree, streams, marker_T (n, 4, 4), infos)``: ``streams`` the stamps per role
    (``color``, ``depth``, ``marker``), ``infos`` the first CameraInfo with where it was read.
    """
    tree = _TfTree()
    streams = {role: _Stream() for role in ("color", "depth", "marker")}
    marker_T, infos = [], []
    role_of = {c.id: role for role in ("color", "depth", "info", "marker")
               if (c := getattr(roles, role)) is not None}
    first_pass = roles.tf + [c for c in bag.reader.connections if c.id in role_of]
    for conn, k, raw in bag.messages(first_pass):
        where = f"{folder}: {conn.topic} message {k}"
        if conn.msgtype == TF:
            msg = bag.decode(conn, k, raw)
            tree.add(msg, conn.topic.rstrip("/").endswith("tf_static"), where)
            continue
        role = role_of[conn.id]
        t, frame_id, msg = _header_stamp(bag, conn, k, raw)
        if role == "info":
            if not infos:
                infos.append((msg, where))
            continue
        s = streams[role]
        if s.t and t <= s.t[-1]:
            raise SessionError(f"{where}: stamp {t:.6f} s is not after the previous one ({s.t[-1]:.6f} s)")
        s.t.append(t)
        s.frame_id = s.frame_id or frame_id
        if role == "marker":
            marker_T.append(_marker_pose(msg, where))
    return tree, streams, np.array(marker_T).reshape(-1, 4, 4), infos


def _clock_offset(clock_offset_s, roles: _Topics, tree: _TfTree, edges, marker_t: np.ndarray,
                  marker_T: np.ndarray, folder: Path) -> tuple[float, str]:
    """``(t_tf - t_camera, how it was found)``: given, from the marker poses' speeds, or 0 (one ROS clock)."""
    if clock_offset_s is None:
        est = _offset(tree, edges, marker_t, marker_T, folder) if roles.color is not None else None
        offset, offset_how = (0.0, "none: one ROS clock") if est is None else (est, "marker-pose speeds")
    else:
        offset, offset_how = float(clock_offset_s), "given"
    if not np.isfinite(offset) or abs(offset) > 60:
        raise ConfigError(f"clock_offset_s must be finite and within 60 s, got {offset!r}")
    return offset, offset_how


def _tries(group: np.ndarray) -> dict[int, list[int]]:
    """The frames to try: the first few of each standstill, in order (``{standstill: [frame, ...]}``)."""
    tries: dict[int, list[int]] = defaultdict(list)
    for i in np.flatnonzero(group >= 0):
        if len(tries[group[i]]) < TRIES_PER_STANDSTILL:
            tries[group[i]].append(int(i))
    return tries


def _marker_samples(tries: dict, t_cam: np.ndarray, T_at: np.ndarray, marker_T: np.ndarray,
                    roles: _Topics) -> list[Observation]:
    """One sample per standstill from a marker pose topic: its first pose there."""
    obs = []
    for g, idx in sorted(tries.items()):
        i = idx[0]
        B = marker_T[i]
        obs.append(Observation(len(obs), float(t_cam[i]), T_at[i], B[:3, 3].copy(), None, B, None,
                               {"topic": roles.names["marker"], "message": i}))
    return obs


def _image_samples(bag: _Bag, roles: _Topics, streams: dict, infos: list, tries: dict, t_cam: np.ndarray,
                   T_at: np.ndarray, target, folder: Path):
    """One sample per standstill from the images: the first of its frames the marker is measured in.

    Returns ``(observations, skipped, intrinsics)``.
    """
    from handeye.calib.vision.extract import extract

    if not infos:
        raise SessionError(f"{folder}: {roles.names['info']} holds no CameraInfo message")
    wanted = {i: g for g, idx in tries.items() for i in idx}
    depth_t = np.array(streams["depth"].t)
    pair = {i: _nearest(depth_t, t_cam[i]) for i in wanted}
    use_depth = roles.depth is not None
    if use_depth and streams["depth"].frame_id and streams["color"].frame_id \
            and streams["depth"].frame_id != streams["color"].frame_id:
        raise SessionError(f"{folder}: depth ({roles.names['depth']}) is in frame "
                           f"{streams['depth'].frame_id!r}, colour in {streams['color'].frame_id!r}: "
                           "record depth registered to colour (e.g. aligned_depth_to_color)")
    tgt = _target(target, use_depth)
    colors, depths = _second_pass(bag, roles, wanted, {j: i for i, j in pair.items() if j is not None}, folder)
    size = next(((c.shape[1], c.shape[0]) for c in colors.values()), None)
    intr = camera_intrinsics(*infos[0], SessionError, size)
    obs, skipped, done = [], [], set()
    for i in sorted(wanted):
        g = wanted[i]
        if g in done:
            continue
        where = f"{roles.names['color']} message {i}"
        depth = None
        if use_depth:
            if pair[i] is None:
                skipped.append({"message": i, "reason": f"no depth frame within {MAX_SKEW_S * 1e3:.0f} ms"})
                continue
            depth = depths[pair[i]]
            if depth.shape != colors[i].shape[:2]:
                raise SessionError(f"{folder}: {roles.names['depth']} message {pair[i]} is "
                                   f"{depth.shape[1]}x{depth.shape[0]}, the colour image "
                                   f"{colors[i].shape[1]}x{colors[i].shape[0]}: depth must be registered")
        try:
            m = extract(colors[i], depth, intr, tgt)
        except ExtractionError as e:
            log.info("%s: skipping %s: %s", folder, where, e)
            skipped.append({"message": i, "reason": str(e)})
            continue
        done.add(g)
        obs.append(Observation.from_measurement(
            len(obs), float(t_cam[i]), T_at[i], m,
            {"topic": roles.names["color"], "message": i, "depth": bool(use_depth)}))
    return obs, skipped, intr


def _second_pass(bag: _Bag, roles: _Topics, wanted: dict, need_depth: dict, folder: Path):
    """Pass 2: the pixels of the chosen frames only; ``({colour message: image}, {depth message: image})``."""
    use_depth = roles.depth is not None
    colors, depths = {}, {}
    conns = [roles.color] + ([roles.depth] if use_depth else [])
    for conn, k, raw in bag.messages(conns):
        if conn.id == roles.color.id and k in wanted:
            colors[k] = color_image(bag.decode(conn, k, raw), f"{folder}: {conn.topic} message {k}", SessionError)
        elif use_depth and conn.id == roles.depth.id and k in need_depth:
            depths[k] = depth_image(bag.decode(conn, k, raw), f"{folder}: {conn.topic} message {k}", SessionError)
    return colors, depths
