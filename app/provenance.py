"""Who made a result, where and with what: the cell's identity that result.yaml and report.html carry.

``cell`` (result.yaml's ``cell``)::

    site, cell, operator          [report] of the config (or --site, --cell, --operator)
    robot: {type, host, model, serial, software}      what the robot driver read (`Device.identity`)
    camera: {backend, resolution, model, serial, ...} the camera driver's, and the image size
    marker: {kind, description}   the [marker] target in words (type, dictionary, id, size)
    software: {handeye, commit}   handeye's version and git commit
    written                       local date and time with its offset from UTC (ISO 8601)

The devices' part is read once per run, when they are open (`device_identity`), and kept in
the session's header (``devices``), so a replay of the session names them too.
"""

from __future__ import annotations

import datetime as _dt
import functools
import subprocess
from importlib import metadata
from pathlib import Path


def local_time(when: _dt.datetime | None = None) -> str:
    """Local ISO 8601 date and time with the UTC offset, to the second (``2026-12-03T10:46:43+01:00``)."""
    return (when or _dt.datetime.now()).astimezone().isoformat(timespec="seconds")


@functools.lru_cache(maxsize=1)
def software() -> dict:
    """``{"handeye": version, "commit": git commit}`` (``"unknown"`` outside a git checkout)."""
    try:
        version = metadata.version("handeye")
    except metadata.PackageNotFoundError:
        version = "unknown"
    try:
        done = subprocess.run(["git", "describe", "--always", "--dirty", "--abbrev=12"], capture_output=True,
                              text=True, timeout=5, cwd=Path(__file__).resolve().parents[1])
        commit = done.stdout.strip() if done.returncode == 0 and done.stdout.strip() else "unknown"
    except (OSError, subprocess.SubprocessError):
        commit = "unknown"
    return {"handeye": version, "commit": commit}


def device_identity(cfg, robot, camera) -> dict:
    """``{"robot": {...}, "camera": {...}}`` of the open devices of a run (module docstring)."""
    robot_id = {"type": getattr(cfg.robot, "type", ""), "host": getattr(cfg.robot, "host", ""), **robot.identity()}
    intr = camera.intrinsics
    camera_id = {"backend": getattr(cfg.camera, "backend", ""), "resolution": f"{intr.width}x{intr.height}"}
    if getattr(cfg.camera, "serial", ""):
        camera_id["serial"] = cfg.camera.serial
    camera_id.update(camera.identity())
    return {"robot": {k: str(v) for k, v in robot_id.items() if v},
            "camera": {k: str(v) for k, v in camera_id.items() if v},
            "marker": {"kind": cfg.marker.kind, "description": marker_description(cfg.marker)}}


def marker_description(marker) -> str:
    """The ``[marker]`` target in words: ``ArUco DICT_4X4_50, id 7, 50 mm square``, ``ChArUco DICT_4X4_50,
    5x7 squares of 30 mm (markers 22 mm)``, ``chessboard, 9x6 squares of 25 mm``."""
    if marker.kind == "aruco":
        return f"ArUco {marker.dictionary}, id {marker.marker_id}, {marker.marker_size * 1e3:g} mm square"
    squares = f"{marker.squares[0]}x{marker.squares[1]} squares of {marker.square_size * 1e3:g} mm"
    if marker.kind == "charuco":
        return f"ChArUco {marker.dictionary}, {squares} (markers {marker.marker_size * 1e3:g} mm)"
    return f"{marker.kind}, {squares}"


def cell(report, devices: dict | None = None) -> dict:
    """result.yaml's ``cell`` (module docstring): ``report`` is the ``[report]`` config (or its dict),
    ``devices`` what `device_identity` read (None: not known, e.g. an imported file)."""
    fields = report if isinstance(report, dict) else report.model_dump()
    out = {k: fields.get(k, "") for k in ("site", "cell", "operator")}
    for kind in ("robot", "camera", "marker"):
        if devices and devices.get(kind):
            out[kind] = dict(devices[kind])
    out["software"] = dict(software())
    out["written"] = local_time()
    return out
