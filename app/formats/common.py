"""Shared pieces of the importers: the `ImportedSamples` value and small parsers.

Every importer returns eye-to-hand or eye-in-hand samples in handeye's own
convention: ``Observation.T_base_flange = A_i`` and ``Observation.T_cam_marker
= B_i`` of the paper's ``A_i X = Y B_i`` (eye-to-hand ``X = T_flange_marker``,
``Y = T_base_cam``; eye-in-hand ``X = T_flange_cam``, ``Y = T_base_marker``),
with ``point_cam`` the marker origin in the camera frame for the point-only
solvers (YKronT', YQuatT').
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from handeye.app.files import read_text_file
from handeye.calib import transforms as tf
from handeye.app.errors import SessionError
from handeye.calib.errors import CalibrationError
from handeye.calib.observation import Observation
from handeye.calib.setup import Setup, check_setup

DEFAULT_FRAMES = {"base": "base", "flange": "flange", "camera": "camera", "marker": "marker"}


@dataclass
class ImportedSamples:
    """Samples read from another tool's files.

    Attributes
    ----------
    observations : list[Observation]
        In file order, ``index`` 0..N-1.
    setup : {"eye_to_hand", "eye_in_hand"}
    meta : dict
        ``format`` (importer name), ``source`` (path), ``frames`` (names of
        base / flange / camera / marker), and importer-specific entries
        (e.g. ``clock_offset_s`` for pose streams, ``skipped`` images).
    """

    observations: list[Observation]
    setup: Setup
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.setup = check_setup(self.setup, error=SessionError)

    @property
    def A(self) -> np.ndarray:
        """``T_base_flange`` stack, shape (N, 4, 4)."""
        return np.array([o.T_base_flange for o in self.observations]).reshape(-1, 4, 4)

    @property
    def B(self) -> np.ndarray:
        """``T_cam_marker`` stack, shape (N, 4, 4) (raises if a sample has only a point)."""
        if any(o.T_cam_marker is None for o in self.observations):
            raise SessionError("some imported samples have no T_cam_marker")
        return np.array([o.T_cam_marker for o in self.observations]).reshape(-1, 4, 4)


def read_yaml(path: Path, *, allow_list: bool = False) -> dict | list:
    """YAML mapping (or, with ``allow_list``, list) from ``path``; `SessionError` naming the file otherwise."""
    text = read_text_file(path, SessionError)
    try:
        data = yaml.safe_load(text)
    except (yaml.YAMLError, RecursionError, ValueError) as e:
        raise SessionError(f"{path}: cannot read YAML ({str(e)[:200]})") from None
    if not isinstance(data, dict) and not (allow_list and isinstance(data, list)):
        raise SessionError(f"{path}: expected a YAML mapping at the top level, got {type(data).__name__}")
    return data


def _number(d: dict, key: str, where: str) -> float:
    if not isinstance(d, dict) or key not in d:
        raise SessionError(f"{where}: missing field {key!r}")
    if isinstance(d[key], bool):
        raise SessionError(f"{where}.{key}: not a number ({d[key]!r})")
    try:
        return float(d[key])
    except (TypeError, ValueError, OverflowError):
        raise SessionError(f"{where}.{key}: not a number ({d[key]!r:.60})") from None


def transform_from_xyz_quat_fields(d: dict, where: str, keys=("x", "y", "z", "qx", "qy", "qz", "qw")) -> np.ndarray:
    """4x4 transform from a flat mapping of translation (m) and scalar-last quaternion fields.

    Raises `SessionError` naming ``where`` and the field on a missing or
    non-numeric field, a NaN, or a quaternion far from unit length.
    """
    v = np.array([_number(d, k, where) for k in keys])
    if not np.isfinite(v).all():
        raise SessionError(f"{where}: NaN or inf in {dict(zip(keys, v))}")
    if np.abs(v).max() > tf.MAX_MAGNITUDE:  # before the norm below overflows
        raise SessionError(f"{where}: a value beyond {tf.MAX_MAGNITUDE:g} in {dict(zip(keys, v.tolist()))}")
    q = v[3:]
    n = np.linalg.norm(q)
    # Files store quaternions with ~6-17 digits; anything further off is not a rotation.
    if abs(n - 1.0) > 1e-3:
        raise SessionError(f"{where}: quaternion norm is {n:.6f}, not 1")
    return tf.from_xyz_quat(v[:3], q / n)


def transform_from_msg(d: dict, where: str) -> np.ndarray:
    """4x4 transform from a ROS ``geometry_msgs/Transform`` mapping.

    Accepts ``{translation: {x, y, z}, rotation: {x, y, z, w}}`` and the same
    wrapped in ``transform:`` (a ``TransformStamped``).
    """
    if isinstance(d, dict) and "transform" in d:
        d = d["transform"]
    if not isinstance(d, dict) or "translation" not in d or "rotation" not in d:
        raise SessionError(f"{where}: expected a Transform with 'translation' and 'rotation', got {d!r:.80}")
    for part in ("translation", "rotation"):
        if not isinstance(d[part], dict):
            raise SessionError(f"{where}: {part} must be a mapping of x, y, z{', w' * (part == 'rotation')}, "
                               f"got {d[part]!r:.60}")
    flat = {**{k: v for k, v in d["translation"].items()},
            **{"q" + str(k): v for k, v in d["rotation"].items()}}
    return transform_from_xyz_quat_fields(flat, where)


def observations_from_poses(A, B, *, source, t=None, meta=None) -> list[Observation]:
    """Observations from paired ``T_base_flange`` (N, 4, 4) and ``T_cam_marker`` (N, 4, 4).

    ``point_cam`` is the marker origin ``B[:, :3, 3]`` (for the point-only
    solvers); ``t`` defaults to the sample index; ``meta`` is a list of
    per-sample dicts. ``source`` (the file or directory read) starts every
    `SessionError` message, e.g. ``<file>: T_cam_marker[3] rotation is not a proper rotation``.
    """
    try:
        A = tf.check_transforms(A, "T_base_flange")
        B = tf.check_transforms(B, "T_cam_marker", atol=1e-5)
    except CalibrationError as e:
        raise SessionError(f"{source}: {e}") from e
    if len(A) != len(B):
        raise SessionError(f"{source}: {len(A)} robot poses but {len(B)} camera poses")
    t = np.arange(len(A), dtype=float) if t is None else np.asarray(t, dtype=float)
    meta = meta or [{} for _ in range(len(A))]
    return [
        Observation(index=i, t=float(t[i]), T_base_flange=A[i], point_cam=B[i, :3, 3].copy(),
                    T_cam_marker=B[i], meta=dict(meta[i]))
        for i in range(len(A))
    ]
