"""Importer for a folder of images with one robot pose per image and the camera's intrinsics.

The layout people bring from their own capture scripts::

    my_capture/
      poses.csv | poses.yaml | poses.json   one robot pose (T_base_flange) per image
      intrinsics.yaml | intrinsics.json     the color camera
      target.yaml                           optional: the target, as handeye's [marker] table
      img_000.png ...                       the images (any format OpenCV reads)
      depth_000.png ...                     optional: 16-bit depth in mm, registered to the image

``poses.csv``: a header and one row per image, ``image,x,y,z,qx,qy,qz,qw``
(m, scalar-last quaternion), optionally a ``depth`` column. ``poses.yaml`` /
``poses.json``: ``{setup: eye_to_hand, poses: [{image, x, y, z, qx, qy, qz,
qw, depth}, ...]}`` (``setup`` optional; a 4x4 ``matrix`` may replace the
seven numbers); a bare list is accepted too.

``intrinsics``: ``{fx, fy, cx, cy, dist: [k1, k2, p1, p2, k3]}`` (``dist``
optional; 4, 5, 8, 12 or 14 values, OpenCV's models), or a ROS ``camera_info``
YAML (``camera_matrix: {data: [9]}``, ``distortion_coefficients: {data: [...]}``).

``target.yaml`` (`handeye.calib.vision.extract.TargetConfig` fields; default: a 5 cm
DICT_4X4_50 ArUco, id 0): each image is measured like a live frame
(`handeye.calib.vision.extract.extract`): with a depth image, the marker center is
lifted from depth; without, it comes from PnP (``use_depth`` off). An image
whose target is not found is skipped with a log line and listed in
``meta["skipped"]``. The setup: ``setup`` in the poses file or the option,
default eye-to-hand.
"""

from __future__ import annotations

import csv
import io
import json
import logging
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np

from handeye.app.errors import ConfigError, SessionError
from handeye.app.files import inside, read_regular_file, read_text_file
from handeye.calib import transforms as tf
from handeye.calib.errors import ExtractionError, HandeyeError, ParameterError
from handeye.calib.observation import Observation
from handeye.calib.setup import Setup, check_setup

from handeye.app.formats.common import ImportedSamples, read_yaml, transform_from_xyz_quat_fields
from handeye.app.formats.registry import register_import

log = logging.getLogger(__name__)

POSE_FILES = ("poses.csv", "poses.yaml", "poses.json")
INTRINSICS_FILES = ("intrinsics.yaml", "intrinsics.json")
_POSE_KEYS = ("x", "y", "z", "qx", "qy", "qz", "qw")
#: Lengths of OpenCV's distortion models (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1..s4 [tx ty]]]]).
DIST_SIZES = (4, 5, 8, 12, 14)


def is_image_folder(path: Path) -> bool:
    return path.is_dir() and any((path / f).exists() for f in POSE_FILES) \
        and any((path / f).exists() for f in INTRINSICS_FILES)


def _image(path: Path, flags):
    """Decoded image of a regular file, or None if it is not an image."""
    data = read_regular_file(path, SessionError)
    try:
        return cv2.imdecode(np.frombuffer(data, np.uint8), flags) if data else None
    except cv2.error:
        return None


def _read_mapping(path: Path):
    if path.suffix == ".json":
        try:
            return json.loads(read_text_file(path, SessionError))
        except (ValueError, RecursionError) as e:  # JSONDecodeError is a ValueError
            raise SessionError(f"{path}: cannot read JSON ({str(e)[:200]})") from None
    return read_yaml(path, allow_list=True)


def _own_file(folder: Path, names) -> Path:
    """The first of ``names`` present in ``folder``, if it resolves inside it (it may be a symlink)."""
    name = next(f for f in names if (folder / f).exists())
    return inside(folder, name, SessionError, what=str(folder / name))


def _poses(folder: Path) -> tuple[list[dict], str | None, Path]:
    path = _own_file(folder, POSE_FILES)
    if path.suffix == ".csv":
        text = read_text_file(path, SessionError)
        try:
            rows = list(csv.DictReader(io.StringIO(text, newline="")))
        except csv.Error as e:
            raise SessionError(f"{path}: cannot read CSV ({e})") from None
        return rows, None, path
    data = _read_mapping(path)
    if isinstance(data, dict):
        return data.get("poses") or [], data.get("setup"), path
    return data, None, path


