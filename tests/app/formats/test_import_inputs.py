"""Importers on damaged files: a HandeyeError naming the file, never a traceback, a hang or a read outside.

Property tests for every importer (easy_handeye2, easy_handeye, industrial_calibration,
pose-stream CSV, ViSP, image folder, OpenCV FileStorage, MoveIt Calibration) plus the
cases the fuzz campaign found.
"""

import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.fuzz import IMPORT_MAIN, write_import_seed
from handeye.app.formats import load
from handeye.calib import simulate
from handeye.calib import transforms as tf
from handeye.app.errors import ConfigError, SessionError
from handeye.calib.errors import HandeyeError

SETTINGS = settings(max_examples=25, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
DATA_DIR = Path(__file__).resolve().parents[2] / "data"

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


def _load_with_value(tmp_path, doc, where, value, name: str) -> None:
    """A copy of ``doc`` with ``value`` at ``where``, written as YAML file ``name``, loads or raises a typed error."""
    import copy

    doc = copy.deepcopy(doc)
    _set_path(doc, where, value)
    p = tmp_path / name
    p.write_text(yaml.safe_dump(doc))
    _load_or_error(p)


@SETTINGS
@given(where=st.sampled_from(EH2_PATHS), value=YAML_VALUES)
def test_easy_handeye2_any_value_anywhere(tmp_path, where, value):
    _load_with_value(tmp_path, EH2, where, value, "c.samples")


@SETTINGS
@given(where=st.sampled_from(EH1_PATHS), value=YAML_VALUES)
def test_easy_handeye_any_value_anywhere(tmp_path, where, value):
    _load_with_value(tmp_path, EH1, where, value, "samples.yaml")


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


# ------------------------------------------------ ViSP, image folder, OpenCV FileStorage, MoveIt
# Seeded from the fuzz campaign's own valid file sets (bench.fuzz.write_import_seed), damaged
# here by hypothesis; each load runs under an audit hook (conftest.OutsideReads) that catches any file
# opened outside the set.

#: More examples than the older importers' tests: these cover every file of a set at once.
DAMAGE_SETTINGS = settings(SETTINGS, max_examples=100)

#: What replaces a value: wrong types, absurd numbers, OpenCV tags, nesting, names outside the set.
TOKENS = st.sampled_from(["null", "[]", "{}", '"abc"', "true", "-1", "1e400", "nan", ".nan", "1e155", "[[1, 2], [3]]",
                          '"../outside.txt"', '"/etc/hostname"', "0", '""', "[" * 40 + "]" * 40, "!!opencv-matrix",
                          "dt: x", "rows: 100000", "4294967297", "-0.0", "1e-320"])
_VALUE = re.compile(rb'-?\d+(?:\.\d+)?(?:e-?\d+)?|"[^"\n]*"|\w+')
DAMAGE = dict(how=st.sampled_from(["insert", "truncate", "token", "token"]), pos=st.integers(0, 10_000),
              junk=st.binary(min_size=1, max_size=64), token=TOKENS)


def _damage(data: bytes, how, pos, junk, token) -> bytes:
    pos %= len(data) + 1
    if how == "insert":
        return data[:pos] + junk + data[pos:]
    if how == "truncate":
        return data[:pos]
    spans = [m.span() for m in _VALUE.finditer(data)] or [(pos, pos)]
    a, b = spans[pos % len(spans)]
    return data[:a] + token.encode() + data[b:]


NEW_KINDS = ["visp", "image_folder", "opencv_storage", "moveit_calibration"]


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    root = tmp_path_factory.mktemp("seeds")
    return {kind: write_import_seed(kind, root, np.random.default_rng(3))
            for kind in NEW_KINDS}


def _fresh(seeds, kind, tmp_path) -> Path:
    """A new copy of ``kind``'s seed (hypothesis reuses ``tmp_path`` across examples), a canary beside it."""
    case = tmp_path / "case"
    shutil.rmtree(case, ignore_errors=True)
    shutil.copytree(seeds[kind], case / kind)
    (case / "outside.txt").write_text("not yours\n")
    return case / kind


def _load_checked(folder: Path, kind: str, outside_reads):
    """Load the damaged set: a result or a HandeyeError naming the file; never another exception, an outside read."""
    path = folder / IMPORT_MAIN[kind] if kind in IMPORT_MAIN else folder
    with outside_reads.watch(folder):
        try:
            imp = load(path)
        except HandeyeError as e:
            assert str(folder) in str(e), f"message does not name the file: {e}"
            return None
    assert len(imp.observations) >= 1
    assert all(np.isfinite(o.T_base_flange).all() and np.isfinite(o.point_cam).all() for o in imp.observations)
    return imp


def _files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file())


