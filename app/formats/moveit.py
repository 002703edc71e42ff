"""Importer for MoveIt Calibration's pose-sample files (JSON).

MoveIt Calibration (``moveit_calibration``, the RViz hand-eye plugin) solves
from two lists its solver plugins take as ``solve(effector_wrt_world,
object_wrt_sensor, setup)``: the end-effector pose in the robot base (world)
frame and the calibration object's pose in the sensor (camera) frame, each a
4x4 homogeneous matrix. Its sample files (e.g. the solver tests'
``pose_samples.json``) store them as a JSON list of pairs, one per robot pose::

    [
      [ [[r00, r01, r02, tx], [.., ty], [.., tz], [0, 0, 0, 1]],     # effector_wrt_world = T_base_flange
        [[r00, r01, r02, tx], [.., ty], [.., tz], [0, 0, 0, 1]] ],   # object_wrt_sensor  = T_cam_marker
      ...
    ]

Metres. Unlike easy_handeye, the effector pose is ``T_base_flange`` in both
setups. The file does not name the setup: ``setup=`` option, default
eye-to-hand (MoveIt's ``SensorMountType`` default). `write_moveit` writes this layout.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from handeye.app.errors import SessionError
from handeye.app.files import read_text_file
from handeye.calib.setup import Setup, check_setup

from handeye.app.formats.common import ImportedSamples, observations_from_poses
from handeye.app.formats.registry import register_import


def looks_like_moveit(data) -> bool:
    """A list of [4x4, 4x4] pairs."""
    try:
        return isinstance(data, list) and len(data) > 0 and np.asarray(data[0], dtype=float).shape == (2, 4, 4)
    except (TypeError, ValueError):
        return False


def _detect(path: Path, document) -> bool:
    # JSON is YAML: the registry's parsed document serves.
    return Path(path).suffix == ".json" and Path(path).is_file() and looks_like_moveit(document())


@register_import("moveit_calibration", _detect, open_setup=True)
def load_moveit(path, setup: str | None = None) -> ImportedSamples:
    """Read a MoveIt Calibration pose-sample JSON file (see the module docstring)."""
    path = Path(path)
    try:
        data = json.loads(read_text_file(path, SessionError))
    except (ValueError, RecursionError) as e:  # JSONDecodeError is a ValueError
        raise SessionError(f"{path}: cannot read JSON ({str(e)[:200]})") from None
    if not isinstance(data, list) or not data:
        raise SessionError(f"{path}: expected a non-empty list of [effector_wrt_world, object_wrt_sensor] pairs")
    pairs = []
    for i, pair in enumerate(data):
        try:
            p = np.asarray(pair, dtype=float)
        except (TypeError, ValueError):
            p = np.zeros(0)
        if p.shape != (2, 4, 4):
            raise SessionError(f"{path}: sample {i} must be a pair of 4x4 matrices, got shape {p.shape}")
        pairs.append(p)
    pairs = np.array(pairs)
    setup = Setup.EYE_TO_HAND if setup is None else check_setup(setup, error=SessionError)
    return ImportedSamples(observations_from_poses(pairs[:, 0], pairs[:, 1], source=path), setup,
                           {"format": "moveit_calibration", "source": str(path), "time": "sample index",
                            "frames": {"base": "world", "flange": "effector", "camera": "sensor", "marker": "object"}})


def write_moveit(path, T_base_flange: np.ndarray, T_cam_marker: np.ndarray) -> Path:
    """Write pose pairs as a MoveIt Calibration sample file."""
    path = Path(path)
    path.write_text(json.dumps([[np.asarray(A).tolist(), np.asarray(B).tolist()]
                                for A, B in zip(T_base_flange, T_cam_marker)]))
    return path
