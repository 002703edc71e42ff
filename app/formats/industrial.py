"""Importer for ros-industrial industrial_calibration ``cal_data.yaml`` sets.

The file lists ``data: [{pose: poses/N.yaml, image: images/N.png}]``, a
``target_finder``, pinhole ``intrinsics`` (fx, fy, cx, cy; no distortion) and
``static_camera`` (true = eye-to-hand, false = eye-in-hand). Each pose file is
the robot's ``base -> tool`` transform (``x y z qx qy qz qw``, m,
scalar-last), i.e. ``T_base_flange``. Each image gives ``T_cam_marker`` by
PnP on the detected target:

- ``CharucoGridTargetFinder``: `handeye.calib.vision.markers.detect_charuco`
  (``rows x cols`` squares, ``chessboard_dim`` / ``aruco_marker_dim`` m,
  ``dictionary`` as OpenCV's integer id); the marker frame is OpenCV's board
  frame.
- ``ModifiedCircleGridTargetFinder``: `handeye.calib.vision.circle_grid.detect_circle_grid`
  (origin at the large dot).

An image whose target is not found is skipped with a log line and listed in
``meta["skipped"]``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from handeye.app.errors import ConfigError, SessionError
from handeye.app.files import inside, read_regular_file
from handeye.calib.errors import ExtractionError
from handeye.calib.setup import Setup
from handeye.calib.vision.circle_grid import CircleGridSpec, detect_circle_grid
from handeye.calib.vision.lift import pnp_covariance, solve_pnp
from handeye.calib.vision.markers import BoardSpec, Detection, detect_charuco

from handeye.app.formats.common import (ImportedSamples, observations_from_poses, read_yaml,
                                        transform_from_xyz_quat_fields)
from handeye.app.formats.registry import register_import

log = logging.getLogger(__name__)

# A view with fewer target points gives too weak a pose to keep.
MIN_POINTS = 6
# Pixel noise assumed at least this large (px) when weighting the PnP covariance.
SIGMA_PX_MIN = 0.2


def _dictionary_name(value) -> str:
    """OpenCV ArUco dictionary name from industrial_calibration's integer id (or a name)."""
    if isinstance(value, str):
        return value
    names = {getattr(cv2.aruco, n): n for n in dir(cv2.aruco) if n.startswith("DICT_")}
    if value not in names:
        raise ConfigError(f"target_finder.dictionary: unknown OpenCV ArUco dictionary id {value!r}")
    return names[value]


def make_detector(finder: dict, where: str):
    """``image -> Detection`` for a ``target_finder`` block; `ConfigError` names the bad field."""
    if not isinstance(finder, dict):
        raise ConfigError(f"{where}: target_finder must be a mapping, got {type(finder).__name__}")
    kind = finder.get("type")
    try:
        if kind == "CharucoGridTargetFinder":
            board = BoardSpec(squares=(int(finder["cols"]), int(finder["rows"])),
                              square_size=float(finder["chessboard_dim"]),
                              marker_size=float(finder["aruco_marker_dim"]),
                              dictionary=_dictionary_name(finder.get("dictionary", 10)))
            return lambda image: detect_charuco(image, board, min_corners=MIN_POINTS)
        if kind == "ModifiedCircleGridTargetFinder":
            params = finder.get("circle_detector_params") or {}
            spec = CircleGridSpec(rows=int(finder["rows"]), cols=int(finder["cols"]), spacing=float(finder["spacing"]),
                                  min_area=float(params.get("minArea", 25.0)),
                                  max_area=float(params.get("maxArea", 5000.0)),
                                  min_convexity=float(params.get("minConvexity", 0.95)))
            return lambda image: detect_circle_grid(image, spec)
    except KeyError as e:
        raise ConfigError(f"{where}: target_finder needs field {e.args[0]!r}") from e
    except (TypeError, ValueError, AttributeError) as e:
        raise ConfigError(f"{where}: target_finder has a non-numeric or malformed field ({e})") from None
    raise ConfigError(f"{where}: target_finder.type {kind!r} is not supported "
                      f"(CharucoGridTargetFinder, ModifiedCircleGridTargetFinder)")


