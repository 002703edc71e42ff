import json

import numpy as np
import pytest

from handeye.app.session import FORMAT_NAME, SessionWriter, read_session
from handeye.calib import transforms as tf
from handeye.app.errors import SessionError
from handeye.calib.observation import Observation


def _obs(rng, i=0, with_pose=True):
    T = tf.make_transform(tf.random_rotations(1, 1.0, rng)[0], rng.normal(size=3))
    B = tf.make_transform(tf.random_rotations(1, 1.0, rng)[0], rng.normal(size=3))
    return Observation(i, 100.0 + i, T, B[:3, 3], np.eye(3) * 1e-6, B if with_pose else None,
                       np.eye(6) * 1e-4 if with_pose else None, {"note": "x"})


def test_roundtrip_with_frames(tmp_path):
    rng = np.random.default_rng(0)
    color = rng.integers(0, 255, size=(12, 16, 3), dtype=np.uint8)
    depth = rng.uniform(0.3, 2.0, size=(12, 16)).astype(np.float32)
    with SessionWriter.create(tmp_path, "eye_in_hand", config={"a": 1}, truth={"T_flange_cam": np.eye(4)}) as w:
        written = [w.add_sample(_obs(rng, i), color=color, depth=depth) for i in range(3)]
        w.add_skip(5.0, "marker not found", T_base_flange=np.eye(4))
        w.add_event(6.0, "alarm", shift_mm=3.0)
    s = read_session(w.path)
    assert s.setup == "eye_in_hand" and s.header["format"] == FORMAT_NAME
    assert s.header["frames"]["X"] == "T_flange_cam"
    np.testing.assert_array_equal(s.truth["T_flange_cam"], np.eye(4))
    assert [o.index for o in s.observations] == [0, 1, 2]
    for a, b in zip(written, s.observations):
        np.testing.assert_array_equal(a.T_base_flange, b.T_base_flange)
        np.testing.assert_array_equal(a.T_cam_marker, b.T_cam_marker)
        np.testing.assert_array_equal(a.point_cov, b.point_cov)
    assert s.skipped[0]["reason"] == "marker not found" and s.skipped[0]["index"] == 3
    assert s.events[0]["event"] == "alarm"
    c, d = s.load_frames(s.observations[1])
    np.testing.assert_array_equal(c, color)
    np.testing.assert_allclose(d, depth, atol=0.0006)  # 16-bit mm quantisation


def test_points_only_session_written_by_hand(tmp_path):
    """Another program can write a session with just poses and points (docs/session-format.md)."""
    (tmp_path / "session.json").write_text(json.dumps({"format": "handeye-session", "version": 1,
                                                       "setup": "eye_to_hand"}))
    line = {"kind": "sample", "index": 0, "t": 1.0, "T_base_flange": np.eye(4).tolist(), "point_cam": [0, 0, 1]}
    (tmp_path / "samples.jsonl").write_text(json.dumps(line) + "\n")
    s = read_session(tmp_path)
    assert len(s.observations) == 1 and s.observations[0].T_cam_marker is None


def test_torn_last_line_ignored_and_resume_continues(tmp_path, caplog):
    rng = np.random.default_rng(1)
    with SessionWriter.create(tmp_path, "eye_to_hand") as w:
        w.add_sample(_obs(rng))
        w.add_sample(_obs(rng))
    with open(w.path / "samples.jsonl", "a") as f:
        f.write('{"kind": "sample", "index": 2, "T_base')
    s = read_session(w.path)
    assert len(s.observations) == 2
    assert "torn last line" in caplog.text
    with SessionWriter.resume(w.path) as w2:
        assert w2.next_index == 2
        w2.add_sample(_obs(rng))
    assert [o.index for o in read_session(w.path).observations] == [0, 1, 2]


@pytest.mark.parametrize("header, match", [
    ({"format": "other", "version": 1, "setup": "eye_to_hand"}, "format"),
    ({"format": "handeye-session", "version": 99, "setup": "eye_to_hand"}, "version"),
    ({"format": "handeye-session", "version": 1, "setup": "sideways"}, "setup"),
])
def test_bad_header(tmp_path, header, match):
    (tmp_path / "session.json").write_text(json.dumps(header))
    with pytest.raises(SessionError, match=match):
        read_session(tmp_path)


def test_missing_session_and_bad_lines(tmp_path):
    with pytest.raises(SessionError, match="no session.json"):
        read_session(tmp_path / "nope")
    (tmp_path / "session.json").write_text(json.dumps({"format": "handeye-session", "version": 1,
                                                       "setup": "eye_to_hand"}))
    (tmp_path / "samples.jsonl").write_text('{"kind": "sample", "index": 0, "t": 1, "T_base_flange": [[1]]}\n')
    with pytest.raises(SessionError, match="line 1: T_base_flange must have shape"):
        read_session(tmp_path)
    (tmp_path / "samples.jsonl").write_text('garbage\n{"kind": "event", "t": 1, "event": "x"}\n')
    with pytest.raises(SessionError, match="line 1: invalid JSON"):
        read_session(tmp_path)


def test_interrupted_is_how_the_calibrations_last_run_ended(tmp_path):
    """`Session.interrupted`: the last of a calibration's interrupted/stopped events is an interruption (a
    resumed run that ended normally clears it); a monitor's Ctrl-C is its normal end."""
    def ends(events, source="handeye"):
        with SessionWriter.create(tmp_path, "eye_to_hand", source=source) as w:
            for i, (event, fields) in enumerate(events):
                w.add_event(float(i), event, **fields)
        return read_session(w.path).interrupted

    assert not ends([])
    assert ends([("interrupted", {"n_samples": 6})])
    assert not ends([("interrupted", {"n_samples": 6}), ("stopped", {"stopped_by": "samples"})])
    assert ends([("stopped", {"stopped_by": "samples"}), ("interrupted", {"stage": "final solve"}),
                 ("alarm", {})])
    assert not ends([("interrupted", {"n_samples": 6})], source="handeye monitor")
