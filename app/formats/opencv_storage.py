"""Importer for pose pairs in an OpenCV FileStorage YAML file (``%YAML:1.0``, read with ``cv2.FileStorage``).

The keys are the names of ``cv2.calibrateHandEye``'s arguments, each a
sequence of ``!!opencv-matrix`` entries (one per robot pose)::

    %YAML:1.0
    ---
    setup: eye_in_hand                 # optional: eye_in_hand | eye_to_hand
    R_gripper2base: [ !!opencv-matrix {rows: 3, cols: 3, dt: d, data: [...]}, ... ]   # or 3x1 rotation vectors
    t_gripper2base: [ !!opencv-matrix {rows: 3, cols: 1, dt: d, data: [...]}, ... ]   # m
    R_target2cam:   [ ... ]
    t_target2cam:   [ ... ]

``gripper2base`` is the gripper (flange) pose in the robot base frame
(``T_base_flange``), ``target2cam`` the target's pose in the camera frame
(``T_cam_marker``), as OpenCV documents them. Instead of the R/t pairs, 4x4
sequences ``H_gripper2base`` and ``H_target2cam`` are accepted too. The
setup defaults to eye-in-hand (``calibrateHandEye``'s own case) unless the
file or the ``setup=`` option says otherwise. `write_opencv_storage` writes this layout.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from handeye.app.errors import SessionError
from handeye.app.files import read_text_file
from handeye.calib import transforms as tf
from handeye.calib.setup import Setup, check_setup

from handeye.app.formats.common import ImportedSamples, observations_from_poses
from handeye.app.formats.registry import register_import

HEADER = "%YAML:1.0"
#: A matrix header's sizes: ``rows``/``cols`` in YAML or JSON (``rows: 3``) or XML (``<rows>3</rows>``),
#: an n-d matrix's ``sizes: [a, b, ...]`` (``<sizes>a b</sizes>``).
_MATRIX_SIZE = re.compile(r"\b(?:rows|cols)\"?\s*:\s*(\d+)|<(?:rows|cols)>\s*(\d+)"
                          r"|\bsizes\"?\s*:\s*\[([^\]]*)|<sizes>([^<]*)")


def is_opencv_storage(path: Path) -> bool:
    """True if the file starts with OpenCV's ``%YAML:1.0`` header (plain YAML readers reject it)."""
    if not Path(path).is_file():  # a FIFO must never block detection
        return False
    try:
        with open(path, "rb") as f:
            return f.read(len(HEADER)).decode(errors="replace") == HEADER
    except OSError:
        return False


def _cv_message(e: BaseException) -> str:
    """The last line of an OpenCV error (the parser's own words, e.g. ``parseValue ... Missing , between ...``)."""
    cause = e.__cause__ or e.__context__ or e
    line = (str(cause).strip().splitlines() or [type(cause).__name__])[-1]
    return re.sub(r"^OpenCV\([^)]*\) \S+: error: ", "", line)[:200]


def _matrices(fs, key: str, path: Path) -> list[np.ndarray] | None:
    node = fs.getNode(key)
    if node.empty():
        return None
    if not node.isSeq():
        raise SessionError(f"{path}: {key} must be a sequence of matrices (one per robot pose)")
    out = []
    for i in range(node.size()):
        m = node.at(i).mat()
        if m is None:
            raise SessionError(f"{path}: {key}[{i}] is not an !!opencv-matrix")
        out.append(np.asarray(m, dtype=float))
    return out


def _rotation(m: np.ndarray, where: str) -> np.ndarray:
    if m.shape == (3, 3):
        return m
    if m.size == 3:
        return cv2.Rodrigues(m.reshape(3, 1))[0]
    raise SessionError(f"{where}: a rotation is 3x3 or a 3x1 rotation vector, got shape {m.shape}")