@DAMAGE_SETTINGS
@given(kind=st.sampled_from(NEW_KINDS), which=st.integers(0, 100), **DAMAGE)
def test_new_importers_any_damage_to_any_file(seeds, tmp_path, outside_reads, kind, which, how, pos, junk, token):
    folder = _fresh(seeds, kind, tmp_path)
    files = _files(folder)
    target = files[which % len(files)]
    target.write_bytes(_damage(target.read_bytes(), how, pos, junk, token))
    _load_checked(folder, kind, outside_reads)


@DAMAGE_SETTINGS
@given(kind=st.sampled_from(["opencv_storage", "moveit_calibration", "image_folder"]), **DAMAGE)
def test_new_importers_damage_to_the_main_file(seeds, tmp_path, outside_reads, kind, how, pos, junk, token):
    folder = _fresh(seeds, kind, tmp_path)
    target = folder / IMPORT_MAIN.get(kind, "poses.json")
    target.write_bytes(_damage(target.read_bytes(), how, pos, junk, token))
    _load_checked(folder, kind, outside_reads)


VISP_PATHS = [("rows",), ("cols",), ("data",), ("data", 0), ("data", 4), ("data", 2, 0), ("data", 5, 0)]


@SETTINGS
@given(name=st.sampled_from(["pose_fPe_1.yaml", "pose_cPo_2.yaml"]), where=st.sampled_from(VISP_PATHS),
       value=YAML_VALUES)
def test_visp_any_value_anywhere(seeds, tmp_path, outside_reads, name, where, value):
    folder = _fresh(seeds, "visp", tmp_path)
    doc = yaml.safe_load((folder / name).read_text())
    _set_path(doc, where, value)
    (folder / name).write_text(yaml.safe_dump(doc))
    _load_checked(folder, "visp", outside_reads)


MOVEIT_PATHS = [(0,), (1, 0), (2, 1), (3, 0, 1), (4, 1, 3), (5, 0, 2, 3), (6, 1, 0, 0), (7, 0, 3, 3)]


@SETTINGS
@given(where=st.sampled_from(MOVEIT_PATHS), value=YAML_VALUES)
def test_moveit_any_value_anywhere(seeds, tmp_path, outside_reads, where, value):
    folder = _fresh(seeds, "moveit_calibration", tmp_path)
    path = folder / IMPORT_MAIN["moveit_calibration"]
    doc = json.loads(path.read_text())
    _set_path(doc, where, value)
    path.write_text(json.dumps(doc))
    _load_checked(folder, "moveit_calibration", outside_reads)


IMAGE_FOLDER_FIELDS = ["image", "depth", "x", "qw", "matrix"]
INTRINSICS_FIELDS = ["fx", "fy", "cx", "cy", "dist", "camera_matrix", "distortion_coefficients"]


@SETTINGS
@given(where=st.one_of(st.tuples(st.just("poses"), st.integers(0, 2), st.sampled_from(IMAGE_FOLDER_FIELDS)),
                       st.sampled_from([("setup",), ("poses",), ("poses", 1)]),
                       st.tuples(st.just("intrinsics"), st.sampled_from(INTRINSICS_FIELDS))),
       value=YAML_VALUES)
def test_image_folder_any_value_anywhere(seeds, tmp_path, outside_reads, where, value):
    folder = _fresh(seeds, "image_folder", tmp_path)
    if where[0] == "intrinsics":
        doc = yaml.safe_load((folder / "intrinsics.yaml").read_text())
        doc[where[1]] = value
        (folder / "intrinsics.yaml").write_text(yaml.safe_dump(doc))
    else:
        doc = json.loads((folder / "poses.json").read_text())
        _set_path(doc, where, value)
        (folder / "poses.json").write_text(json.dumps(doc))
    _load_checked(folder, "image_folder", outside_reads)