def read_intrinsics(folder: Path) -> SimpleNamespace:
    """``K`` (3, 3) and ``dist`` of ``intrinsics.yaml|json`` (plain fields or a ROS camera_info)."""
    path = _own_file(folder, INTRINSICS_FILES)
    d = _read_mapping(path)
    if not isinstance(d, dict):
        raise ConfigError(f"{path}: expected a mapping")
    try:
        if "camera_matrix" in d:
            K = np.asarray(d["camera_matrix"]["data"], dtype=float).reshape(3, 3)
            dist = np.asarray((d.get("distortion_coefficients") or {}).get("data", []), dtype=float)
        else:
            K = np.array([[float(d["fx"]), 0.0, float(d["cx"])], [0.0, float(d["fy"]), float(d["cy"])], [0, 0, 1.0]])
            dist = np.asarray(d.get("dist", []), dtype=float)
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as e:
        raise ConfigError(f"{path}: needs fx, fy, cx, cy (or a camera_info camera_matrix): {e}") from None
    if not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ConfigError(f"{path}: focal lengths must be finite and > 0")
    if dist.size not in (0, *DIST_SIZES) or not np.isfinite(dist).all():
        raise ConfigError(f"{path}: distortion coefficients must be {', '.join(map(str, DIST_SIZES))} finite "
                          f"numbers (OpenCV's models), got {dist.tolist()!r:.100}")
    dist = dist.reshape(-1)
    return SimpleNamespace(K=K, dist=dist if dist.size else np.zeros(5))


def _target(folder: Path, use_depth: bool):
    from handeye.calib.vision.extract import TargetConfig

    data = dict(read_yaml(_own_file(folder, ["target.yaml"]))) if (folder / "target.yaml").exists() else {}
    data.setdefault("use_depth", use_depth)
    try:
        return TargetConfig(**data)
    except (ParameterError, TypeError) as e:
        raise ConfigError(f"{folder / 'target.yaml'}: {e}") from None


def _pose(row: dict, where: str) -> np.ndarray:
    if "matrix" in row:
        try:
            return tf.check_transform(np.asarray(row["matrix"], dtype=float), where)
        except (ValueError, TypeError, HandeyeError) as e:
            raise SessionError(f"{where}: matrix is not a rigid 4x4 transform ({e})") from None
    return transform_from_xyz_quat_fields(row, where, _POSE_KEYS)


def _detect(path: Path, document) -> bool:
    return is_image_folder(Path(path))


@register_import("image_folder", _detect, open_setup=True)
def load_image_folder(path, setup: str | None = None) -> ImportedSamples:
    """Measure the target in every image of the folder and pair it with that image's robot pose."""
    from handeye.calib.vision.extract import extract

    folder = Path(path)
    if not is_image_folder(folder):
        raise SessionError(f"{folder}: needs one of {POSE_FILES} and one of {INTRINSICS_FILES}")
    rows, file_setup, pose_path = _poses(folder)
    if not isinstance(rows, list) or not rows:
        raise SessionError(f"{pose_path}: no poses")
    intr = read_intrinsics(folder)
    targets = {}
    obs, skipped = [], []
    for i, row in enumerate(rows):
        where = f"{pose_path}: pose {i}"
        if not isinstance(row, dict) or not row.get("image"):
            raise SessionError(f"{where}: needs an 'image' name")
        T_base_flange = _pose(row, where)
        # Image names come from the pose file: read them only inside the folder.
        color = _image(inside(folder, row["image"], SessionError, what=f"{where}: image"), cv2.IMREAD_COLOR)
        if color is None:
            raise SessionError(f"{where}: cannot read image {row['image']}")
        depth = None
        if row.get("depth"):
            raw = _image(inside(folder, row["depth"], SessionError, what=f"{where}: depth"), cv2.IMREAD_UNCHANGED)
            if raw is None or raw.ndim != 2:
                raise SessionError(f"{where}: cannot read depth image {row['depth']} (16-bit PNG, mm)")
            depth = raw.astype(float) * 1e-3
        use_depth = depth is not None
        if use_depth not in targets:
            targets[use_depth] = _target(folder, use_depth)
        try:
            m = extract(color, depth, intr, targets[use_depth])
        except ExtractionError as e:
            log.info("%s: skipping %s: %s", folder, row["image"], e)
            skipped.append({"image": row["image"], "reason": str(e)})
            continue
        obs.append(Observation(len(obs), float(i), T_base_flange, m.point_cam, m.point_cov, m.T_cam_marker,
                               m.pose_cov, {"image": row["image"], "depth": bool(use_depth)}))
    if not obs:
        raise SessionError(f"{folder}: the target was found in none of the {len(rows)} images")
    if setup is None:  # the file's own word, named in the message if it is not a setup
        setup = check_setup(file_setup or Setup.EYE_TO_HAND, f"{pose_path}: setup", error=SessionError)
    setup = check_setup(setup, error=SessionError)
    return ImportedSamples(obs, setup, {"format": "image_folder", "source": str(folder), "time": "image index",
                                        "frames": {"base": "base", "flange": "flange", "camera": "camera",
                                                   "marker": "marker"},
                                        "intrinsics": {"K": intr.K.tolist(), "dist": intr.dist.tolist()},
                                        "skipped": skipped})
