"""Exported files parse back (YAML/JSON load, URDF via ElementTree, launch file via ast) to the result."""

import ast
import dataclasses
import json
import shlex
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from handeye.app.formats import EXPORT_FORMATS, result_to_dict, write_result
from handeye.calib import simulate
from handeye.calib import transforms as tf
from handeye.calib.api import solve
from handeye.app.errors import ConfigError
from handeye.calib.errors import CalibrationError

FRAMES = {"base": "base_link", "flange": "tool0", "camera": "cam_optical", "marker": "target"}


@pytest.fixture(scope="module", params=["eye_to_hand", "eye_in_hand", "auto with a camera correction"])
def result(request):
    if request.param.startswith("auto"):
        data = simulate.realistic_profile(30, np.random.default_rng(0)).data
        res = solve("auto", data.A, data.B)
        assert res.raw_points_fit is not None
        return res
    data = simulate.realistic_cell(20, np.random.default_rng(11), setup=request.param)
    return solve("YKronRT", data.A, data.B, setup=request.param)


def _parent(result):
    return FRAMES["base"] if result.setup == "eye_to_hand" else FRAMES["flange"]


def _from_flags(args):
    """Transform and frame names from static_transform_publisher's --x .. --child-frame-id flags."""
    opts = dict(zip(args[::2], args[1::2]))
    T = tf.from_xyz_quat([float(opts[f"--{k}"]) for k in "xyz"], [float(opts[f"--q{k}"]) for k in "xyzw"])
    return T, opts["--frame-id"], opts["--child-frame-id"]


def _close(T, result, atol=1e-7):
    """``T`` is the transform a rigid-only export carries: the one for the camera's uncorrected points."""
    rot, trans = tf.pose_error(T, result.camera_transform_raw_points)
    assert rot < atol and trans < atol


def test_main_yaml_round_trip(result, tmp_path):
    path = write_result(result, tmp_path / "result.yaml", frames=FRAMES)
    doc = yaml.safe_load(path.read_text())
    assert doc["setup"] == result.setup and doc["solver"] == result.method
    cam = doc["camera_transform"]
    assert cam["name"] == ("T_base_cam" if result.setup == "eye_to_hand" else "T_flange_cam")
    assert (cam["parent_frame"], cam["child_frame"]) == (_parent(result), "cam_optical")
    np.testing.assert_allclose(cam["matrix"], result.camera_transform, atol=1e-12)
    for key, T in (("camera_transform", result.camera_transform),
                   ("camera_transform_raw_points", result.camera_transform_raw_points)):
        if key not in doc:
            assert result.raw_points_fit is None
            continue
        R = Rotation.from_euler("xyz", doc[key]["rpy_deg"], degrees=True).as_matrix()
        for pose in (tf.from_xyz_quat(doc[key]["translation_m"], doc[key]["quaternion_xyzw"]),
                     tf.make_transform(R, doc[key]["translation_m"])):
            rot, trans = tf.pose_error(pose, T)
            assert rot < 1e-7 and trans < 1e-7
    sd = np.sqrt(np.diag(result.cov))
    np.testing.assert_allclose(cam["sigma_1"]["translation_mm"], sd[3:] * 1e3)
    np.testing.assert_allclose(cam["sigma_1"]["rotation_deg"], np.rad2deg(sd[:3]))
    assert doc["residuals"]["n_samples"] == result.n_samples
    assert doc["residuals"]["rms_translation_mm"] == pytest.approx(result.residuals.rms_translation * 1e3)
    assert doc["residuals"]["rms_rotation_deg"] == pytest.approx(np.rad2deg(result.residuals.rms_rotation))
    # The pasted command and URDF line carry the same transform.
    T, parent, child = _from_flags(shlex.split(doc["ros2_static_transform_publisher"])[4:])
    assert shlex.split(doc["ros2_static_transform_publisher"])[:4] == ["ros2", "run", "tf2_ros",
                                                                       "static_transform_publisher"]
    _close(T, result)
    assert (parent, child) == (_parent(result), "cam_optical")
    origin = ET.fromstring(doc["urdf_origin"])
    R = Rotation.from_euler("xyz", [float(v) for v in origin.get("rpy").split()]).as_matrix()
    _close(tf.make_transform(R, [float(v) for v in origin.get("xyz").split()]), result)


def test_json_matches_yaml_content(result, tmp_path):
    doc = json.loads(write_result(result, tmp_path / "r.json", fmt="json", frames=FRAMES).read_text())
    assert doc == json.loads(json.dumps(result_to_dict(result, FRAMES)))


def test_easy_handeye_files(result, tmp_path):
    ros1 = yaml.safe_load(write_result(result, tmp_path / "eh.yaml", fmt="easy_handeye", frames=FRAMES).read_text())
    assert ros1["parameters"]["eye_on_hand"] is (result.setup == "eye_in_hand")
    assert ros1["parameters"]["tracking_base_frame"] == "cam_optical"
    tr = ros1["transformation"]
    _close(tf.from_xyz_quat([tr["x"], tr["y"], tr["z"]], [tr["qx"], tr["qy"], tr["qz"], tr["qw"]]), result)
    ros2 = yaml.safe_load(write_result(result, tmp_path / "eh.calib", fmt="easy_handeye2", frames=FRAMES).read_text())
    expected = "eye_in_hand" if result.setup == "eye_in_hand" else "eye_on_base"
    assert ros2["parameters"]["calibration_type"] == expected
    t, r = ros2["transform"]["translation"], ros2["transform"]["rotation"]
    _close(tf.from_xyz_quat([t["x"], t["y"], t["z"]], [r["x"], r["y"], r["z"], r["w"]]), result)