def pose_from_detection(det: Detection, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``T_cam_marker`` (4, 4) by planar PnP (undistorted pinhole), its 6x6 covariance and the reprojection RMS (px).

    The covariance (`handeye.calib.vision.lift.pnp_covariance`, rotation vector rad
    then translation m) takes the pixel noise from the reprojection RMS, with
    a floor of ``SIGMA_PX_MIN`` so a perfect fit does not claim zero noise.
    """
    T, rms = solve_pnp(det.image_points, det.object_points, K, np.zeros(5), square=False)[0]
    cov = pnp_covariance(T, det.object_points, K, max(rms, SIGMA_PX_MIN))
    return T, cov, rms


def _read_image(path: Path):
    """Decoded image of a regular file, or None if it is not an image."""
    data = read_regular_file(path, SessionError)
    try:
        return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) if data else None
    except cv2.error:
        return None


def _is_industrial_calibration(path: Path, document) -> bool:
    if path.is_dir():
        return (path / "cal_data.yaml").exists()
    data = document()
    return isinstance(data, dict) and "target_finder" in data and "data" in data


@register_import("industrial_calibration", _is_industrial_calibration)
def load_industrial_calibration(path) -> ImportedSamples:
    """Read an industrial_calibration data set: poses, images -> target poses.

    Parameters
    ----------
    path : str or Path
        ``cal_data.yaml`` or the directory holding it.

    Returns
    -------
    ImportedSamples
        Setup from ``static_camera``; ``meta`` has ``intrinsics`` (fx, fy,
        cx, cy), ``target`` (finder type), ``skipped`` (image, reason) and
        per-observation ``image``, ``n_points``, ``reprojection_rms_px``.
    """
    path = Path(path)
    if path.is_dir():
        path = inside(path, "cal_data.yaml", SessionError, what=str(path))
    data = read_yaml(path)
    root = path.parent
    for key in ("data", "target_finder", "intrinsics"):
        if key not in data:
            raise SessionError(f"{path}: missing {key!r}")
    intr = data["intrinsics"]
    try:
        fx, fy, cx, cy = (float(intr[k]) for k in ("fx", "fy", "cx", "cy"))
    except (KeyError, TypeError, ValueError, OverflowError) as e:
        raise ConfigError(f"{path}: intrinsics needs numeric fx, fy, cx, cy ({e})") from None
    if not (np.isfinite([fx, fy, cx, cy]).all() and fx > 0 and fy > 0):
        raise ConfigError(f"{path}: intrinsics fx, fy must be finite and > 0, cx, cy finite; "
                          f"got {fx}, {fy}, {cx}, {cy}")
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    detect = make_detector(data["target_finder"], str(path))
    setup = Setup.EYE_TO_HAND if data.get("static_camera", False) else Setup.EYE_IN_HAND

    A, B, covs, per, skipped = [], [], [], [], []
    if not isinstance(data["data"], list):
        raise SessionError(f"{path}: data must be a list of {{pose, image}} entries")
    for i, entry in enumerate(data["data"]):
        if not isinstance(entry, dict) or "pose" not in entry or "image" not in entry:
            raise SessionError(f"{path}: data[{i}] needs 'pose' and 'image'")
        # File names come from the data set: read them only inside its directory.
        pose_file = inside(root, entry["pose"], SessionError, what=f"{path}: data[{i}].pose")
        T_base_flange = transform_from_xyz_quat_fields(read_yaml(pose_file), str(pose_file))
        image_file = inside(root, entry["image"], SessionError, what=f"{path}: data[{i}].image")
        image = _read_image(image_file)
        if image is None:
            raise SessionError(f"{path}: data[{i}]: cannot decode image {entry['image']!r}")
        try:
            det = detect(image)
            T_cam_marker, cov, rms = pose_from_detection(det, K)
        except (cv2.error, np.linalg.LinAlgError) as e:
            # A board geometry no camera can see (e.g. a spacing of 1e300 m) breaks the PnP itself.
            raise SessionError(f"{path}: data[{i}]: no target pose from {entry['image']!r} "
                               f"(check target_finder and intrinsics): {str(e).splitlines()[0][:120]}") from None
        except ExtractionError as e:
            log.info("%s: skipping %s: %s", path, entry["image"], e)
            skipped.append({"image": entry["image"], "reason": str(e)})
            continue
        A.append(T_base_flange)
        B.append(T_cam_marker)
        covs.append(cov)
        per.append({"image": entry["image"], "pose": entry["pose"], "n_points": len(det.ids),
                    "reprojection_rms_px": rms})
    if not A:
        raise SessionError(f"{path}: the target was found in none of the {len(data['data'])} images")
    obs = observations_from_poses(np.array(A), np.array(B), source=path, meta=per)
    for o, cov in zip(obs, covs):
        # Translation block = covariance of the target origin, the point the point-only solvers use.
        o.pose_cov, o.point_cov = cov, cov[3:, 3:].copy()
    meta = {"format": "industrial_calibration", "source": str(path), "time": "sample index",
            "frames": {"base": "base", "flange": "tool0", "camera": "camera", "marker": "target"},
            "intrinsics": {"fx": fx, "fy": fy, "cx": cx, "cy": cy}, "target": data["target_finder"].get("type"),
            "skipped": skipped}
    return ImportedSamples(obs, setup, meta)
