"""Exporters of a `handeye.calib.result.CalibrationResult` into the formats other tools read.

The exported transform is the *camera* transform: ``T_base_cam`` (parent =
base frame, child = camera frame) for eye-to-hand, ``T_flange_cam`` (parent =
flange frame, child = camera frame) for eye-in-hand. Units: metres and
quaternions (x, y, z, w) as in ROS; degrees only where a field says ``_deg``.
RPY is URDF's: fixed axes, roll about x, then pitch about y, then yaw about z
(``R = Rz(yaw) Ry(pitch) Rx(roll)``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from handeye.calib import transforms as tf
from handeye.app.errors import ConfigError
from handeye.calib.errors import CalibrationError
from handeye.calib.result import CalibrationResult
from handeye.calib.setup import Setup, check_setup

from handeye.app.formats.common import DEFAULT_FRAMES

EXPORT_FORMATS = ("yaml", "json", "easy_handeye", "easy_handeye2", "urdf", "ros2_launch")
RESULT_FORMAT = "handeye-result"
RESULT_VERSION = 1



class _Dumper(yaml.SafeDumper):
    """Lists of numbers on one line (``[x, y, z]``), everything else in block style."""


def _represent_list(dumper, data):
    flow = all(isinstance(v, (int, float)) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _represent_list)


def check_frames(frames: dict | None) -> dict:
    frames = {**DEFAULT_FRAMES, **(frames or {})}
    unknown = set(frames) - set(DEFAULT_FRAMES)
    if unknown:
        raise ConfigError(f"frames: unknown keys {sorted(unknown)} (use {sorted(DEFAULT_FRAMES)})")
    for k, v in frames.items():
        if not isinstance(v, str) or not v or any(c.isspace() for c in v):
            raise ConfigError(f"frames.{k} must be a non-empty name without spaces, got {v!r}")
    return frames


def check_result(result) -> CalibrationResult:
    """Validate what the exporters rely on: a `CalibrationResult` of a known setup with rigid X, Y.

    Raises
    ------
    CalibrationError
        Naming the bad attribute.
    """
    if not isinstance(result, CalibrationResult):
        raise CalibrationError(f"result must be a CalibrationResult, got {type(result).__name__}")
    check_setup(result.setup, "result.setup")
    tf.check_transform(result.X, "result.X")
    tf.check_transform(result.Y, "result.Y")
    if result.cov is not None:
        cov = np.asarray(result.cov, dtype=float)
        if cov.shape != (6, 6) or not np.isfinite(cov).all():
            raise CalibrationError(f"result.cov must be a finite (6, 6) matrix, got shape {cov.shape}")
    return result


def _parent_child(setup: str, frames: dict) -> tuple[str, str]:
    """(parent, child) frame names of the camera transform."""
    return (frames["base"] if setup == Setup.EYE_TO_HAND else frames["flange"]), frames["camera"]


def published_transform(result: CalibrationResult, frames: dict, camera_tf: dict | None = None
                        ) -> tuple[str, str, np.ndarray]:
    """(parent, child, T_parent_child) a static transform publisher sends for the camera.

    Without ``camera_tf``: the camera transform for uncorrected points, parent -> the optical frame.
    With ``camera_tf`` (``root``, ``T_root_camera`` (4, 4): the camera driver's own tf from its root,
    e.g. ``camera_link``, to the optical frame; `handeye.app.formats.ros2_bag` reports it): parent -> root,
    ``camera_transform_raw_points @ inv(T_root_camera)``, since a tf frame has one parent.
    """
    parent, child = _parent_child(result.setup, frames)
    T = result.camera_transform_raw_points
    if camera_tf is None:
        return parent, child, T
    try:
        T_root_camera = tf.check_transform(np.asarray(camera_tf["T_root_camera"], dtype=float), "T_root_camera")
        root = str(camera_tf["root"])
    except (KeyError, TypeError, ValueError, CalibrationError) as e:
        raise ConfigError(f"camera_tf needs root and a rigid 4x4 T_root_camera: {e}") from None
    return parent, root, T @ tf.invert(T_root_camera)


def _marker_parent_child(setup: str, frames: dict) -> tuple[str, str]:
    """(parent, child) frame names of the marker-side transform."""
    return (frames["flange"] if setup == Setup.EYE_TO_HAND else frames["base"]), frames["marker"]


def rpy_deg(T) -> np.ndarray:
    """URDF roll, pitch, yaw (deg) of a transform's rotation."""
    return np.rad2deg(Rotation.from_matrix(np.asarray(T)[:3, :3]).as_euler("xyz"))


