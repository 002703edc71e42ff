"""ROS 2 bags (rosbag2, sqlite3 and MCAP) of the rendered demo, written by rosbags, imported by handeye.

The bags are written here from the simulator and renderer (`handeye.mocks.ros2_bag`), with the equivalent
session beside them: the frame a live run takes at each stop, its exact flange pose and pixels.
"""

import os
import shutil

import numpy as np
import pytest

pytest.importorskip("rosbags")

from handeye.app.cli import main  # noqa: E402
from handeye.app.errors import SessionError  # noqa: E402
from handeye.app.formats import detect_format, load  # noqa: E402
from handeye.app.formats import ros2_bag  # noqa: E402
from handeye.calib import transforms as tf  # noqa: E402
from handeye.calib.api import solve_observations  # noqa: E402
from handeye.calib.observation import Observation  # noqa: E402
from handeye.calib.vision.extract import TargetConfig, extract  # noqa: E402
from handeye.mocks.ros2_bag import T_BASE_LINK_BASE, T_WRIST3_FLANGE, session_frames, write_demo_bag  # noqa: E402

N_POSES = 12


def _session(bag):
    """What a live run measured at each stop: the app's extraction on the frame, the exact flange pose."""
    target = TargetConfig()
    taken = session_frames(bag, lambda c: extract(c.color, c.depth, bag.intrinsics, target))
    return [c for c, _ in taken], [Observation.from_measurement(i, c.t, c.T_base_flange, m)
                                   for i, (c, m) in enumerate(taken)]


def _session_observations(bag) -> list[Observation]:
    return _session(bag)[1]


def _messages(bag) -> list[int]:
    return [c.message for c in _session(bag)[0]]


def _agreement_mm(a, b, method):
    ra = solve_observations(method, a, "eye_to_hand")
    rb = solve_observations(method, b, "eye_to_hand")
    rot, trans = tf.pose_error(ra.camera_transform, rb.camera_transform)
    return trans * 1e3, np.rad2deg(rot), ra


@pytest.fixture(scope="module", params=["mcap", "sqlite3"])
def demo_bag(request, tmp_path_factory):
    path = tmp_path_factory.mktemp(request.param) / "demo_bag"
    return write_demo_bag(path, storage=request.param, n_poses=N_POSES, fps=10, render_moving=False)


def test_bag_replays_to_the_sessions_calibration(demo_bag):
    assert detect_format(demo_bag.path) == "ros2_bag"
    imported = load(demo_bag.path)
    assert imported.meta["storage"] == ("db3" if (demo_bag.path / "demo_bag.db3").exists() else "mcap")
    # One sample per stop, from the frame the live run took, at the flange pose of the stop.
    assert [o.meta["message"] for o in imported.observations] == _messages(demo_bag)
    for o, s in zip(imported.observations, _session(demo_bag)[0]):
        np.testing.assert_allclose(o.T_base_flange, s.T_base_flange, atol=1e-9)
    counts = imported.meta["frames_read"]
    assert counts["standstills"] == N_POSES and counts["moving_or_no_tf"] > 0
    session = _session_observations(demo_bag)
    for method in ("YKronT'", "YQuatT'"):
        mm, deg, res = _agreement_mm(imported.observations, session, method)
        assert mm < 0.1 and deg < 0.01, (method, mm, deg)
    # And the calibration is a calibration: near the rendered truth.
    rot, trans = tf.pose_error(res.camera_transform, demo_bag.truth["T_base_cam"])
    assert trans < 5e-3 and np.rad2deg(rot) < 0.5


def test_float_depth_compressed_colour_and_a_given_clock_offset(tmp_path):
    bag = write_demo_bag(tmp_path / "bag", storage="sqlite3", n_poses=8, fps=10, render_moving=False,
                         depth_encoding="32FC1", compressed=True, camera_clock_offset_s=0.2)
    imported = load(bag.path, clock_offset_s=0.2)
    assert imported.meta["clock_offset_s"] == 0.2 and imported.meta["clock_offset_from"] == "given"
    assert [o.meta["message"] for o in imported.observations] == _messages(bag)
    mm, deg, _ = _agreement_mm(imported.observations, _session_observations(bag), "YKronT'")
    assert mm < 0.1, mm
    # Without the offset, the 0.2 s lag puts frames of the motion's start into the standstills.
    shifted = load(bag.path, clock_offset_s=0.0)
    assert [o.meta["message"] for o in shifted.observations] != _messages(bag)


def test_clock_offset_estimated_from_the_marker_pose_topic(tmp_path):
    bag = write_demo_bag(tmp_path / "bag", storage="mcap", n_poses=6, fps=10, marker_topic=True,
                         camera_clock_offset_s=0.05)
    imported = load(bag.path)
    assert imported.meta["clock_offset_from"] == "marker-pose speeds"
    assert abs(imported.meta["clock_offset_s"] - 0.05) < 0.005, imported.meta["clock_offset_s"]
    assert [o.meta["message"] for o in imported.observations] == _messages(bag)


