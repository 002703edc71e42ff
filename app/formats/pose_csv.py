"""Importer for two unsynchronised pose streams in CSV (robot and camera).

Each CSV row is ``t, x, y, z, qx, qy, qz, qw`` (seconds, metres, scalar-last
quaternion), the format of ethz-asl/hand_eye_calibration. A small TOML
manifest names the two files and what they contain::

    format = "pose_csv"
    setup = "eye_in_hand"             # or "eye_to_hand"
    robot = "hand.csv"                # rows are T_base_flange ...
    robot_transform = "T_base_flange" # ... or "T_flange_base"
    camera = "target.csv"
    camera_transform = "T_marker_cam" # or "T_cam_marker" (what each row is)
    clock_offset = "estimate"         # or seconds: t_robot = t_camera + offset
    max_offset = 1.0                  # s, search range of the estimate
    refine = true                     # refine by minimising the calibration residual
    refine_method = "YKronT'"         # solver whose residual is minimised
    max_gap = 0.1                     # s, camera samples across larger robot gaps are dropped
    stride = 1                        # keep every n-th camera sample
    [frames]                          # optional names for the exports
    base = "base_link"

The camera stream is kept as sampled; the robot stream is interpolated at each
camera time shifted by the clock offset (SLERP + linear, `handeye.calib.timesync`).
The offset is estimated by correlating the two streams' angular speeds and,
with ``refine``, polished by minimising the RMS residual of a calibration on
the paired samples (both setups).
"""

from __future__ import annotations

import gzip
import io
import logging
import re
import sys
import zlib
from pathlib import Path
from typing import Literal

if sys.version_info >= (3, 11):
    import tomllib
else:       # Python 3.10 (ROS 2 Humble): the same parser, before it joined the standard library
    import tomli as tomllib

import numpy as np
from pydantic import Field, ValidationError

from handeye.app.files import MAX_FILE_BYTES, inside, read_regular_file, read_text_file
from handeye.calib import timesync
from handeye.calib import transforms as tf
from handeye.app.errors import ConfigError, SessionError
from handeye.calib.errors import HandeyeError
from handeye.calib.observation import Observation
from handeye.calib.params import Bool, Float, Params, PositiveFloat, PositiveInt, Str, describe
from handeye.calib.setup import Setup

from handeye.app.formats.common import DEFAULT_FRAMES, ImportedSamples
from handeye.app.formats.registry import register_import

log = logging.getLogger(__name__)

# Commas (ETH), semicolons or whitespace (TUM trajectory files) between fields.
_SEPARATORS = re.compile(r"\s*[,;]\s*|\s+")

# Below this peak correlation the offset estimate is doubtful (docs/benchmarks-history.md,
# handeye.app.formats.pose_csv).
LOW_CORRELATION = 0.5

# Pairs used per residual evaluation while refining the offset: enough to
# average the pose noise, few enough to keep the refinement's solver calls cheap.
REFINE_PAIRS = 300


