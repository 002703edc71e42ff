"""Importers for easy_handeye (ROS 1) and easy_handeye2 (ROS 2) sample lists.

easy_handeye2 saves ``~/.ros2/easy_handeye2/samples/<name>.samples``::

    parameters: {name, calibration_type: eye_in_hand | eye_on_base, robot_base_frame,
                 robot_effector_frame, tracking_base_frame, tracking_marker_frame, ...}
    samples:
    - robot:    {translation: {x, y, z}, rotation: {x, y, z, w}}
      tracking: {translation: {x, y, z}, rotation: {x, y, z, w}}

easy_handeye (ROS 1) keeps samples in memory; its ``get_sample_list`` service
returns an ``easy_handeye_msgs/SampleList`` with ``hand_world_samples`` and
``camera_marker_samples`` (lists of ``geometry_msgs/Transform``), which is what
this importer reads (as dumped by ``rosservice call``, optionally under
``samples:``; a ``parameters`` block as in its calibration file, with
``eye_on_hand``, names the setup). A list of ``{robot, optical}`` pairs (the
sampler's own structure) is accepted too.

Both tools store, per sample, the tracking transform ``tracking_base ->
tracking_marker`` (= ``T_cam_marker``) and a robot transform that depends on
the setup: ``T_base_effector`` for eye-in-hand, its inverse
``T_effector_base`` for eye-on-base (= eye-to-hand). The importer undoes that
inversion, so observations always carry ``T_base_flange``.
"""

from __future__ import annotations

from pathlib import Path

from handeye.calib import transforms as tf
from handeye.app.errors import SessionError
from handeye.calib.setup import Setup, check_setup

from handeye.app.formats.common import ImportedSamples, observations_from_poses, read_yaml, transform_from_msg
from handeye.app.formats.registry import register_import

# easy_handeye's names for the two setups (and ours).
_SETUP_NAMES = {"eye_in_hand": Setup.EYE_IN_HAND, "eye_on_hand": Setup.EYE_IN_HAND,
                "eye_on_base": Setup.EYE_TO_HAND, "eye_to_hand": Setup.EYE_TO_HAND}


def _setup_from(value, path: Path, given: str | None) -> Setup:
    if given is not None:
        return check_setup(given, error=SessionError)
    if isinstance(value, str) and value in _SETUP_NAMES:
        return _SETUP_NAMES[value]
    raise SessionError(
        f"{path}: the file does not say whether the camera is on the hand or on the base "
        f"(calibration_type / eye_on_hand missing or empty); pass setup='eye_in_hand' or 'eye_to_hand'"
    )


def _params(value, path: Path) -> dict:
    """The ``parameters`` block: a mapping, or empty when absent."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise SessionError(f"{path}: parameters must be a mapping, got {type(value).__name__}")
    return value


def _frames(params: dict) -> dict:
    def name(key, default):
        v = params.get(key)
        return v if isinstance(v, str) and v else default

    return {
        "base": name("robot_base_frame", "base"),
        "flange": name("robot_effector_frame", "flange"),
        "camera": name("tracking_base_frame", "camera"),
        "marker": name("tracking_marker_frame", "marker"),
    }


def _build(robot, tracking, setup: Setup, path: Path, fmt: str, params: dict) -> ImportedSamples:
    if not robot:
        raise SessionError(f"{path}: no samples")
    if len(robot) != len(tracking):
        raise SessionError(f"{path}: {len(robot)} robot transforms but {len(tracking)} tracking transforms")
    R = [transform_from_msg(d, f"{path}: sample {i} robot") for i, d in enumerate(robot)]
    B = [transform_from_msg(d, f"{path}: sample {i} tracking") for i, d in enumerate(tracking)]
    # eye-on-base samples store T_effector_base (the tools invert it for their solver).
    A = R if setup == Setup.EYE_IN_HAND else list(tf.invert(R))
    obs = observations_from_poses(A, B, source=path)
    meta = {"format": fmt, "source": str(path), "frames": _frames(params), "time": "sample index"}
    return ImportedSamples(obs, setup, meta)


def _sample_list(document):
    """The first sample of an easy_handeye(2) YAML document's sample list, if it has one."""
    data = document()
    samples = data.get("samples", data) if isinstance(data, dict) else data
    return samples[0] if isinstance(samples, list) and samples and isinstance(samples[0], dict) else None