def test_marker_poses_alone_are_the_measurements(tmp_path):
    bag = write_demo_bag(tmp_path / "bag", storage="mcap", n_poses=6, fps=10, marker_topic=True,
                         render_moving=False)
    # A bag of tf and a detector's poses only.
    only = _copy_topics(bag.path, tmp_path / "poses_only", lambda topic: topic in ("/tf", "/tf_static",
                                                                                  "/marker_pose"))
    imported = load(only)
    assert imported.meta["topics"] == {"marker": "/marker_pose"}
    first = [c for c in bag.candidates if c.attempt == 0]  # a pose per stop: nothing to retry
    assert [o.meta["message"] for o in imported.observations] == [c.message for c in first]
    for o, s in zip(imported.observations, first):
        np.testing.assert_allclose(o.T_base_flange, s.T_base_flange, atol=1e-9)
        B = tf.invert(bag.truth["T_base_cam"]) @ s.T_base_flange @ np.asarray(_marker_mount(), float)
        np.testing.assert_allclose(o.T_cam_marker, B, atol=1e-6)


def _copy_topics(src, dst, keep):
    """A new MCAP bag with the topics of ``src`` that ``keep(topic)`` accepts (a ``ros2 bag convert`` filter)."""
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(src) as r, Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {c.id: w.add_connection(c.topic, c.msgtype, typestore=ts) for c in r.connections if keep(c.topic)}
        for c, t, raw in r.messages(connections=[c for c in r.connections if c.id in conns]):
            w.write(conns[c.id], t, raw)
    return dst


def _marker_mount():
    from handeye.mocks.render.camera import RenderedCameraConfig

    return RenderedCameraConfig().T_flange_marker


def test_frames_are_chosen_along_the_tf_tree(demo_bag):
    imported = load(demo_bag.path, frames={"base": "base_link", "flange": "wrist_3_link"})
    for o, s in zip(imported.observations, _session(demo_bag)[0]):
        np.testing.assert_allclose(o.T_base_flange, T_BASE_LINK_BASE @ s.T_base_flange @ tf.invert(T_WRIST3_FLANGE),
                                   atol=1e-9)
    assert imported.meta["frames"]["camera"] == "camera_color_optical_frame"
    with pytest.raises(SessionError, match=r"frame 'tool0' \(flange\) is not in /tf.*wrist_3_link"):
        load(demo_bag.path, frames={"flange": "tool0"})


