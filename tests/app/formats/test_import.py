"""Importers: easy_handeye (ROS 1), easy_handeye2 (ROS 2), pose-stream CSV; format detection; bad input."""

import numpy as np
import pytest
import yaml

from handeye.app.formats import detect_format, load
from handeye.app.formats.pose_csv import read_pose_csv
from handeye.calib import simulate
from handeye.calib import transforms as tf
from handeye.calib.api import solve
from handeye.app.errors import ConfigError, SessionError


def _msg(T):
    t, q = tf.to_xyz_quat(T)
    return {"translation": dict(zip("xyz", map(float, t))), "rotation": dict(zip("xyzw", map(float, q)))}


def _robot_as_stored(data):
    # Both tools store T_effector_base for eye-on-base (they invert it for their solver).
    return data.A if data.setup == "eye_in_hand" else tf.invert(data.A)


@pytest.fixture(params=["eye_to_hand", "eye_in_hand"])
def data(request):
    return simulate.realistic_cell(12, np.random.default_rng(2), setup=request.param, pose_noise=(0.0, 0.0),
                                   sigma_lateral=1e-9, sigma_depth=1e-9)


def _assert_same_samples(imp, data):
    assert len(imp.observations) == len(data.A)
    np.testing.assert_allclose(imp.A, data.A, atol=1e-9)
    np.testing.assert_allclose(imp.B, data.B, atol=1e-9)
    np.testing.assert_allclose([o.point_cam for o in imp.observations], data.B[:, :3, 3], atol=1e-12)
    res = solve("YKronRT", imp.A, imp.B, setup=imp.setup)
    rot, trans = tf.pose_error(res.camera_transform, data.Y if data.setup == "eye_to_hand" else data.X)
    assert trans < 1e-6 and rot < 1e-6


def test_easy_handeye2_samples(data, tmp_path):
    kind = "eye_in_hand" if data.setup == "eye_in_hand" else "eye_on_base"
    doc = {"parameters": {"name": "cell", "calibration_type": kind, "robot_base_frame": "panda_link0",
                          "robot_effector_frame": "panda_link8", "tracking_base_frame": "cam",
                          "tracking_marker_frame": "tag"},
           "samples": [{"robot": _msg(R), "tracking": _msg(B)} for R, B in zip(_robot_as_stored(data), data.B)]}
    path = tmp_path / "cell.samples"
    path.write_text(yaml.safe_dump(doc))
    assert detect_format(path) == "easy_handeye2"
    imp = load(path)
    assert imp.setup == data.setup
    assert imp.meta["frames"] == {"base": "panda_link0", "flange": "panda_link8", "camera": "cam", "marker": "tag"}
    _assert_same_samples(imp, data)


def test_easy_handeye2_setup_from_calib_file_or_argument(data, tmp_path):
    kind = "eye_in_hand" if data.setup == "eye_in_hand" else "eye_on_base"
    # easy_handeye2's own sample files leave the parameters empty.
    doc = {"parameters": {"name": "", "calibration_type": ""},
           "samples": [{"robot": _msg(R), "tracking": _msg(B)} for R, B in zip(_robot_as_stored(data), data.B)]}
    path = tmp_path / "demo.samples"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(SessionError, match="pass setup="):
        load(path)
    _assert_same_samples(load(path, setup=data.setup), data)
    (tmp_path / "demo.calib").write_text(yaml.safe_dump({"parameters": {"calibration_type": kind}}))
    assert load(path).setup == data.setup


def test_easy_handeye_ros1_sample_list(data, tmp_path):
    doc = {"parameters": {"eye_on_hand": data.setup == "eye_in_hand", "robot_base_frame": "base_link"},
           "samples": {"hand_world_samples": [_msg(R) for R in _robot_as_stored(data)],
                       "camera_marker_samples": [_msg(B) for B in data.B]}}
    path = tmp_path / "samples.yaml"
    path.write_text(yaml.safe_dump(doc))
    assert detect_format(path) == "easy_handeye"
    imp = load(path)
    assert imp.setup == data.setup and imp.meta["frames"]["base"] == "base_link"
    _assert_same_samples(imp, data)


