"""The session reader on damaged sessions: a SessionError naming file and line, never a traceback or a hang.

Eye-to-hand sessions (``X = T_flange_marker``, ``Y = T_base_cam``).
"""

import json
import os
import shutil

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from handeye.app.session import SessionWriter, read_session
from handeye.calib import simulate
from handeye.app.errors import SessionError
from handeye.calib.observation import Observation

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=3), inner, max_size=3),
    max_leaves=16,
)


@pytest.fixture(scope="module")
def seed_session(tmp_path_factory):
    root = tmp_path_factory.mktemp("seed")
    d = simulate.realistic_cell(6, np.random.default_rng(1))
    with SessionWriter.create(root, "eye_to_hand", name="s", truth={"T_base_cam": d.Y}) as w:
        for i in range(6):
            w.add_sample(Observation(i, float(i), d.A[i], d.points[i], d.point_cov[i], d.B[i]),
                         color=np.zeros((4, 4, 3), np.uint8) if i == 0 else None)
        w.add_skip(7.0, "marker not found", T_base_flange=d.A[0])
        w.add_event(8.0, "note")
    return root / "s"


@pytest.fixture
def session(seed_session, tmp_path):
    dst = tmp_path / "s"
    shutil.copytree(seed_session, dst)
    return dst


def _lines(path):
    return [json.loads(x) for x in (path / "samples.jsonl").read_text().splitlines()]


