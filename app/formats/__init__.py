"""Import samples from the tools users already have; export results for them.

Import (both setups; every importer returns handeye's convention, ``A =
T_base_flange``, ``B = T_cam_marker``, see `app.formats.common`)::

    load(path, format=None, **options) -> ImportedSamples(observations, setup, meta)

=========================  ===================================================
format                     path
=========================  ===================================================
``easy_handeye2``          ``*.samples`` of easy_handeye2 (ROS 2)
``easy_handeye``           YAML sample list of easy_handeye (ROS 1)
``industrial_calibration`` ``cal_data.yaml`` (or its directory) with images and poses
``pose_csv``               TOML manifest (or a directory with ``streams.toml``)
                           naming two ``t,x,y,z,qx,qy,qz,qw`` CSV streams;
                           the clock offset is estimated and reported in
                           ``meta["clock_offset_s"]``
``visp``                   directory of ViSP's ``pose_fPe_<i>.yaml`` + ``pose_cPo_<i>.yaml``
``image_folder``           directory of images + ``poses.csv|yaml|json`` + ``intrinsics.yaml|json``
``opencv_storage``         OpenCV FileStorage YAML (``%YAML:1.0``) with ``R_/t_gripper2base``,
                           ``R_/t_target2cam`` sequences
``moveit_calibration``     MoveIt Calibration's JSON list of [effector_wrt_world, object_wrt_sensor]
=========================  ===================================================

``format=None`` detects it from the file. Options: ``setup=`` for the formats
that may not say (`SETUP_OPTION_FORMATS`); manifest overrides for ``pose_csv``.

Export (`app.formats.export`)::

    write_result(result, path, fmt="yaml", frames=None) -> Path

``fmt`` in ``EXPORT_FORMATS``: ``yaml`` (the main result file: 4x4, xyz +
quaternion, xyz + rpy in deg, 1-sigma in mm/deg, residuals, solver, setup,
frames, a ``ros2 run tf2_ros static_transform_publisher`` command and a URDF
``<origin>`` line), ``json`` (same content), ``easy_handeye`` (ROS 1
calibration YAML), ``easy_handeye2`` (ROS 2 ``.calib``), ``urdf`` (fixed joint
snippet), ``ros2_launch`` (Python launch file). ``frames`` names ``base``,
``flange``, ``camera``, ``marker``. Also `result_to_dict`, `ros2_command`,
`urdf_origin`.

This package imports neither rerun nor drivers.
"""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from app.errors import SessionError
from app.files import read_text_file

from app.formats.common import DEFAULT_FRAMES, ImportedSamples
from app.formats.export import EXPORT_FORMATS, result_to_dict, ros2_command, urdf_origin, write_result

IMPORT_FORMATS = ("easy_handeye2", "easy_handeye", "industrial_calibration", "pose_csv", "visp", "image_folder",
                  "opencv_storage", "moveit_calibration")
#: Formats whose files may leave the setup open: they take a ``setup=`` option.
SETUP_OPTION_FORMATS = ("easy_handeye2", "easy_handeye", "visp", "image_folder", "opencv_storage",
                        "moveit_calibration")


def detect_format(path) -> str:
    """Name of the import format of ``path`` (one of `IMPORT_FORMATS`); `SessionError` if unknown."""
    path = Path(path)
    if path.is_dir():
        if (path / "cal_data.yaml").exists():
            return "industrial_calibration"
        if (path / "streams.toml").exists():
            return "pose_csv"
        from app.formats.image_folder import is_image_folder
        from app.formats.visp import is_visp_dir

        if is_visp_dir(path):
            return "visp"
        if is_image_folder(path):
            return "image_folder"
        raise SessionError(f"{path}: directory holds none of cal_data.yaml, streams.toml, pose_fPe_<i>.yaml "
                           "(ViSP), poses.csv|yaml|json + intrinsics.yaml|json (image folder)")
    if path.suffix == ".toml":
        return "pose_csv"
    if path.suffix == ".samples":
        return "easy_handeye2"
    from app.formats.opencv_storage import is_opencv_storage

    if is_opencv_storage(path):
        return "opencv_storage"
    if path.suffix == ".json":
        from app.formats.moveit import looks_like_moveit

        try:
            if looks_like_moveit(json.loads(path.read_text())):
                return "moveit_calibration"
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise SessionError(f"{path}: cannot read JSON ({e})") from e
    try:
        data = yaml.safe_load(read_text_file(path, SessionError))
    except (yaml.YAMLError, RecursionError, ValueError) as e:
        raise SessionError(f"{path}: cannot read ({str(e)[:200]})") from None
    if isinstance(data, dict):
        if "target_finder" in data and "data" in data:
            return "industrial_calibration"
        samples = data.get("samples", data)
        if isinstance(samples, list) and samples and isinstance(samples[0], dict):
            return "easy_handeye2" if "tracking" in samples[0] else "easy_handeye"
        if isinstance(samples, dict) and "hand_world_samples" in samples:
            return "easy_handeye"
    if isinstance(data, list) and data and isinstance(data[0], dict) and "optical" in data[0]:
        return "easy_handeye"
    raise SessionError(f"{path}: not a known sample format ({', '.join(IMPORT_FORMATS)})")


def load(path, format: str | None = None, **options) -> ImportedSamples:
    """Import samples from ``path`` (format detected if not given); see the module docstring."""
    fmt = format or detect_format(path)
    if fmt == "easy_handeye2":
        from app.formats.easy_handeye import load_easy_handeye2

        return load_easy_handeye2(path, **options)
    if fmt == "easy_handeye":
        from app.formats.easy_handeye import load_easy_handeye

        return load_easy_handeye(path, **options)
    if fmt == "industrial_calibration":
        from app.formats.industrial import load_industrial_calibration

        return load_industrial_calibration(path, **options)
    if fmt == "pose_csv":
        from app.formats.pose_csv import load_pose_streams

        return load_pose_streams(path, **options)
    if fmt == "visp":
        from app.formats.visp import load_visp

        return load_visp(path, **options)
    if fmt == "image_folder":
        from app.formats.image_folder import load_image_folder

        return load_image_folder(path, **options)
    if fmt == "opencv_storage":
        from app.formats.opencv_storage import load_opencv_storage

        return load_opencv_storage(path, **options)
    if fmt == "moveit_calibration":
        from app.formats.moveit import load_moveit

        return load_moveit(path, **options)
    raise SessionError(f"unknown import format {fmt!r} (use one of {IMPORT_FORMATS})")


__all__ = [
    "DEFAULT_FRAMES",
    "EXPORT_FORMATS",
    "IMPORT_FORMATS",
    "SETUP_OPTION_FORMATS",
    "ImportedSamples",
    "detect_format",
    "load",
    "result_to_dict",
    "ros2_command",
    "urdf_origin",
    "write_result",
]