def test_easy_handeye_parameter_names_match_the_tools(result, tmp_path):
    """The tools build their parameter classes with **parameters: every key must be one of their fields."""
    ros1 = yaml.safe_load(write_result(result, tmp_path / "eh.yaml", fmt="easy_handeye").read_text())
    # easy_handeye HandeyeCalibrationParameters.__init__ arguments (IFL-CAMP/easy_handeye).
    assert set(ros1["parameters"]) == {"namespace", "move_group_namespace", "move_group", "eye_on_hand",
                                       "robot_base_frame", "robot_effector_frame", "tracking_base_frame",
                                       "tracking_marker_frame"}
    ros2 = yaml.safe_load(write_result(result, tmp_path / "eh.calib", fmt="easy_handeye2").read_text())
    # easy_handeye2 HandeyeCalibrationParameters dataclass fields, as in its tests/data/*.calib.
    assert set(ros2["parameters"]) == {"name", "calibration_type", "robot_base_frame", "robot_effector_frame",
                                       "tracking_base_frame", "tracking_marker_frame", "freehand_robot_movement",
                                       "move_group_namespace", "move_group"}
    assert set(ros2["transform"]) == {"translation", "rotation"}


def test_urdf_joint(result, tmp_path):
    robot = ET.parse(write_result(result, tmp_path / "j.urdf.xacro", fmt="urdf", frames=FRAMES)).getroot()
    assert robot.tag == "robot"
    root = robot.find("joint")
    assert root.get("type") == "fixed"
    assert root.find("parent").get("link") == _parent(result)
    assert root.find("child").get("link") == "cam_optical"
    o = root.find("origin")
    R = Rotation.from_euler("xyz", [float(v) for v in o.get("rpy").split()]).as_matrix()
    _close(tf.make_transform(R, [float(v) for v in o.get("xyz").split()]), result)


def test_ros2_launch_file(result, tmp_path):
    tree = ast.parse(write_result(result, tmp_path / "tf.launch.py", fmt="ros2_launch", frames=FRAMES).read_text())
    assert any(isinstance(n, ast.FunctionDef) and n.name == "generate_launch_description" for n in tree.body)
    nodes = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", None) == "Node"]
    assert len(nodes) == 1
    kw = {k.arg: ast.literal_eval(k.value) for k in nodes[0].keywords}
    assert (kw["package"], kw["executable"]) == ("tf2_ros", "static_transform_publisher")
    T, parent, child = _from_flags(kw["arguments"])
    _close(T, result)
    assert (parent, child) == (_parent(result), "cam_optical")


def test_bad_export_arguments(result, tmp_path):
    with pytest.raises(ConfigError, match="fmt"):
        write_result(result, tmp_path / "x", fmt="xml")
    with pytest.raises(ConfigError, match="frames.camera"):
        write_result(result, tmp_path / "x.yaml", frames={"camera": "my camera"})
    with pytest.raises(ConfigError, match="unknown keys"):
        write_result(result, tmp_path / "x.yaml", frames={"world": "w"})
    # A result holding NaN cannot even be made, so none reaches an exporter.
    with pytest.raises(CalibrationError, match="Y of the solution is not finite"):
        dataclasses.replace(result, Y=np.full((4, 4), np.nan))
    with pytest.raises(CalibrationError, match="CalibrationResult"):
        write_result({"X": np.eye(4)}, tmp_path / "x.yaml")
    assert set(EXPORT_FORMATS) == {"yaml", "json", "easy_handeye", "easy_handeye2", "urdf", "ros2_launch"}


def test_rigid_exports_carry_the_camera_correction_folded_in(result, tmp_path):
    """A URDF or tf gets the camera's raw points: with an estimated camera correction, its transform is
    camera_transform @ G (the correction's rigid stand-in), named so in result.yaml and the files."""
    doc = result_to_dict(result, FRAMES)
    urdf = write_result(result, tmp_path / "j.urdf.xacro", fmt="urdf", frames=FRAMES).read_text()
    if result.raw_points_fit is None:
        assert "camera_transform_raw_points" not in doc and "uncorrected" not in urdf
        np.testing.assert_array_equal(result.camera_transform_raw_points, result.camera_transform)
        assert doc["which_transform"].startswith("one transform, camera_transform")
        return
    raw = doc["camera_transform_raw_points"]
    G = result.raw_points_fit["transform"]
    np.testing.assert_allclose(raw["matrix"], result.camera_transform @ G, atol=1e-12)
    assert tf.pose_error(result.camera_transform_raw_points, result.camera_transform)[1] > 1e-3
    assert raw["misfit_mm"] == pytest.approx(result.raw_points_fit["misfit_m"] * 1e3)
    assert "uncorrected points" in urdf and "uncorrected points" in raw["name"]
    # Said once, which transform goes with which points: the correction's values and how far apart they are.
    use = doc["which_transform"]
    assert use.startswith("use camera_transform_raw_points") and "static_transform_publisher" in use
    assert "depth scale" in use and "the two differ by" in use