def test_easy_handeye_robot_optical_pairs(data, tmp_path):
    pairs = [{"robot": {"transform": _msg(R)}, "optical": {"transform": _msg(B)}}
             for R, B in zip(_robot_as_stored(data), data.B)]
    path = tmp_path / "pairs.yaml"
    path.write_text(yaml.safe_dump(pairs))
    assert detect_format(path) == "easy_handeye"
    _assert_same_samples(load(path, setup=data.setup), data)


def test_bad_samples_are_named(tmp_path):
    good = _msg(np.eye(4))
    nan = {"translation": {"x": float("nan"), "y": 0.0, "z": 0.0}, "rotation": good["rotation"]}
    doc = {"parameters": {"calibration_type": "eye_in_hand"}, "samples": [{"robot": good, "tracking": good},
                                                                          {"robot": nan, "tracking": good}]}
    path = tmp_path / "bad.samples"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(SessionError, match="sample 1 robot: NaN"):
        load(path)
    doc["samples"][1]["robot"] = {"translation": good["translation"], "rotation": {"x": 0.5, "y": 0, "z": 0, "w": 0.5}}
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(SessionError, match="quaternion norm"):
        load(path)
    doc["samples"][1] = {"robot": good}
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(SessionError, match="sample 1 needs"):
        load(path)
    (tmp_path / "x.yaml").write_text("just: text\n")
    with pytest.raises(SessionError, match="not a known sample format"):
        load(tmp_path / "x.yaml")


# --- pose-stream CSV -------------------------------------------------------

def _write_csv(path, t, T, *, header=True):
    xyz, q = tf.to_xyz_quat(T)
    rows = np.column_stack([t, xyz, q])
    path.write_text(("# t, x, y, z, qx, qy, qz, qw\n" if header else "")
                    + "\n".join(", ".join(f"{v:.12g}" for v in r) for r in rows) + "\n")


def _streams(rng, offset):
    """Eye-in-hand hand (50 Hz) and target->camera (30 Hz, stamped ``offset`` s early) streams, and X."""
    X = tf.make_transform(tf.random_rotations(1, 1.0, rng)[0], [0.03, -0.05, 0.08])   # T_flange_cam
    Y = tf.make_transform(np.eye(3), [0.9, 0.0, 0.0])                                  # T_base_marker
    f = rng.uniform(0.2, 0.6, size=(3, 2))

    def A_at(t):
        rv = 0.5 * np.sin(2 * np.pi * np.outer(t, f[:, 0]))
        return tf.from_rotvec_translation(rv, [0.4, 0.0, 0.5] + 0.15 * np.sin(2 * np.pi * np.outer(t, f[:, 1])))

    t_a = np.arange(0.0, 20.0, 0.02)
    t_b = np.arange(0.01, 20.0, 1 / 30)
    T_marker_cam = tf.invert(tf.invert(A_at(t_b) @ X) @ Y)
    return t_a, A_at(t_a), t_b - offset, T_marker_cam, X


