"""Importers on damaged files: a HandeyeError naming the file, never a traceback, a hang or a read outside.

One property test per importer (easy_handeye2, easy_handeye, industrial_calibration,
pose-stream CSV) plus the cases the fuzz campaign found.
"""

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from app.formats import load
from calib import simulate
from calib import transforms as tf
from app.errors import SessionError
from calib.errors import HandeyeError

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
DATA_DIR = Path(__file__).resolve().parents[1] / "data"

YAML_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=3), inner, max_size=3),
    max_leaves=12,
)


def _msg(T):
    t, q = tf.to_xyz_quat(T)
    return {"translation": dict(zip("xyz", map(float, t))), "rotation": dict(zip("xyzw", map(float, q)))}


CELL = simulate.realistic_cell(6, np.random.default_rng(4))
EH2 = {"parameters": {"name": "c", "calibration_type": "eye_on_base"},
       "samples": [{"robot": _msg(R), "tracking": _msg(B)} for R, B in zip(tf.invert(CELL.A), CELL.B)]}
EH1 = {"parameters": {"eye_on_hand": False},
       "samples": {"hand_world_samples": [_msg(R) for R in tf.invert(CELL.A)],
                   "camera_marker_samples": [_msg(B) for B in CELL.B]}}


def _load_or_error(path):
    try:
        imp = load(path)
    except HandeyeError as e:
        assert str(e)
        return None
    assert all(np.isfinite(o.T_base_flange).all() for o in imp.observations)
    return imp


def _set_path(doc, path, value):
    node = doc
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value


EH2_PATHS = [("parameters",), ("parameters", "calibration_type"), ("samples",), ("samples", 0),
             ("samples", 1, "robot"), ("samples", 2, "tracking", "rotation"),
             ("samples", 3, "robot", "translation", "x"), ("samples", 4, "tracking", "rotation", "w")]
EH1_PATHS = [("parameters",), ("parameters", "eye_on_hand"), ("samples",), ("samples", "hand_world_samples"),
             ("samples", "camera_marker_samples", 1), ("samples", "hand_world_samples", 2, "rotation", "x")]


@SETTINGS
@given(where=st.sampled_from(EH2_PATHS), value=YAML_VALUES)
def test_easy_handeye2_any_value_anywhere(tmp_path, where, value):
    import copy

    doc = copy.deepcopy(EH2)
    _set_path(doc, where, value)
    p = tmp_path / "c.samples"
    p.write_text(yaml.safe_dump(doc))
    _load_or_error(p)


@SETTINGS
@given(where=st.sampled_from(EH1_PATHS), value=YAML_VALUES)
def test_easy_handeye_any_value_anywhere(tmp_path, where, value):
    import copy

    doc = copy.deepcopy(EH1)
    _set_path(doc, where, value)
    p = tmp_path / "samples.yaml"
    p.write_text(yaml.safe_dump(doc))
    _load_or_error(p)


@SETTINGS
@given(junk=st.binary(max_size=200), pos=st.integers(0, 3000))
def test_easy_handeye2_binary_junk(tmp_path, junk, pos):
    data = yaml.safe_dump(EH2).encode()
    p = tmp_path / "c.samples"
    p.write_bytes(data[:pos] + junk + data[pos:])
    _load_or_error(p)


@pytest.fixture
def streams(tmp_path):
    t = np.arange(40) * 0.05
    A = simulate.realistic_cell(40, np.random.default_rng(6)).A
    for name, T in (("hand.csv", A), ("target.csv", tf.invert(A))):
        xyz, q = tf.to_xyz_quat(T)
        (tmp_path / name).write_text("\n".join(",".join(f"{v:.9f}" for v in r) for r in np.column_stack([t, xyz, q])))
    (tmp_path / "streams.toml").write_text('format = "pose_csv"\nsetup = "eye_in_hand"\nrobot = "hand.csv"\n'
                                           'camera = "target.csv"\nclock_offset = 0.0\nrefine = false\n')
    return tmp_path


MANIFEST_VALUES = st.sampled_from(['"../outside.csv"', '"/etc/hostname"', "5", "true", '""', "[1]", "{a = 1}",
                                   '"hand.csv"', "nan", "-1", '"x"', "1e400"])


@SETTINGS
@given(key=st.sampled_from(["setup", "robot", "camera", "clock_offset", "max_gap", "stride", "refine",
                            "robot_transform", "max_offset", "format"]), value=MANIFEST_VALUES)
def test_pose_csv_any_manifest_value(streams, key, value):
    lines = [x for x in (streams / "streams.toml").read_text().splitlines() if not x.startswith(key + " ")]
    (streams / "streams.toml").write_text("\n".join([f"{key} = {value}"] + lines) + "\n")
    _load_or_error(streams)