def _fmt(v: float) -> str:
    return f"{v:.9g}"


def _transform_dict(T, name: str, parent: str, child: str, cov=None) -> dict:
    t, q = tf.to_xyz_quat(T)
    d = {
        "name": name,
        "parent_frame": parent,
        "child_frame": child,
        "matrix": np.asarray(T).tolist(),
        "translation_m": t.tolist(),
        "quaternion_xyzw": q.tolist(),
        "rpy_deg": rpy_deg(T).tolist(),
    }
    if cov is not None:
        sd = np.sqrt(np.clip(np.diag(np.asarray(cov)), 0.0, None))
        d["sigma_1"] = {
            "rotation_deg": np.rad2deg(sd[:3]).tolist(),
            "translation_mm": (sd[3:] * 1e3).tolist(),
            "note": "1-sigma per axis from result.cov (left rotation vector and translation, in the parent frame)",
        }
        # The whole matrix too: the report draws the error ellipsoid from it, with the axes' correlations.
        d["covariance"] = {"matrix": np.asarray(cov, dtype=float).tolist(),
                           "units": "[rotvec rad (3), translation m (3)]: R_true = Exp(d) R, t_true = t + dt"}
    return d


def ros2_command(result: CalibrationResult, frames: dict | None = None, camera_tf: dict | None = None) -> str:
    """``ros2 run tf2_ros static_transform_publisher ...`` for the camera transform (ROS 2 Humble+ flags).

    Like every rigid-only export, it carries the transform for the camera's
    uncorrected points (`CalibrationResult.camera_transform_raw_points`);
    ``camera_tf``: attach the camera driver's tf root instead (`published_transform`).
    """
    check_result(result)
    frames = check_frames(frames)
    parent, child, T = published_transform(result, frames, camera_tf)
    t, q = tf.to_xyz_quat(T)
    args = " ".join(f"--{k} {_fmt(v)}" for k, v in zip(("x", "y", "z", "qx", "qy", "qz", "qw"), [*t, *q]))
    return f"ros2 run tf2_ros static_transform_publisher {args} --frame-id {parent} --child-frame-id {child}"


def urdf_origin(result: CalibrationResult) -> str:
    """``<origin xyz=".." rpy=".."/>`` of the camera transform for uncorrected points (rpy in rad, as URDF wants)."""
    check_result(result)
    T = result.camera_transform_raw_points
    rpy = np.deg2rad(rpy_deg(T))
    return (f'<origin xyz="{" ".join(_fmt(v) for v in T[:3, 3])}" '
            f'rpy="{" ".join(_fmt(v) for v in rpy)}"/>')