# -- what the campaign found in these four (regressions)

@pytest.mark.parametrize("kind,name", [("visp", "pose_fPe_1.yaml"), ("image_folder", "poses.json"),
                                       ("image_folder", "intrinsics.yaml")])
def test_files_of_a_set_symlinked_out_are_refused(seeds, tmp_path, kind, name):
    folder = _fresh(seeds, kind, tmp_path)
    (folder / name).unlink()
    (folder / name).symlink_to(folder.parent / "outside.txt")
    with pytest.raises(SessionError, match="outside"):
        load(folder)


@pytest.mark.parametrize("damage", [lambda t: t[:200], lambda t: t.replace("dt: d", "dt: x", 1),
                                    lambda t: t.replace("rows: 3", "rows: 1", 1), lambda t: ""])
def test_opencv_storage_parse_errors_are_session_errors(seeds, tmp_path, damage):
    folder = _fresh(seeds, "opencv_storage", tmp_path)
    path = folder / IMPORT_MAIN["opencv_storage"]
    path.write_text(damage(path.read_text()))
    with pytest.raises(SessionError, match=r"pairs\.yaml: not a valid OpenCV FileStorage file \(\("):
        load(path, format="opencv_storage")


@pytest.mark.parametrize("dist", ["[0.1, 0.2]", "[1, 2, 3, 4, 5, 6]", "[0, 0, 0, 0, .nan]"])
def test_image_folder_distortion_of_no_opencv_model_is_a_config_error(seeds, tmp_path, dist):
    folder = _fresh(seeds, "image_folder", tmp_path)
    text = (folder / "intrinsics.yaml").read_text()
    (folder / "intrinsics.yaml").write_text(text.replace("dist: [0.0, 0.0, 0.0, 0.0, 0.0]", f"dist: {dist}"))
    with pytest.raises(ConfigError, match="intrinsics.yaml: distortion coefficients must be 4, 5, 8, 12, 14"):
        load(folder)


def test_a_non_rotation_names_the_file(seeds, tmp_path):
    folder = _fresh(seeds, "moveit_calibration", tmp_path)
    path = folder / IMPORT_MAIN["moveit_calibration"]
    doc = json.loads(path.read_text())
    doc[2][1][0][0] = 3.0
    path.write_text(json.dumps(doc))
    with pytest.raises(SessionError, match=r"pose_samples\.json: T_cam_marker\[2\] rotation is not a proper rotation"):
        load(path)


def test_a_wrong_setup_in_the_pose_file_names_it(seeds, tmp_path):
    folder = _fresh(seeds, "image_folder", tmp_path)
    text = (folder / "poses.json").read_text()
    (folder / "poses.json").write_text(text.replace('"eye_to_hand"', '"abc"'))
    with pytest.raises(SessionError, match=r"poses\.json: setup must be one of"):
        load(folder)


def test_a_huge_pose_value_is_refused_without_overflow(seeds, tmp_path):
    import warnings

    folder = _fresh(seeds, "image_folder", tmp_path)
    doc = json.loads((folder / "poses.json").read_text())
    doc["poses"][1]["qx"] = 1e155
    (folder / "poses.json").write_text(json.dumps(doc))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the quaternion norm overflowed to inf with a RuntimeWarning
        with pytest.raises(SessionError, match=r"poses\.json: pose 1: a value beyond 1e\+06"):
            load(folder)


@pytest.mark.parametrize("header", ["rows: 200000", "cols: 5", "sizes: [ 100000, 100000 ]"])
def test_opencv_storage_matrix_sizes_are_bounded_before_opencv_allocates(seeds, tmp_path, header):
    folder = _fresh(seeds, "opencv_storage", tmp_path)
    path = folder / IMPORT_MAIN["opencv_storage"]
    path.write_text(path.read_text().replace("rows: 3", header, 1))
    with pytest.raises(SessionError, match=r"pairs\.yaml: a matrix with .*pose matrices are at most 4x4"):
        load(path)