@SETTINGS
@given(junk=st.binary(max_size=100), pos=st.integers(0, 4000), which=st.sampled_from(["hand.csv", "streams.toml"]))
def test_pose_csv_binary_junk(streams, junk, pos, which):
    data = (streams / which).read_bytes()
    (streams / which).write_bytes(data[:pos] + junk + data[pos:])
    _load_or_error(streams)


@pytest.mark.parametrize("name", ["../outside.csv", "/etc/hostname", "../../../../../../../../etc/hostname"])
def test_pose_csv_manifest_cannot_read_outside_its_directory(streams, name):
    (streams.parent / "outside.csv").write_text("0,0,0,0,0,0,0,1\n1,0,0,0,0,0,0,1\n")
    text = (streams / "streams.toml").read_text().replace('robot = "hand.csv"', f'robot = "{name}"')
    (streams / "streams.toml").write_text(text)
    with pytest.raises(SessionError, match="outside"):
        load(streams)


@pytest.mark.timeout(20)
def test_pose_csv_fifo_is_refused(streams):
    (streams / "hand.csv").unlink()
    os.mkfifo(streams / "hand.csv")
    with pytest.raises(SessionError, match="not a regular file"):
        load(streams)


def test_gzip_junk_is_a_session_error(streams):
    (streams / "hand.csv.gz").write_bytes(b"\x1f\x8b\x08junk")
    (streams / "streams.toml").write_text((streams / "streams.toml").read_text().replace("hand.csv", "hand.csv.gz"))
    with pytest.raises(SessionError, match="decompress"):
        load(streams)


@pytest.fixture
def industrial(tmp_path):
    src = DATA_DIR / "circle_grid"
    doc = yaml.safe_load((src / "cal_data.yaml").read_text())
    doc["data"] = doc["data"][:2]
    (tmp_path / "images").mkdir()
    (tmp_path / "poses").mkdir()
    for e in doc["data"]:
        shutil.copy(src / e["image"], tmp_path / e["image"])
        shutil.copy(src / e["pose"], tmp_path / e["pose"])
    (tmp_path / "cal_data.yaml").write_text(yaml.safe_dump(doc))
    return tmp_path, doc


@pytest.mark.parametrize("field", ["pose", "image"])
@pytest.mark.parametrize("name", ["../../../../../../../../etc/hostname", "/etc/hostname"])
def test_industrial_cannot_read_outside_its_directory(industrial, field, name):
    root, doc = industrial
    doc["data"][0][field] = name
    (root / "cal_data.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(SessionError, match="outside"):
        load(root)


INDUSTRIAL_PATHS = [("data",), ("data", 0), ("data", 1, "pose"), ("target_finder",), ("target_finder", "rows"),
                    ("target_finder", "spacing"), ("intrinsics",), ("intrinsics", "fx"), ("static_camera",)]


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(where=st.sampled_from(INDUSTRIAL_PATHS), value=YAML_VALUES)
def test_industrial_any_value_anywhere(industrial, where, value):
    import copy

    root, doc = industrial
    doc = copy.deepcopy(doc)
    _set_path(doc, where, value)
    (root / "cal_data.yaml").write_text(yaml.safe_dump(doc))
    _load_or_error(root)


@pytest.mark.parametrize("name", ["../../../../../../../../etc/hostname", "/etc/hostname"])
def test_image_folder_cannot_read_outside_its_directory(tmp_path, name):
    import json

    (tmp_path / "intrinsics.yaml").write_text(
        "image_width: 640\nimage_height: 480\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
        "  data: [500, 0, 320, 0, 500, 240, 0, 0, 1]\n"
        "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [0, 0, 0, 0, 0]\n")
    row = {"image": name, "x": 0.5, "y": 0.0, "z": 0.5, "qx": 0.0, "qy": 0.0, "qz": 0.0, "qw": 1.0}
    (tmp_path / "poses.json").write_text(json.dumps([row]))
    with pytest.raises(SessionError, match="outside"):
        load(tmp_path)


@pytest.mark.timeout(20)
def test_moveit_fifo_and_latin1_are_session_errors(tmp_path):
    p = tmp_path / "samples.json"
    p.write_bytes(b'[[caf\xe9]]')
    with pytest.raises(SessionError, match="not UTF-8"):
        load(p, format="moveit_calibration")
    p.unlink()
    os.mkfifo(p)
    with pytest.raises(SessionError, match="not a regular file"):
        load(p, format="moveit_calibration")


@pytest.mark.timeout(20)
def test_opencv_storage_fifo_is_refused_not_waited_on(tmp_path):
    p = tmp_path / "calib.yaml"
    os.mkfifo(p)
    with pytest.raises(SessionError, match="not a regular file"):
        load(p, format="opencv_storage")
