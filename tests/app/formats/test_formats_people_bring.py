"""Round trips of the formats people bring (issue 13): ViSP pose files, an image folder,
OpenCV FileStorage YAML, MoveIt Calibration samples. Each test file is written here from
the format's documentation, read back by the importer, and solved."""

import csv
import json

import cv2
import numpy as np
import pytest

from handeye.app.cli import main
from handeye.app.errors import SessionError
from handeye.app.formats import detect_format, load
from handeye.app.formats.moveit import write_moveit
from handeye.app.formats.opencv_storage import write_opencv_storage
from handeye.app.formats.visp import write_visp
from handeye.calib import simulate
from handeye.calib import transforms as tf
from tests.app.verdict_status import printed_status


@pytest.fixture(scope="module")
def cell():
    """Eye-to-hand pose pairs with their truth (noise-free B, so a round trip is exact)."""
    return simulate.realistic_cell(12, np.random.default_rng(21))


def _same(imported, A, B):
    np.testing.assert_allclose(imported.A, A, atol=1e-9)
    np.testing.assert_allclose(imported.B, B, atol=1e-9)


def _replay_error_mm(path, setup, truth, capsys) -> float:
    rc = main(["replay", str(path), "--setup", setup, "-m", "YKronT'", "--verbose"])   # (the table)
    out = capsys.readouterr().out
    assert rc == printed_status(out), out
    row = next(line for line in out.splitlines() if line.startswith("| YKronT'"))
    xyz = np.array(row.split("|")[5].split(), dtype=float)
    return float(np.linalg.norm(xyz - truth[:3, 3] * 1e3))


def test_visp_pose_files(cell, tmp_path, capsys):
    d = write_visp(tmp_path / "visp", cell.A, cell.B_true)
    assert sorted(p.name for p in d.iterdir())[:2] == ["pose_cPo_1.yaml", "pose_cPo_10.yaml"]
    text = (d / "pose_fPe_1.yaml").read_text().splitlines()
    assert text[:3] == ["rows: 6", "cols: 1", "data:"] and len(text) == 9
    assert detect_format(d) == "visp"
    imported = load(d, setup="eye_to_hand")
    _same(imported, cell.A, cell.B_true)
    assert imported.setup == "eye_to_hand" and load(d).setup == "eye_in_hand"
    assert _replay_error_mm(d, "eye_to_hand", cell.Y, capsys) < 0.01
    (d / "pose_cPo_3.yaml").write_text("rows: 6\ncols: 1\ndata:\n  - [1]\n")
    with pytest.raises(SessionError, match="pose_cPo_3.yaml"):
        load(d)


def test_opencv_filestorage(cell, tmp_path, capsys):
    path = write_opencv_storage(tmp_path / "pairs.yaml", cell.A, cell.B_true, setup="eye_to_hand")
    assert path.read_text().startswith("%YAML:1.0")
    assert detect_format(path) == "opencv_storage"
    imported = load(path)
    _same(imported, cell.A, cell.B_true)
    assert imported.setup == "eye_to_hand"
    assert _replay_error_mm(path, "eye_to_hand", cell.Y, capsys) < 0.01
    # Rotation vectors instead of matrices, as calibrateHandEye accepts them too.
    fs = cv2.FileStorage(str(tmp_path / "rvec.yaml"), cv2.FILE_STORAGE_WRITE)
    for name, Ts in (("gripper2base", cell.A), ("target2cam", cell.B_true)):
        for part, get in (("R", lambda T: cv2.Rodrigues(T[:3, :3])[0]), ("t", lambda T: T[:3, 3:4].copy())):
            fs.startWriteStruct(f"{part}_{name}", cv2.FileNode_SEQ)
            for T in Ts:
                fs.write("", get(T))
            fs.endWriteStruct()
    fs.release()
    _same(load(tmp_path / "rvec.yaml"), cell.A, cell.B_true)
    bad = tmp_path / "bad.yaml"
    bad.write_text("%YAML:1.0\n---\nR_gripper2base: []\n")
    with pytest.raises(SessionError, match="t_gripper2base"):
        load(bad)