def result_to_dict(result: CalibrationResult, frames: dict | None = None, samples_from=None,
                   cell: dict | None = None) -> dict:
    """The main result document (YAML/JSON): the verdict, transforms, uncertainty, residuals, ready-to-paste lines.

    Parameters
    ----------
    result : CalibrationResult
    frames : dict, optional
        Names for ``base``, ``flange``, ``camera``, ``marker``.
    samples_from : str or Path, optional
        The session (or imported file) the result was solved from, as ``samples_from``: verify
        reads its poses back (to avoid and to flag them).
    cell : dict, optional
        Who made it, where and with what (`handeye.app.provenance.cell`), as ``cell``.

    Returns
    -------
    dict
        JSON-serialisable; ``camera_transform`` is ``T_base_cam``
        (eye-to-hand) or ``T_flange_cam`` (eye-in-hand), with ``sigma_1``
        (deg, mm) when the result has a covariance; with an estimated camera
        correction also ``camera_transform_raw_points`` (`raw_points_dict`),
        which the ros2/urdf lines carry.
    """
    check_result(result)
    frames = check_frames(frames)
    setup = Setup(result.setup)
    marker_T = result.X if setup == Setup.EYE_TO_HAND else result.Y
    res = result.residuals
    if len(res.translation):
        resid = {
            "n_samples": int(result.n_samples),
            "rms_translation_mm": res.rms_translation * 1e3,
            "median_translation_mm": float(np.median(res.translation)) * 1e3,
            "max_translation_mm": res.max_translation * 1e3,
            "rms_rotation_deg": None if res.rms_rotation is None else math.degrees(res.rms_rotation),
            "note": "per-sample residuals of A_i X = Y B_i (paper eq. 1); translation in the camera frame",
        }
    else:
        resid = {"n_samples": int(result.n_samples), "note": "no per-sample residuals: a live estimate of the "
                 "monitoring engine (its verification is each sample's prediction error before it is fused)"}
    marker = _transform_dict(marker_T, setup.marker_name, *_marker_parent_child(setup, frames))
    marker["rotation_known"] = bool(result.marker_rotation_known)
    doc = {
        "format": RESULT_FORMAT,
        "version": RESULT_VERSION,
        "setup": setup.value,
        "equation": setup.equation,
        "solver": result.method,
    }
    if result.verdict is not None:
        doc["verdict"] = result.verdict.to_dict()
    if result.accuracy is not None:
        doc["accuracy"] = accuracy_dict(result)
    if result.undetermined:
        doc["undetermined"] = list(result.undetermined)
    doc.update({
        "which_transform": which_transform(result),
        **({"cell": cell} if cell is not None else {}),
        **({"samples_from": str(samples_from)} if samples_from is not None else {}),
        "frames": frames,
        "camera_transform": _transform_dict(result.camera_transform, setup.camera_name, *_parent_child(setup, frames),
                                            cov=result.cov),
    })
    if result.raw_points_fit is not None:
        doc["camera_transform_raw_points"] = raw_points_dict(result, frames)
    doc.update({
        "marker_transform": marker,
        "camera_frame": camera_frame_note(result, frames),
        "residuals": resid,
        "n_samples": int(result.n_samples),
        "rejected_samples": result.rejected.tolist(),
        "converged": bool(result.converged),
        "iterations": int(result.iterations),
        "ros2_static_transform_publisher": ros2_command(result, frames),
        "urdf_origin": urdf_origin(result),
        "model": model_report(result),
    })
    return doc


def accuracy_dict(result: CalibrationResult) -> dict:
    """``result.accuracy`` (`handeye.calib.verdict.workspace_accuracy`) with its units and what it means."""
    acc = result.accuracy
    parent = "base" if Setup(result.setup) == Setup.EYE_TO_HAND else "flange"
    return {"rms_mm": acc.rms_mm, "p95_mm": acc.p95_mm, "rms_deg": acc.rms_deg, "p95_deg": acc.p95_deg,
            "note": f"predicted error of a marker point measured where the calibration samples were, in the "
                    f"{parent} frame, camera correction included: RMS over the workspace and at most at 95 %; "
                    "deg: the camera's rotation"}


def which_transform(result: CalibrationResult) -> str:
    """Which camera transform goes with which points, in one sentence (result.yaml, the console, the report)."""
    cam = Setup(result.setup).camera_name
    if result.raw_points_fit is None:
        return (f"one transform, camera_transform ({cam}): {result.method} estimates no camera correction, so it "
                "holds for the camera's points as its driver publishes them (ROS tf, URDF, the "
                "static_transform_publisher line)")
    cc = model_report(result)["camera_correction"]
    parts = ", ".join(f"{name.replace('_percent', '').replace('_mm', '').replace('_', ' ')} "
                      f"{c['value']:+.2f} {'%' if name.endswith('_percent') else 'mm'}"
                      for name, c in cc.items() if c["estimated"])
    rot, trans = tf.pose_error(result.camera_transform_raw_points, result.camera_transform)
    return (f"use camera_transform_raw_points ({cam} for uncorrected points) with the points a camera driver "
            "publishes: ROS tf, URDF and the static_transform_publisher line carry it; camera_transform holds "
            f"for points corrected by model.camera_correction ({parts}), as handeye's verify and monitor use them; "
            f"the two differ by {trans * 1e3:.2f} mm / {math.degrees(rot):.3f} deg")