def read_pose_csv(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a ``t, x, y, z, qx, qy, qz, qw`` CSV (or the same whitespace-separated, as TUM) into times and transforms.

    Rows are sorted by time; rows repeating an earlier timestamp are dropped
    (the ETH simulated hand stream publishes most poses twice) and counted in
    the log. Lines starting with ``#`` and a non-numeric header line are
    skipped; a ``.gz`` file is decompressed.

    Returns
    -------
    t : ndarray, shape (N,)
        Strictly increasing, s.
    T : ndarray, shape (N, 4, 4)

    Raises
    ------
    SessionError
        Unreadable file, wrong column count, NaN, or a non-unit quaternion
        (the message names the line).
    """
    path = Path(path)
    data = read_regular_file(path, SessionError)
    if path.suffix == ".gz":
        try:
            # Bounded: a small corrupt or hostile archive must not inflate without limit.
            with gzip.GzipFile(fileobj=io.BytesIO(data)) as f:
                data = f.read(MAX_FILE_BYTES + 1)
        except (OSError, EOFError, zlib.error) as e:
            raise SessionError(f"{path}: cannot decompress ({e})") from None
        if len(data) > MAX_FILE_BYTES:
            raise SessionError(f"{path}: decompresses to more than {MAX_FILE_BYTES} bytes")
    try:
        lines = data.decode("utf-8").splitlines()
    except UnicodeDecodeError as e:
        raise SessionError(f"{path}: not UTF-8 text (byte {e.start})") from None
    rows, line_nos = [], []
    for no, line in enumerate(lines, start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = _SEPARATORS.split(s)
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            if not rows:  # a header
                continue
            raise SessionError(f"{path}:{no}: not numeric: {s[:80]!r}") from None
        if len(vals) != 8:
            raise SessionError(f"{path}:{no}: expected 8 columns (t, x, y, z, qx, qy, qz, qw), got {len(vals)}")
        rows.append(vals)
        line_nos.append(no)
    if len(rows) < 2:
        raise SessionError(f"{path}: fewer than 2 pose rows")
    a = np.array(rows)
    bad = ~np.isfinite(a).all(axis=1)
    if bad.any():
        raise SessionError(f"{path}:{line_nos[int(np.argmax(bad))]}: NaN or inf")
    qn = np.linalg.norm(a[:, 4:8], axis=1)
    bad = np.abs(qn - 1.0) > 1e-3
    if bad.any():
        i = int(np.argmax(bad))
        raise SessionError(f"{path}:{line_nos[i]}: quaternion norm {qn[i]:.6f}, not 1")
    order = np.argsort(a[:, 0], kind="stable")
    a = a[order]
    keep = np.r_[True, np.diff(a[:, 0]) > 0]
    if not keep.all():
        log.info("%s: dropped %d rows repeating an earlier timestamp", path, int((~keep).sum()))
    a = a[keep]
    return a[:, 0], tf.from_xyz_quat(a[:, 1:4], a[:, 4:8] / qn[order][keep, None])


class FramesConfig(Params):
    """Frame names of the exported result (`handeye.app.formats.common.DEFAULT_FRAMES`)."""

    base: Str = DEFAULT_FRAMES["base"]
    flange: Str = DEFAULT_FRAMES["flange"]
    camera: Str = DEFAULT_FRAMES["camera"]
    marker: Str = DEFAULT_FRAMES["marker"]


class StreamsConfig(Params):
    """The manifest of a pose-stream pair (see the module docstring); paths relative to it."""

    setup: Setup
    robot: Str
    camera: Str
    robot_transform: Literal["T_base_flange", "T_flange_base"] = "T_base_flange"
    camera_transform: Literal["T_cam_marker", "T_marker_cam"] = "T_cam_marker"
    clock_offset: Float | Literal["estimate"] = "estimate"
    max_offset: PositiveFloat = 1.0
    refine: Bool = True
    refine_method: Str = "YKronT'"
    refine_half_width: PositiveFloat = 0.05
    max_gap: PositiveFloat = 0.1
    stride: PositiveInt = 1
    frames: FramesConfig = Field(default_factory=FramesConfig)
    format: Literal["pose_csv"] = "pose_csv"


def read_manifest(path) -> StreamsConfig:
    """Parse and validate a pose-stream TOML manifest; `ConfigError` names the bad field."""
    path = Path(path)
    try:
        data = tomllib.loads(read_text_file(path, ConfigError, max_bytes=1024 * 1024))
    except (tomllib.TOMLDecodeError, RecursionError) as e:
        raise ConfigError(f"{path}: cannot read TOML ({str(e)[:200]})") from None
    try:
        return StreamsConfig.model_validate(data)
    except ValidationError as e:
        raise ConfigError(f"{path}: {describe(e)}") from None


def residual_of_solve(method: str, setup: Setup):
    """``f(A, B) -> RMS translation residual (m)`` of the closed-form ``method`` on paired poses.

    Uses `handeye.calib.api.closed_form` (no covariance: it is evaluated ~25 times);
    a point method (YKronT') takes the translations of the pose stack itself.
    A solver failure (e.g. too few pairs at an offset) costs infinity.
    """
    from handeye.calib.api import closed_form

    def f(A, B) -> float:
        if len(A) > REFINE_PAIRS:
            keep = np.linspace(0, len(A) - 1, REFINE_PAIRS).round().astype(int)
            A, B = A[keep], B[keep]
        try:
            res = closed_form(method, A, B, setup=setup)
        except HandeyeError:
            return np.inf
        return res.residuals.rms_translation

    return f


def _is_pose_streams(path: Path, document) -> bool:
    return (path / "streams.toml").exists() if path.is_dir() else path.suffix == ".toml"


@register_import("pose_csv", _is_pose_streams)
def load_pose_streams(path, **overrides) -> ImportedSamples:
    """Pair a robot and a camera pose stream named by a TOML manifest.

    Parameters
    ----------
    path : str or Path
        The manifest (or a directory holding ``streams.toml``).
    **overrides
        Manifest fields to replace (e.g. ``clock_offset=0.0``, ``refine=False``).

    Returns
    -------
    ImportedSamples
        One observation per kept camera sample, ``t`` on the robot clock
        (``meta``: ``t_camera``, and ``camera_sample``, the index in the
        time-sorted, de-duplicated camera stream);
        ``meta`` holds ``clock_offset_s`` (used), ``clock_offset_xcorr_s`` and
        ``xcorr_score`` (angular-speed correlation), ``clock_offset_refined_s``
        and ``refine_rms_mm`` if refined, row counts and ``n_paired`` (camera
        samples inside the robot stream, before ``stride``).
    """
    path = Path(path)
    if path.is_dir():
        path = inside(path, "streams.toml", SessionError, what=str(path))
    cfg = read_manifest(path)
    if overrides:
        try:
            cfg = StreamsConfig.model_validate({**cfg.model_dump(), **overrides})
        except ValidationError as e:
            raise ConfigError(f"{path}: {describe(e)}") from None
    # The manifest names its CSVs relative to itself; they must stay beside it.
    t_a, A = read_pose_csv(inside(path.parent, cfg.robot, SessionError, what=f"{path}: robot"))
    t_b, B = read_pose_csv(inside(path.parent, cfg.camera, SessionError, what=f"{path}: camera"))
    if cfg.robot_transform == "T_flange_base":
        A = tf.invert(A)
    if cfg.camera_transform == "T_marker_cam":
        B = tf.invert(B)
    meta = {"format": "pose_csv", "source": str(path), "frames": cfg.frames.model_dump(),
            "n_robot_rows": len(t_a), "n_camera_rows": len(t_b), "time": "robot clock, s"}
    try:
        if cfg.clock_offset == "estimate":
            est = timesync.estimate_clock_offset(t_a, A, t_b, B, max_offset=cfg.max_offset, max_gap=cfg.max_gap)
            offset = est.offset
            meta.update(clock_offset_xcorr_s=est.offset, xcorr_score=est.score)
            if est.score < LOW_CORRELATION:
                log.warning("%s: the two streams' angular speeds correlate poorly (%.2f at %+.3f s): "
                            "check that they show the same motion, or give clock_offset", path, est.score, offset)
            if cfg.refine:
                cost = timesync.calibration_cost(t_a, A, t_b, B, residual_of_solve(cfg.refine_method, cfg.setup),
                                                 max_gap=cfg.max_gap)
                ref = timesync.refine_clock_offset(cost, offset, half_width=cfg.refine_half_width)
                offset = ref.offset
                meta.update(clock_offset_refined_s=ref.offset, refine_method=cfg.refine_method,
                            refine_rms_mm=ref.score * 1e3, refine_rms_mm_at_xcorr=cost(est.offset) * 1e3)
        else:
            offset = float(cfg.clock_offset)
        t, A_p, B_p, idx = timesync.pair_streams(t_a, A, t_b, B, offset, max_gap=cfg.max_gap)
    except HandeyeError as e:
        raise SessionError(f"{path}: {e}") from e
    if len(t) == 0:
        raise SessionError(f"{path}: no camera sample overlaps the robot stream at offset {offset:+.3f} s")
    meta.update(clock_offset_s=offset, n_paired=len(t))
    log.info("%s: clock offset %+.4f s, %d of %d camera samples paired", path, offset, len(t), len(t_b))
    sel = slice(None, None, cfg.stride)
    t, A_p, B_p, idx = t[sel], A_p[sel], B_p[sel], idx[sel]
    obs = [
        Observation(index=i, t=float(t[i] + offset), T_base_flange=A_p[i], point_cam=B_p[i, :3, 3].copy(),
                    T_cam_marker=B_p[i], meta={"t_camera": float(t[i]), "camera_sample": int(idx[i])})
        for i in range(len(t))
    ]
    return ImportedSamples(obs, cfg.setup, meta)