def _write_lines(path, recs):
    (path / "samples.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))


def _read_or_session_error(path):
    try:
        s = read_session(path)
    except SessionError as e:
        assert str(path) in str(e) or "samples.jsonl" in str(e) or "session.json" in str(e), str(e)
        return None
    for o in s.observations:
        assert isinstance(o.index, int) and np.isfinite(o.t)
        assert o.T_base_flange.shape == (4, 4) and o.T_base_flange.dtype == float
        assert np.isfinite(o.T_base_flange).all()
    return s


@SETTINGS
@given(line=st.integers(0, 7), key=st.sampled_from(["index", "t", "T_base_flange", "point_cam", "point_cov",
                                                     "T_cam_marker", "pose_cov", "meta", "kind", "reason"]),
       value=JSON_VALUES)
def test_any_value_in_any_field(session, line, key, value):
    recs = _lines(session)
    recs[line][key] = value
    _write_lines(session, recs)
    _read_or_session_error(session)


@SETTINGS
@given(line=st.integers(0, 7), value=JSON_VALUES)
def test_any_json_value_as_a_line(session, line, value):
    recs = _lines(session)
    recs[line] = value
    _write_lines(session, recs)
    _read_or_session_error(session)


@SETTINGS
@given(junk=st.binary(max_size=300), pos=st.integers(0, 4000))
def test_binary_junk(session, junk, pos):
    data = (session / "samples.jsonl").read_bytes()
    (session / "samples.jsonl").write_bytes(data[:pos] + junk + data[pos:])
    _read_or_session_error(session)


@SETTINGS
@given(value=JSON_VALUES, key=st.sampled_from(["truth", "version", "setup", "format"]))
def test_any_header_field(session, value, key):
    header = json.loads((session / "session.json").read_text())
    header[key] = value
    (session / "session.json").write_text(json.dumps(header))
    _read_or_session_error(session)


@pytest.mark.parametrize("value,match", [
    ([], r"line 2: expected a JSON object, got list"),
    (None, r"line 2: expected a JSON object, got NoneType"),
    (5, r"line 2: expected a JSON object"),
])
def test_lines_that_are_not_objects_name_the_line(session, value, match):
    recs = _lines(session)
    recs[1] = value
    _write_lines(session, recs)
    with pytest.raises(SessionError, match=match):
        read_session(session)


@pytest.mark.parametrize("field,value,match", [
    ("T_base_flange", [[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "line 3: T_base_flange is not a rectangular"),
    ("point_cam", ["a", 0, 0], "line 3: point_cam must hold real numbers"),
    ("t", "noon", "line 3: t must be a finite number"),
    ("index", 1.5, "line 3: index must be an integer"),
    ("index", True, "line 3: index must be an integer"),
    ("meta", [1], "line 3: meta must be an object"),
])
def test_bad_fields_name_line_and_field(session, field, value, match):
    recs = _lines(session)
    recs[2][field] = value
    _write_lines(session, recs)
    with pytest.raises(SessionError, match=match):
        read_session(session)


def test_duplicate_sample_indices_are_refused_naming_them(session):
    recs = _lines(session)
    recs[4]["index"] = recs[1]["index"]
    _write_lines(session, recs)
    with pytest.raises(SessionError, match=r"line 5: index 1 is used twice \(also on line 2\)"):
        read_session(session)


@pytest.mark.parametrize("truth,match", [
    ([1, 2], "truth must be an object"),
    ({"T_base_cam": [[1, 2], [3]]}, "truth.T_base_cam"),
    ({"T_base_cam": np.diag([2.0, 1, 1, 1]).tolist()}, "truth.T_base_cam.*rotation"),
])
def test_wrong_truth(session, truth, match):
    header = json.loads((session / "session.json").read_text())
    header["truth"] = truth
    (session / "session.json").write_text(json.dumps(header))
    with pytest.raises(SessionError, match=match):
        read_session(session)


@pytest.mark.timeout(20)
def test_fifo_named_samples_jsonl_is_refused_not_waited_on(session):
    (session / "samples.jsonl").unlink()
    os.mkfifo(session / "samples.jsonl")
    with pytest.raises(SessionError, match="not a regular file"):
        read_session(session)


def test_samples_jsonl_as_a_directory(session):
    (session / "samples.jsonl").unlink()
    (session / "samples.jsonl").mkdir()
    with pytest.raises(SessionError, match="is a directory"):
        read_session(session)


@pytest.mark.parametrize("name", ["../../../../../../../../etc/hostname", "/etc/hostname", "../outside.png"])
def test_frames_are_read_only_inside_the_session(session, name):
    (session.parent / "outside.png").write_bytes(b"x")
    recs = _lines(session)
    recs[0]["meta"]["color"] = name
    _write_lines(session, recs)
    s = read_session(session)
    with pytest.raises(SessionError, match="outside"):
        s.load_frames(s.observations[0])


def test_session_files_symlinked_out_are_refused(session, tmp_path):
    (tmp_path / "elsewhere.jsonl").write_text("")
    (session / "samples.jsonl").unlink()
    (session / "samples.jsonl").symlink_to(tmp_path / "elsewhere.jsonl")
    with pytest.raises(SessionError, match="outside"):
        read_session(session)


FRAME_NAMES = st.sampled_from(["../outside.png", "/etc/hostname", "../../../../../../../../etc/hostname", "..", ".",
                               "frames", "samples.jsonl", "session.json", "frames/000000_color.png"]) \
    | st.text(max_size=8)


@SETTINGS
@given(line=st.integers(0, 7), key=st.sampled_from(["color", "depth"]), name=FRAME_NAMES,
       junk=st.binary(max_size=40), pos=st.integers(0, 4000))
def test_damaged_sessions_never_read_outside(seed_session, tmp_path, outside_reads, line, key, name, junk, pos):
    """Any frame name on any line, then bytes of junk: reading the session and every frame
    gives a result or a SessionError, and opens nothing outside the session directory."""
    session = tmp_path / "case" / "s"  # a fresh copy per example (hypothesis reuses tmp_path)
    shutil.rmtree(session.parent, ignore_errors=True)
    shutil.copytree(seed_session, session)
    (session.parent / "outside.png").write_bytes(b"x")
    recs = _lines(session)
    recs[line].setdefault("meta", {})[key] = name
    _write_lines(session, recs)
    data = (session / "samples.jsonl").read_bytes()
    (session / "samples.jsonl").write_bytes(data[:pos] + junk + data[pos:])
    with outside_reads.watch(session):
        s = _read_or_session_error(session)
        for obs in s.observations if s else []:
            try:
                s.load_frames(obs)
            except SessionError as e:
                assert "samples.jsonl" in str(e), str(e)


@pytest.mark.parametrize("name", [".", "frames"])
def test_a_frame_name_that_is_a_directory_names_the_sample(session, name):
    recs = _lines(session)
    recs[0]["meta"]["color"] = name
    _write_lines(session, recs)
    s = read_session(session)
    with pytest.raises(SessionError, match=r"samples\.jsonl sample 0: color: .*is a directory"):
        s.load_frames(s.observations[0])


@pytest.mark.parametrize("name,match", [("frames" + "[" * 3000, "too long for a file name"),
                                        ("loop.png", "symlink loop")])
def test_frame_names_the_os_refuses_are_session_errors(session, name, match):
    """Found by the fuzz campaign (3,000 brackets in a line: OSError ENAMETOOLONG; a loop: RuntimeError)."""
    (session / "loop.png").symlink_to(session / "loop2.png")
    (session / "loop2.png").symlink_to(session / "loop.png")
    recs = _lines(session)
    recs[0]["meta"]["color"] = name
    _write_lines(session, recs)
    s = read_session(session)
    with pytest.raises(SessionError, match=match):
        s.load_frames(s.observations[0])
