"""Import samples from the tools users already have; export results for them.

Import (both setups; every importer returns handeye's convention, ``A =
T_base_flange``, ``B = T_cam_marker``, see `handeye.app.formats.common`)::

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
``ros2_bag``               rosbag2 directory (sqlite3 / MCAP): tf, colour + depth images and
                           CameraInfo (or a marker detector's poses); one sample per standstill
                           (options ``frames``, ``topics``, ``target``, ``clock_offset_s``)
=========================  ===================================================

``format=None`` detects it from the file. Options: ``setup=`` for the formats
whose files may not say (``open_setup``); manifest overrides for ``pose_csv``. Each
importer registers itself (`handeye.app.formats.registry.register_import`); a new
format is one module plus its name in ``IMPORTER_MODULES``.

Export (`handeye.app.formats.export`)::

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

from handeye.app.formats.common import DEFAULT_FRAMES, ImportedSamples
from handeye.app.formats.export import EXPORT_FORMATS, result_to_dict, ros2_command, urdf_origin, write_result
from handeye.app.formats.registry import detect_format, get_format, import_formats, register_import


def load(path, format: str | None = None, **options) -> ImportedSamples:
    """Import samples from ``path`` (format detected if not given); see the module docstring."""
    return get_format(format or detect_format(path)).load(path, **options)


__all__ = [
    "DEFAULT_FRAMES",
    "EXPORT_FORMATS",
    "ImportedSamples",
    "detect_format",
    "get_format",
    "import_formats",
    "load",
    "register_import",
    "result_to_dict",
    "ros2_command",
    "urdf_origin",
    "write_result",
]