def _transforms(fs, name: str, path: Path) -> np.ndarray:
    H = _matrices(fs, f"H_{name}", path)
    if H is not None:
        if any(h.shape != (4, 4) for h in H):
            raise SessionError(f"{path}: H_{name} entries must be 4x4")
        return np.array(H)
    R, t = _matrices(fs, f"R_{name}", path), _matrices(fs, f"t_{name}", path)
    if R is None or t is None:
        raise SessionError(f"{path}: needs R_{name} and t_{name} (or H_{name})")
    if len(R) != len(t):
        raise SessionError(f"{path}: {len(R)} R_{name} but {len(t)} t_{name}")
    out = []
    for i, (r, v) in enumerate(zip(R, t)):
        if v.size != 3:
            raise SessionError(f"{path}: t_{name}[{i}] must have 3 values, got shape {v.shape}")
        out.append(tf.make_transform(_rotation(r, f"{path}: R_{name}[{i}]"), v.reshape(3)))
    return np.array(out).reshape(-1, 4, 4)


def _detect(path: Path, document) -> bool:
    return Path(path).is_file() and is_opencv_storage(Path(path))


@register_import("opencv_storage", _detect, open_setup=True)
def load_opencv_storage(path, setup: str | None = None) -> ImportedSamples:
    """Read gripper2base / target2cam pose pairs from an OpenCV FileStorage YAML file.

    Returns
    -------
    ImportedSamples
        ``T_base_flange`` from ``gripper2base``, ``T_cam_marker`` from ``target2cam``.
    """
    path = Path(path)
    # Read through handeye.app.files (regular file, bounded, UTF-8), then parsed from memory by OpenCV.
    text = read_text_file(path, SessionError)
    # OpenCV allocates what a matrix header asks for before reading its data: refuse sizes
    # no pose matrix has (the largest is 4x4) before a header can ask for gigabytes.
    for m in _MATRIX_SIZE.finditer(text):
        if any(int(n) > 4 for n in re.findall(r"\d+", next(g for g in m.groups() if g is not None))):
            raise SessionError(f"{path}: a matrix with {m.group(0).strip()!r:.40}; pose matrices are at most 4x4")
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        if not fs.isOpened():
            raise SessionError(f"{path}: cannot open as an OpenCV FileStorage file")
        try:
            A = _transforms(fs, "gripper2base", path)
            B = _transforms(fs, "target2cam", path)
            node = fs.getNode("setup")
            file_setup = node.string() if not node.empty() else None
        finally:
            fs.release()
    # The bindings raise a parse error of the constructor as a SystemError whose cause is the cv2.error.
    except (cv2.error, SystemError) as e:
        raise SessionError(f"{path}: not a valid OpenCV FileStorage file ({_cv_message(e)})") from None
    if setup is None:  # the file's own word, named in the message if it is not a setup
        setup = check_setup(file_setup or Setup.EYE_IN_HAND, f"{path}: setup", error=SessionError)
    return ImportedSamples(observations_from_poses(A, B, source=path), check_setup(setup, error=SessionError),
                           {"format": "opencv_storage", "source": str(path), "time": "sample index",
                            "frames": {"base": "base", "flange": "gripper", "camera": "cam", "marker": "target"}})


def write_opencv_storage(path, T_base_flange: np.ndarray, T_cam_marker: np.ndarray, setup: str | None = None) -> Path:
    """Write pose pairs as ``R_/t_gripper2base`` and ``R_/t_target2cam`` sequences with ``cv2.FileStorage``."""
    path = Path(path)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if setup is not None:
        fs.write("setup", str(setup))
    for name, Ts in (("gripper2base", T_base_flange), ("target2cam", T_cam_marker)):
        for part, get in (("R", lambda T: T[:3, :3]), ("t", lambda T: T[:3, 3:4])):
            fs.startWriteStruct(f"{part}_{name}", cv2.FileNode_SEQ)
            for T in Ts:
                fs.write("", np.ascontiguousarray(get(np.asarray(T, dtype=float))))
            fs.endWriteStruct()
    fs.release()
    return path
