"""Importer for ViSP's hand-eye calibration data: ``pose_fPe_<i>.yaml`` + ``pose_cPo_<i>.yaml``.

ViSP's hand-eye apps (``visp-acquire-*-calib-data``, ``visp-compute-eye-in-hand-calibration``,
``visp-compute-eye-to-hand-calibration``) keep one pair of files per robot
pose in a directory, paired by the index ``<i>``:

- ``pose_fPe_<i>.yaml``: the end-effector pose in the robot base frame
  (``fPe``, ViSP's ``wMe``), i.e. ``T_base_flange``;
- ``pose_cPo_<i>.yaml``: the calibration object's pose in the camera frame
  (``cPo``), i.e. ``T_cam_marker``.

Each file is a ``vpPoseVector`` as written by ``vpPoseVector::saveYAML``::

    rows: 6
    cols: 1
    data:
      - [tx]      # m
      - [ty]
      - [tz]
      - [tux]     # theta-u: rotation vector (axis * angle), rad
      - [tuy]
      - [tuz]

A directory holds no word of the setup (ViSP has one app per setup), so it is
an option (``setup=``, ``handeye replay --setup``); default eye-in-hand, the
setup of ViSP's main tutorial. `write_visp` writes the same layout.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from handeye.app.errors import SessionError
from handeye.app.files import inside
from handeye.calib import transforms as tf
from handeye.calib.setup import Setup, check_setup

from handeye.app.formats.common import ImportedSamples, observations_from_poses, read_yaml
from handeye.app.formats.registry import register_import

_NAME = re.compile(r"^pose_(fPe|cPo)_(\d+)\.yaml$")


def is_visp_dir(path: Path) -> bool:
    """True if ``path`` is a directory holding at least one ``pose_fPe_<i>.yaml``."""
    return path.is_dir() and any(_NAME.match(p.name) and "fPe" in p.name for p in path.iterdir())


def read_pose_vector(path: Path) -> np.ndarray:
    """4x4 transform of one ``vpPoseVector`` YAML file; `SessionError` naming the file otherwise."""
    data = read_yaml(path)
    try:
        v = np.asarray(data["data"], dtype=float).reshape(-1)
    except (KeyError, TypeError, ValueError) as e:
        raise SessionError(f"{path}: not a vpPoseVector (needs data: 6 x [value]): {e}") from None
    if (data.get("rows"), data.get("cols")) != (6, 1) or v.shape != (6,) or not np.isfinite(v).all():
        raise SessionError(f"{path}: a vpPoseVector has rows: 6, cols: 1 and 6 finite values, got {v.tolist()}")
    return tf.from_rotvec_translation(v[3:], v[:3])


def _detect(path: Path, document) -> bool:
    return is_visp_dir(Path(path))


@register_import("visp", _detect, open_setup=True)
def load_visp(path, setup: str | None = None) -> ImportedSamples:
    """Read a ViSP hand-eye data directory.

    Parameters
    ----------
    path : str or Path
        The directory with ``pose_fPe_<i>.yaml`` and ``pose_cPo_<i>.yaml``.
    setup : {"eye_in_hand", "eye_to_hand"}, optional
        Default eye-in-hand.

    Returns
    -------
    ImportedSamples
        One observation per index present in both file sets, in index order;
        ``meta["unpaired"]`` lists indices with only one of the two files.
    """
    path = Path(path)
    if not path.is_dir():
        raise SessionError(f"{path}: ViSP data is a directory of pose_fPe_<i>.yaml / pose_cPo_<i>.yaml files")
    files: dict[str, dict[int, Path]] = {"fPe": {}, "cPo": {}}
    for p in path.iterdir():
        m = _NAME.match(p.name)
        if m:
            # A pose file may be a symlink: read it only if it resolves inside the directory.
            files[m.group(1)][int(m.group(2))] = inside(path, p.name, SessionError, what=str(p))
    paired = sorted(set(files["fPe"]) & set(files["cPo"]))
    if not paired:
        raise SessionError(f"{path}: no index has both pose_fPe_<i>.yaml and pose_cPo_<i>.yaml")
    A = np.array([read_pose_vector(files["fPe"][i]) for i in paired])
    B = np.array([read_pose_vector(files["cPo"][i]) for i in paired])
    obs = observations_from_poses(A, B, source=path, meta=[{"index": i} for i in paired])
    unpaired = sorted(set(files["fPe"]) ^ set(files["cPo"]))
    setup = Setup.EYE_IN_HAND if setup is None else check_setup(setup, error=SessionError)
    return ImportedSamples(obs, setup, {"format": "visp", "source": str(path), "time": "sample index",
                                        "frames": {"base": "f", "flange": "e", "camera": "c", "marker": "o"},
                                        "unpaired": unpaired})


def write_pose_vector(path: Path, T: np.ndarray) -> None:
    """One ``vpPoseVector`` YAML file (``vpPoseVector::saveYAML`` layout)."""
    rotvec, t = tf.to_rotvec_translation(T)
    rows = "".join(f"  - [{v:.17g}]\n" for v in [*t, *rotvec])
    Path(path).write_text(f"rows: 6\ncols: 1\ndata:\n{rows}")


def write_visp(directory, T_base_flange: np.ndarray, T_cam_marker: np.ndarray) -> Path:
    """Write pose pairs as ViSP's ``pose_fPe_<i>.yaml`` / ``pose_cPo_<i>.yaml`` (i from 1, as ViSP numbers them)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    for i, (A, B) in enumerate(zip(T_base_flange, T_cam_marker), start=1):
        write_pose_vector(directory / f"pose_fPe_{i}.yaml", A)
        write_pose_vector(directory / f"pose_cPo_{i}.yaml", B)
    return directory