def model_report(result: CalibrationResult) -> dict | None:
    """The model and self-check part of a result, JSON-ready with units in the keys (for result.yaml, the CLI).

    Returns None when the result carries neither. Camera correction: depth and
    focal scale in %, depth offset in mm (value, 1-sigma, whether estimated)
    and the misfit (mm) of its rigid stand-in
    (`CalibrationResult.camera_transform_raw_points`); noise levels: camera
    point covariance scale, robot flange error (mm), marker orientation (deg);
    self-check: chi-square against the camera's a-priori model and the
    held-out (leave-one-out) prediction error of the marker point, observed
    and predicted (mm); blocked folds: each candidate model's error on the
    contiguous stretches held out (mm) and what decided.
    """
    auto, check = result.auto, result.self_check
    if check is None and auto is None:
        return None
    out: dict = {}
    if auto is not None:
        out.update(_auto_report(result))
    if check is not None:
        out["self_check"] = {
            "chi2": check.chi2, "dof": check.dof, "p_value": check.p_value,
            "camera_noise_model_rejected": check.prior_model_rejected,
            "heldout_observed_mm": check.loo_observed_m * 1e3,
            "heldout_predicted_mm": check.loo_predicted_m * 1e3,
            "heldout_ratio": check.loo_ratio,
            "consistent": check.consistent,
            "warning": check.warning,
        }
    if auto is not None and auto.blocked_folds is not None:
        b = auto.blocked_folds
        out["blocked_folds"] = {"folds": b.folds, "chosen_by": b.chosen_by, "candidates": [
            {**({"closed_form": c.closed_form} if c.closed_form is not None else
                {"orientations": c.orientations, "camera_correction": list(c.camera_correction)}),
             "heldout_mm": c.heldout_m * 1e3} for c in b.candidates]}
    if auto is not None and auto.notes:
        out["notes"] = list(auto.notes)
    return out


#: Unit of each camera parameter in the report: its key there and the factor from SI.
_CAMERA_UNITS = {"depth_scale": ("depth_scale_percent", 100.0), "depth_offset": ("depth_offset_mm", 1e3),
                 "focal_scale": ("focal_scale_percent", 100.0)}


def _auto_report(result: CalibrationResult) -> dict:
    """`model_report`'s part from ``auto``'s details: measurements, camera correction, noise, shared robot error."""
    auto = result.auto
    out: dict = {"measurements": list(auto.measurements), "camera_correction": {
        _CAMERA_UNITS[name][0]: {"value": c.value * _CAMERA_UNITS[name][1], "sigma": c.sigma * _CAMERA_UNITS[name][1],
                                 "estimated": c.estimated}
        for name, c in auto.camera_correction.items()}}
    if result.raw_points_fit is not None:
        # How far the rigid stand-in for the correction (what a URDF or tf carries) is from the correction itself.
        out["raw_points_misfit_mm"] = result.raw_points_fit["misfit_m"] * 1e3
    n = auto.noise
    out["noise"] = {"camera_point_scale": n.point_scale, "robot_mm": n.robot * 1e3,
                    "marker_rotation_deg": None if n.rotation is None else float(np.rad2deg(n.rotation))}
    if auto.robot_shared_error_m is not None:
        # The 1-sigma of the camera translation that the robot's shared (kinematic) error adds.
        out["robot_shared_error_mm"] = auto.robot_shared_error_m * 1e3
    return out


def raw_points_dict(result: CalibrationResult, frames: dict | None = None) -> dict:
    """The camera transform for uncorrected points (`CalibrationResult.camera_transform_raw_points`), with its misfit."""
    setup = Setup(result.setup)
    d = _transform_dict(result.camera_transform_raw_points, setup.camera_name + " for uncorrected points",
                        *_parent_child(setup, check_frames(frames)))
    d["misfit_mm"] = result.raw_points_fit["misfit_m"] * 1e3
    d["note"] = ("the camera correction folded into a rigid transform (which_transform says when to use it); "
                 "misfit_mm: its RMS misfit over the calibration samples")
    return d