def test_replay_cli_takes_frames_and_the_configs_marker(demo_bag, tmp_path, capsys):
    cfg = tmp_path / "cell.toml"
    cfg.write_text('[frames]\nbase = "base_link"\n[marker]\nmarker_size = 0.05\n')
    rc = main(["replay", str(demo_bag.path), "-c", str(cfg), "--frames", "flange=wrist_3_link"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert f"{N_POSES} samples" in out and "auto" in out          # replay solves with auto, as calibrate
    # A frame the bag does not have: one line naming it, exit 1.
    rc = main(["replay", str(demo_bag.path), "--frames", "flange=tool0"])
    out, err = capsys.readouterr()
    assert rc == 1 and "tool0" in err and len(err.strip().splitlines()) == 1


# ------------------------------------------------------------------------- damage


@pytest.fixture()
def small_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("small") / "bag"
    return write_demo_bag(path, storage="mcap", n_poses=3, fps=5, render_moving=False).path


def test_wrong_type_on_tf_names_the_topic(tmp_path):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Writer(tmp_path / "bag", version=9) as w:
        c = w.add_connection("/tf", "std_msgs/msg/String", typestore=ts)
        w.write(c, 1, ts.serialize_cdr(ts.types["std_msgs/msg/String"](data="x"), "std_msgs/msg/String"))
    with pytest.raises(SessionError, match="topic /tf has type std_msgs/msg/String, expected tf2_msgs/msg/TFMessage"):
        load(tmp_path / "bag")


def test_huge_message_names_topic_and_index(small_bag, monkeypatch):
    monkeypatch.setattr(ros2_bag, "MAX_MESSAGE_BYTES", 100_000)
    with pytest.raises(SessionError, match=r"/camera/\S+ message 0: \d+ bytes, above the 100000"):
        load(small_bag)


def test_truncated_storage_is_a_clean_error(small_bag):
    mcap = next(small_bag.glob("*.mcap"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])
    with pytest.raises(SessionError, match=str(small_bag)):
        load(small_bag)


def test_metadata_naming_a_file_outside_is_refused(small_bag, tmp_path):
    outside = tmp_path / "outside.mcap"
    shutil.copy(next(small_bag.glob("*.mcap")), outside)
    meta = small_bag / "metadata.yaml"
    text = meta.read_text()
    name = next(small_bag.glob("*.mcap")).name
    meta.write_text(text.replace(f"- {name}", f"- ../{outside.name}"))
    with pytest.raises(SessionError, match="points outside"):
        load(small_bag)


def test_a_fifo_as_bag_file_does_not_block(small_bag):
    mcap = next(small_bag.glob("*.mcap"))
    mcap.unlink()
    os.mkfifo(mcap)
    with pytest.raises(SessionError, match="not a regular file"):
        load(small_bag)


def test_no_camera_info_is_named(tmp_path):
    src = write_demo_bag(tmp_path / "src", storage="mcap", n_poses=2, fps=5, render_moving=False).path
    dst = _copy_topics(src, tmp_path / "no_info", lambda topic: "camera_info" not in topic)
    with pytest.raises(SessionError, match="no sensor_msgs/msg/CameraInfo for /camera/color/image_raw"):
        load(dst)


def test_parse_pairs_names_the_bad_part():
    assert ros2_bag.parse_pairs("base=base_link, flange=tool0", "--frames", ("base", "flange")) == \
        {"base": "base_link", "flange": "tool0"}
    from handeye.app.errors import ConfigError

    with pytest.raises(ConfigError, match="'tool=tool0' is not KEY=NAME"):
        ros2_bag.parse_pairs("tool=tool0", "--frames", ("base", "flange"))


def test_data_outside_the_bag_is_not_opened(small_bag, tmp_path):
    # Only metadata.yaml and the files it names, all inside the directory.
    import sys

    opened, watching = [], [True]

    def hook(event, args):  # audit hooks cannot be removed: this one stops recording after the load
        if watching and event == "open" and isinstance(args[0], (str, os.PathLike)):
            opened.append(os.path.realpath(os.fspath(args[0])))

    sys.addaudithook(hook)
    try:
        load(small_bag)
    finally:
        watching.clear()
    root = os.path.realpath(small_bag)
    mine = [p for p in opened if p.startswith(os.path.realpath(tmp_path.parent))]
    assert mine and all(p.startswith(root + os.sep) for p in mine), mine


def test_use_it_in_ros2_from_the_bag_to_a_launch_file(demo_bag, tmp_path):
    """docs/formats.md "Use it in ROS 2": the frames of the bag, the driver's camera_link, one launch file."""
    import ast

    from handeye.app.formats import write_result
    from handeye.mocks.ros2_bag import COLOR_FRAME, T_CAMERA_LINK_OPTICAL

    imported = load(demo_bag.path, frames={"base": "base_link", "flange": "flange"})
    assert imported.meta["frames"]["camera"] == COLOR_FRAME  # the image's optical frame
    cam_tf = imported.meta["camera_tf"]
    assert cam_tf["root"] == "camera_link" and cam_tf["frame"] == COLOR_FRAME
    np.testing.assert_allclose(cam_tf["T_root_camera"], T_CAMERA_LINK_OPTICAL, atol=1e-9)
    res = solve_observations("YKronT'", imported.observations, imported.setup)
    launch = write_result(res, tmp_path / "handeye_tf.launch.py", fmt="ros2_launch", frames=imported.meta["frames"],
                          camera_tf=cam_tf)
    call = next(n for n in ast.walk(ast.parse(launch.read_text())) if isinstance(n, ast.keyword)
                and n.arg == "arguments")
    args = [ast.literal_eval(e) for e in call.value.elts]
    kv = dict(zip(args[::2], args[1::2]))
    assert kv["--frame-id"] == "base_link" and kv["--child-frame-id"] == "camera_link"
    T_pub = tf.from_xyz_quat([float(kv[f"--{k}"]) for k in "xyz"], [float(kv[f"--q{k}"]) for k in "xyzw"])
    # camera_link as published, then the driver's camera_link -> optical frame: the true camera in base_link.
    truth = T_BASE_LINK_BASE @ demo_bag.truth["T_base_cam"]
    rot, trans = tf.pose_error(T_pub @ T_CAMERA_LINK_OPTICAL, truth)
    assert trans < 5e-3 and np.rad2deg(rot) < 0.5, (trans, np.rad2deg(rot))


def _with_copies(src, dst, extra):
    """``src`` rewritten to ``dst`` with each topic's messages also on the topics ``extra[topic]`` lists."""
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(src) as r, Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {c.id: [w.add_connection(t, c.msgtype, typestore=ts) for t in [c.topic, *extra.get(c.topic, [])]]
                 for c in r.connections}
        for c, t, raw in r.messages():
            for out in conns[c.id]:
                w.write(out, t, raw)
    return dst


def test_a_realsense_drivers_topics_are_told_apart(small_bag, tmp_path):
    """realsense2_camera records colour, infra, raw and aligned depth: the aligned depth and the colour
    are taken; two topics of a kind that no name tells apart need --topics."""
    dst = _with_copies(small_bag, tmp_path / "driver", {
        "/camera/color/image_raw": ["/camera/infra1/image_rect_raw"],
        "/camera/aligned_depth_to_color/image_raw": ["/camera/depth/image_rect_raw"]})
    imported = load(dst)
    assert imported.meta["topics"]["color"] == "/camera/color/image_raw"
    assert imported.meta["topics"]["depth"] == "/camera/aligned_depth_to_color/image_raw"
    two = _with_copies(small_bag, tmp_path / "two", {"/camera/color/image_raw": ["/left/color/image_raw"]})
    with pytest.raises(SessionError, match=r"several color topics \(/camera/color/image_raw, /left/color/image_raw\)"
                       r".*--topics color="):
        load(two)
    assert load(two, topics={"color": "/left/color/image_raw"}).meta["topics"]["color"] == "/left/color/image_raw"