def _is_easy_handeye2(path: Path, document) -> bool:
    if path.is_dir():
        return False
    if path.suffix == ".samples":
        return True
    first = _sample_list(document)
    return isinstance(document(), dict) and first is not None and "tracking" in first


def _is_easy_handeye(path: Path, document) -> bool:
    if path.is_dir() or path.suffix in (".samples", ".toml"):
        return False
    data, first = document(), _sample_list(document)
    if isinstance(data, dict):
        samples = data.get("samples", data)
        return ("tracking" not in first) if first is not None else (isinstance(samples, dict)
                                                                     and "hand_world_samples" in samples)
    return first is not None and "optical" in first


@register_import("easy_handeye2", _is_easy_handeye2, open_setup=True)
def load_easy_handeye2(path, *, setup: str | None = None) -> ImportedSamples:
    """Read an easy_handeye2 ``.samples`` file.

    Parameters
    ----------
    path : str or Path
    setup : {"eye_to_hand", "eye_in_hand"}, optional
        Needed only when ``parameters.calibration_type`` is empty (as in
        easy_handeye2's own test files) and no ``<name>.calib`` lies beside it.

    Returns
    -------
    ImportedSamples
    """
    path = Path(path)
    data = read_yaml(path)
    params = _params(data.get("parameters"), path)
    kind = params.get("calibration_type")
    calib_file = path.with_suffix(".calib")
    if not kind and setup is None and calib_file.exists():
        params = {**_params(read_yaml(calib_file).get("parameters"), calib_file),
                  **{k: v for k, v in params.items() if v}}
        kind = params.get("calibration_type")
    samples = data.get("samples")
    if not isinstance(samples, list):
        raise SessionError(f"{path}: 'samples' must be a list of {{robot, tracking}} entries")
    for i, s in enumerate(samples):
        if not isinstance(s, dict) or "robot" not in s or "tracking" not in s:
            raise SessionError(f"{path}: sample {i} needs 'robot' and 'tracking'")
    setup = _setup_from(kind, path, setup)
    return _build([s["robot"] for s in samples], [s["tracking"] for s in samples], setup, path,
                  "easy_handeye2", params)


def _transform_list(value, where: str) -> list:
    if isinstance(value, dict) and "transforms" in value:  # visp TransformArray
        value = value["transforms"]
    if not isinstance(value, list):
        raise SessionError(f"{where}: expected a list of transforms")
    return value


@register_import("easy_handeye", _is_easy_handeye, open_setup=True)
def load_easy_handeye(path, *, setup: str | None = None) -> ImportedSamples:
    """Read an easy_handeye (ROS 1) sample list (see the module docstring).

    Parameters
    ----------
    path : str or Path
    setup : {"eye_to_hand", "eye_in_hand"}, optional
        Needed when the file has no ``parameters.eye_on_hand``.

    Returns
    -------
    ImportedSamples
    """
    path = Path(path)
    data = read_yaml(path, allow_list=True)
    if isinstance(data, list):
        data = {"samples": data}
    params = _params(data.get("parameters"), path)
    eye_on_hand = params.get("eye_on_hand", data.get("eye_on_hand"))
    kind = None if eye_on_hand is None else ("eye_in_hand" if eye_on_hand else "eye_on_base")
    setup = _setup_from(kind, path, setup)
    body = data.get("samples", data)
    if isinstance(body, dict) and "hand_world_samples" in body:
        robot = _transform_list(body["hand_world_samples"], f"{path}: hand_world_samples")
        tracking = _transform_list(body.get("camera_marker_samples"), f"{path}: camera_marker_samples")
    elif isinstance(body, list):
        for i, s in enumerate(body):
            if not isinstance(s, dict) or "robot" not in s or "optical" not in s:
                raise SessionError(f"{path}: sample {i} needs 'robot' and 'optical'")
        robot, tracking = [s["robot"] for s in body], [s["optical"] for s in body]
    else:
        raise SessionError(f"{path}: no 'hand_world_samples'/'camera_marker_samples' nor a list of samples")
    return _build(robot, tracking, setup, path, "easy_handeye", params)