#: Rotation from a ROS ``camera_link`` (x forward, y left, z up) to the camera's optical frame
#: (z forward, x right, y down): ``T_camera_link_optical``, origin shared.
T_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def camera_frame_note(result: CalibrationResult, frames: dict | None = None) -> dict:
    """What the camera frame is (the optical frame) and the pose of a ROS ``camera_link`` at the same origin."""
    frames = check_frames(frames)
    parent, child = _parent_child(result.setup, frames)
    link = result.camera_transform_raw_points @ tf.invert(T_LINK_OPTICAL)
    t, q = tf.to_xyz_quat(link)
    return {
        "name": child,
        "convention": "optical frame: z forward (viewing direction), x right, y down in the image "
                      "(ROS REP 103 *_optical_frame); not a ROS camera_link",
        "camera_link_to_optical": {"quaternion_xyzw": [-0.5, 0.5, -0.5, 0.5], "rpy_deg": [-90.0, 0.0, -90.0],
                                   "note": "T_camera_link_optical: camera_link (x forward, y left, z up) to the "
                                           "optical frame, same origin"},
        "camera_link_transform": {"parent_frame": parent, "translation_m": t.tolist(), "quaternion_xyzw": q.tolist(),
                                  "note": f"T_{parent}_camera_link = camera_transform_raw_points @ "
                                          "inv(T_camera_link_optical) (camera_transform without a camera correction)"},
    }


def easy_handeye_dict(result: CalibrationResult, frames: dict | None = None, *, namespace: str = "handeye") -> dict:
    """easy_handeye (ROS 1) calibration file: ``parameters`` + ``transformation`` {x..qw}.

    easy_handeye publishes ``transformation`` from the effector (eye-on-hand)
    or base (eye-on-base) frame to ``tracking_base_frame``, i.e. handeye's
    camera transform.
    """
    check_result(result)
    frames = check_frames(frames)
    t, q = tf.to_xyz_quat(result.camera_transform_raw_points)
    return {
        "parameters": {
            "namespace": f"/{namespace}/", "move_group_namespace": "/", "move_group": "manipulator",
            "eye_on_hand": result.setup == Setup.EYE_IN_HAND,
            "robot_base_frame": frames["base"], "robot_effector_frame": frames["flange"],
            "tracking_base_frame": frames["camera"], "tracking_marker_frame": frames["marker"],
        },
        "transformation": dict(zip(("x", "y", "z", "qx", "qy", "qz", "qw"), map(float, [*t, *q]))),
    }


def easy_handeye2_dict(result: CalibrationResult, frames: dict | None = None, *, name: str = "handeye") -> dict:
    """easy_handeye2 ``.calib`` file: ``parameters`` + ``transform`` {translation, rotation}."""
    check_result(result)
    frames = check_frames(frames)
    t, q = tf.to_xyz_quat(result.camera_transform_raw_points)
    return {
        "parameters": {
            "name": name, "calibration_type": "eye_in_hand" if result.setup == Setup.EYE_IN_HAND else "eye_on_base",
            "robot_base_frame": frames["base"], "robot_effector_frame": frames["flange"],
            "tracking_base_frame": frames["camera"], "tracking_marker_frame": frames["marker"],
            "freehand_robot_movement": True, "move_group_namespace": "/", "move_group": "manipulator",
        },
        "transform": {"translation": dict(zip("xyz", map(float, t))),
                      "rotation": dict(zip("xyzw", map(float, q)))},
    }


def _raw_points_remark(result: CalibrationResult) -> str:
    """What a rigid-only export holds when the result estimated a camera correction (else nothing)."""
    raw = result.raw_points_fit
    if raw is None:
        return ""
    return ("; for the camera's uncorrected points: the estimated camera correction folded in "
            f"(misfit {raw['misfit_m'] * 1e3:.2f} mm RMS over the samples, see result.yaml)")


def urdf_joint(result: CalibrationResult, frames: dict | None = None) -> str:
    """A xacro file holding one fixed ``<joint>`` from the camera's parent frame to the camera frame.

    The ``<robot>`` root makes it a valid ``<xacro:include>`` for an existing
    robot description, which must define both links.
    """
    check_result(result)
    frames = check_frames(frames)
    parent, child = _parent_child(result.setup, frames)
    cam_name = Setup(result.setup).camera_name
    return (
        f"<!-- handeye {result.setup}: {cam_name} by {result.method}, {result.n_samples} samples, "
        f"residual RMS {result.residuals.rms_translation * 1e3:.2f} mm{_raw_points_remark(result)} -->\n"
        f'<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="handeye_calibration">\n'
        f'  <joint name="{parent}_to_{child}_handeye" type="fixed">\n'
        f'    <parent link="{parent}"/>\n'
        f'    <child link="{child}"/>\n'
        f"    {urdf_origin(result)}\n"
        f"  </joint>\n"
        f"</robot>\n"
    )


