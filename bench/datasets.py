"""The real recordings the benchmarks measure on, read from their upstream copies.

The folder (``industrial_calibration/``, ``ethz_hand_eye/``, licenses there)
is ``$HANDEYE_DATASETS``, else the nearest ``shared/datasets`` above the
repository (``../shared/datasets`` for a plain checkout).
The suite's trimmed copies in ``tests/data`` are for tests only. The ETH
pose streams come without a manifest: `real_sets` stages each pair with its
``streams.toml`` in a work folder, because a manifest may only name files
beside it.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from pathlib import Path

from handeye.app.formats import load
from handeye.app.formats.common import ImportedSamples


def datasets_dir() -> Path:
    """Where the shared real recordings are (may not exist on a fresh machine)."""
    env = os.environ.get("HANDEYE_DATASETS")
    if env:
        return Path(env)
    # The nearest ``shared/datasets`` above the checkout, so a git worktree nested deeper finds it too.
    beside = [p / "shared" / "datasets" for p in Path(__file__).resolve().parents[2:]]
    return next((d for d in beside if d.is_dir()), beside[0])


#: ETH pose-stream pairs: (name, folder, robot CSV, camera CSV). Both eye-in-hand; the camera
#: stream holds T_marker_cam (ethz-asl/hand_eye_calibration, datasets/).
ETH_STREAMS = [
    ("ETH robot_arm SR300 (eye-in-hand)", "robot_arm",
     "robot_arm_complete_bag_color_and_ir_base_link_sr300_hinge.csv",
     "robot_arm_complete_bag_color_and_ir_target_ir.csv"),
    ("ETH robot_arm simulated", "robot_arm_w_color_camera_sim", "robot_arm_sim_hand.csv", "robot_arm_sim_camera.csv"),
    ("ETH prime_sense_1 Vicon", "prime_sense_1", "2017-04-09-18-13-10_vicon_prime_sense.csv",
     "2017-04-09-18-13-10_W_camera_rgb_image_raw.csv"),
]


def real_sets(work: Path, root: Path | None = None) -> Iterator[tuple[str, ImportedSamples]]:
    """``(name, samples)`` of every real set found under ``root`` (default `datasets_dir`).

    Sets that are missing are left out; ``work`` receives the staged ETH streams.
    """
    root = datasets_dir() if root is None else Path(root)
    ind = root / "industrial_calibration"
    for name, path in [("industrial_calibration ChArUco (eye-to-hand)", ind / "test_set_charuco" / "cal_data.yaml"),
                       ("industrial_calibration 10x10 circles (eye-in-hand)", ind / "test_set_10x10")]:
        if path.exists():
            yield name, load(path)
    for name, folder, robot, camera in ETH_STREAMS:
        src = root / "ethz_hand_eye" / folder
        if not (src / robot).exists() or not (src / camera).exists():
            continue
        stage = Path(work) / folder
        stage.mkdir(parents=True, exist_ok=True)
        shutil.copy(src / robot, stage / robot)
        shutil.copy(src / camera, stage / camera)
        (stage / "streams.toml").write_text(f'format = "pose_csv"\nsetup = "eye_in_hand"\nrobot = "{robot}"\n'
                                            f'camera = "{camera}"\ncamera_transform = "T_marker_cam"\n')
        yield name, load(stage)