def test_moveit_calibration_samples(cell, tmp_path, capsys):
    path = write_moveit(tmp_path / "pose_samples.json", cell.A, cell.B_true)
    data = json.loads(path.read_text())
    assert len(data) == 12 and np.asarray(data[0]).shape == (2, 4, 4)
    assert detect_format(path) == "moveit_calibration"
    imported = load(path)
    _same(imported, cell.A, cell.B_true)
    assert imported.setup == "eye_to_hand"
    assert _replay_error_mm(path, "eye_to_hand", cell.Y, capsys) < 0.01
    path.write_text(json.dumps([[np.eye(4).tolist()]]))
    with pytest.raises(SessionError, match="sample 0"):
        load(path, format="moveit_calibration")


@pytest.mark.parametrize("poses_format", ["csv", "yaml", "json"])
def test_image_folder(tmp_path, capsys, poses_format):
    """Rendered images of the simulated cell's marker, a pose per image, the intrinsics: the
    importer measures each image (depth-lifted center) and replay recovers the camera."""
    from handeye.app.planning import random_pose
    from handeye.app.config import load_config
    from handeye.drivers.robot import ur_kinematics as kin
    from handeye.mocks.render.camera import RenderedCamera, RenderedCameraConfig

    cfg = load_config(None)
    cam_cfg = RenderedCameraConfig(setup="eye_to_hand", seed=5)
    T_start = kin.forward(np.array(cfg.robot.initial_q), "ur10")
    rng = np.random.default_rng(7)
    folder = tmp_path / "capture"
    folder.mkdir()
    pose = {"T": T_start}
    rows = []
    with RenderedCamera(cam_cfg, lambda: pose["T"]) as cam:
        K = cam.intrinsics.K
        for i in range(10):
            pose["T"] = random_pose(T_start, cfg.calibrate, rng)
            frame = cam.read()
            cv2.imwrite(str(folder / f"img_{i:03d}.png"), frame.color)
            depth = np.nan_to_num(frame.depth * 1e3).astype(np.uint16)
            cv2.imwrite(str(folder / f"depth_{i:03d}.png"), depth)
            xyz, q = tf.to_xyz_quat(pose["T"])
            rows.append({"image": f"img_{i:03d}.png", **dict(zip(("x", "y", "z", "qx", "qy", "qz", "qw"),
                                                                 map(float, [*xyz, *q]))),
                         "depth": f"depth_{i:03d}.png"})
    # ROS camera_info style intrinsics (what `ros2 topic echo --once .../camera_info` gives).
    (folder / "intrinsics.yaml").write_text(
        f"image_width: 640\nimage_height: 480\ncamera_matrix:\n  rows: 3\n  cols: 3\n  data: {K.reshape(-1).tolist()}\n"
        "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [0, 0, 0, 0, 0]\n")
    if poses_format == "csv":
        with open(folder / "poses.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    elif poses_format == "yaml":
        import yaml

        # No depth column: the marker pose comes from PnP alone.
        rows = [{k: v for k, v in r.items() if k != "depth"} for r in rows]
        (folder / "poses.yaml").write_text(yaml.safe_dump({"setup": "eye_to_hand", "poses": rows}))
    else:
        (folder / "poses.json").write_text(json.dumps(rows))
    assert detect_format(folder) == "image_folder"
    imported = load(folder)
    assert len(imported.observations) >= 9 and imported.setup == "eye_to_hand"
    T_true = np.array(cam_cfg.T_base_cam)
    for o in imported.observations:
        np.testing.assert_allclose(o.T_base_flange, tf.from_xyz_quat(
            [rows[int(o.t)][k] for k in "xyz"], [rows[int(o.t)][k] for k in ("qx", "qy", "qz", "qw")]), atol=1e-9)
    # A 5 cm marker's PnP range is far noisier than depth: 10 views give about 1 cm without depth.
    assert _replay_error_mm(folder, "eye_to_hand", T_true, capsys) < (25.0 if poses_format == "yaml" else 5.0)
    if poses_format == "csv":
        # replay --out writes the image folder's result and every export, as calibrate does.
        from tests.app.test_replay_out import check_outputs

        assert main(["replay", str(folder), "--out", str(tmp_path / "out")]) == 0
        check_outputs(tmp_path / "out", capsys)