def ros2_launch(result: CalibrationResult, frames: dict | None = None, camera_tf: dict | None = None) -> str:
    """A ROS 2 Python launch file starting ``static_transform_publisher`` with the camera transform
    (``camera_tf``: to the camera driver's tf root, `published_transform`)."""
    check_result(result)
    frames = check_frames(frames)
    parent, child, T = published_transform(result, frames, camera_tf)
    t, q = tf.to_xyz_quat(T)
    args = []
    for k, v in zip(("x", "y", "z", "qx", "qy", "qz", "qw"), [*t, *q]):
        args += [f"--{k}", _fmt(v)]
    args += ["--frame-id", parent, "--child-frame-id", child]
    arg_lines = "".join(f"                {json.dumps(a)}, {json.dumps(b)},\n" for a, b in zip(args[::2], args[1::2]))
    return (
        f'"""Publish the hand-eye calibration ({result.setup}, {Setup(result.setup).camera_name}, '
        f'solver {result.method}) as a static transform{_raw_points_remark(result)}."""\n'
        "from launch import LaunchDescription\n"
        "from launch_ros.actions import Node\n\n\n"
        "def generate_launch_description():\n"
        "    return LaunchDescription([\n"
        "        Node(\n"
        '            package="tf2_ros",\n'
        '            executable="static_transform_publisher",\n'
        '            name="handeye_static_transform",\n'
        "            arguments=[\n"
        f"{arg_lines}"
        "            ],\n"
        "        ),\n"
        "    ])\n"
    )


def write_result(result: CalibrationResult, path, fmt: str = "yaml", frames: dict | None = None,
                 camera_tf: dict | None = None, samples_from=None, cell: dict | None = None) -> Path:
    """Write a calibration result in one of `EXPORT_FORMATS`.

    Parameters
    ----------
    result : CalibrationResult
    path : str or Path
        Output file; parent directories are created.
    fmt : {"yaml", "json", "easy_handeye", "easy_handeye2", "urdf", "ros2_launch"}
        ``yaml``/``json``: the main result document (`result_to_dict`);
        ``easy_handeye``: ROS 1 calibration YAML; ``easy_handeye2``: ROS 2
        ``.calib`` YAML; ``urdf``: a xacro include with the fixed joint; ``ros2_launch``: a
        Python launch file.
    frames : dict, optional
        Frame names (``base``, ``flange``, ``camera``, ``marker``).
    camera_tf : dict, optional
        ``ros2_launch`` only: publish to the camera driver's tf root (`published_transform`).
    samples_from : str or Path, optional
        ``yaml`` / ``json``: where the samples came from (`result_to_dict`).
    cell : dict, optional
        ``yaml`` / ``json``: who made it, where and with what (`result_to_dict`).

    Returns
    -------
    Path
        The file written.
    """
    check_result(result)
    if fmt not in EXPORT_FORMATS:
        raise ConfigError(f"fmt must be one of {EXPORT_FORMATS}, got {fmt!r}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if fmt == "yaml":
        text = (f"# handeye calibration result ({result.setup}); camera_transform = {Setup(result.setup).camera_name}; "
                "verdict: pass | warn | fail with its reasons\n"
                "# The camera frame is the OPTICAL frame (z forward, x right, y down); camera_frame gives a ROS "
                "camera_link.\n"
                + yaml.dump(result_to_dict(result, frames, samples_from, cell), Dumper=_Dumper, sort_keys=False,
                            width=1000))
    elif fmt == "json":
        text = json.dumps(result_to_dict(result, frames, samples_from, cell), indent=2) + "\n"
    elif fmt == "easy_handeye":
        text = yaml.safe_dump(easy_handeye_dict(result, frames), default_flow_style=False)
    elif fmt == "easy_handeye2":
        text = yaml.safe_dump(easy_handeye2_dict(result, frames), sort_keys=False)
    elif fmt == "urdf":
        text = urdf_joint(result, frames)
    else:
        text = ros2_launch(result, frames, camera_tf)
    path.write_text(text)
    return path