def test_pose_streams_offset_estimated_and_reported(tmp_path):
    rng = np.random.default_rng(4)
    t_a, A, t_b, T_marker_cam, X = _streams(rng, 0.08)
    _write_csv(tmp_path / "hand.csv", t_a, A)
    # Repeated rows (as in the ETH simulated hand stream) are dropped, not fatal.
    _write_csv(tmp_path / "target.csv", np.r_[t_b, t_b[:5]], np.r_[T_marker_cam, T_marker_cam[:5]], header=False)
    (tmp_path / "streams.toml").write_text(
        'setup = "eye_in_hand"\nrobot = "hand.csv"\ncamera = "target.csv"\ncamera_transform = "T_marker_cam"\n'
        "max_offset = 0.5\n")
    assert detect_format(tmp_path) == "pose_csv"
    imp = load(tmp_path)
    assert imp.setup == "eye_in_hand"
    assert imp.meta["clock_offset_xcorr_s"] == pytest.approx(0.08, abs=0.01)
    assert imp.meta["clock_offset_s"] == pytest.approx(0.08, abs=2e-3)
    assert imp.meta["n_camera_rows"] == len(t_b)
    res = solve("YKronT'", imp.A, [o.point_cam for o in imp.observations], setup="eye_in_hand")
    # Noise-free streams: only interpolation error remains once paired at the right offset.
    assert res.residuals.rms_translation < 5e-4
    assert np.linalg.norm(res.X[:3, 3] - X[:3, 3]) < 2e-3
    thinned = load(tmp_path, stride=4, refine=False)
    assert len(thinned.observations) == -(-thinned.meta["n_paired"] // 4)    # every 4th paired sample
    # A fixed offset skips estimation; a wrong one shows in the residual.
    wrong = load(tmp_path, clock_offset=0.0)
    assert "clock_offset_xcorr_s" not in wrong.meta and wrong.meta["clock_offset_s"] == 0.0
    res0 = solve("YKronT'", wrong.A, [o.point_cam for o in wrong.observations], setup="eye_in_hand")
    assert res0.residuals.rms_translation > 5 * res.residuals.rms_translation
    with pytest.raises(SessionError, match="no camera sample overlaps"):
        load(tmp_path, clock_offset=1000.0)


def test_pose_csv_separators(tmp_path):
    T = tf.from_xyz_quat([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]], [[0, 0, 0, 1], [0, 0, np.sin(0.1), np.cos(0.1)]])
    (tmp_path / "tum.txt").write_text("# timestamp tx ty tz qx qy qz qw\n"
                                      "1.0 0.1 0.2 0.3 0 0 0 1\n2.0\t0.4 0.5 0.6 0 0 %r %r\n" % (float(np.sin(0.1)), float(np.cos(0.1))))
    (tmp_path / "semi.csv").write_text("t;x;y;z;qx;qy;qz;qw\n1.0; 0.1; 0.2; 0.3; 0; 0; 0; 1\n"
                                       "2.0; 0.4; 0.5; 0.6; 0; 0; %r; %r\n" % (float(np.sin(0.1)), float(np.cos(0.1))))
    for name in ("tum.txt", "semi.csv"):
        t, T_read = read_pose_csv(tmp_path / name)
        np.testing.assert_allclose(t, [1.0, 2.0])
        np.testing.assert_allclose(T_read, T, atol=1e-12)


def test_pose_csv_errors_name_line_and_field(tmp_path):
    (tmp_path / "short.csv").write_text("0, 0, 0, 0, 0, 0, 1\n1, 0, 0, 0, 0, 0, 0, 1\n")
    with pytest.raises(SessionError, match=r"short.csv:1: expected 8 columns"):
        read_pose_csv(tmp_path / "short.csv")
    (tmp_path / "q.csv").write_text("0, 0, 0, 0, 0, 0, 0, 1\n1, 0, 0, 0, 0, 0, 0, 2\n")
    with pytest.raises(SessionError, match=r"q.csv:2: quaternion norm"):
        read_pose_csv(tmp_path / "q.csv")
    (tmp_path / "m.toml").write_text('setup = "eye_in_hand"\nrobot = "a.csv"\ncamera = "b.csv"\n'
                                     'camera_transform = "T_camera_marker"\n')
    with pytest.raises(ConfigError, match="camera_transform"):
        load(tmp_path / "m.toml")
    (tmp_path / "m.toml").write_text('setup = "eye_in_hand"\nrobot = "a.csv"\ncamera = "b.csv"\nmax_gap = -1\n')
    with pytest.raises(ConfigError, match="max_gap"):
        load(tmp_path / "m.toml")
