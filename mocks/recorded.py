"""A camera that plays back a recorded RGB-D sequence from a directory.

Selected by ``[camera] backend = "recorded"``. Layout (version 1)::

    <path>/
      intrinsics.yaml     width, height, fx, fy, cx, cy, dist (handeye.drivers.camera.intrinsics)
      frames.csv          header "index,t,color,depth"; one row per frame:
                          frame counter, host time of exposure (s, UNIX epoch),
                          color and depth file names relative to <path>
      color/000000.png    8-bit BGR (or grey) color image
      depth/000000.png    16-bit single-channel depth in millimetres, 0 = no reading,
                          registered to the color image

`RecordingWriter` writes this layout (one row flushed per frame, so a crash
loses at most the frame being written); any tool that writes PNGs and a CSV
can produce it.
"""

from __future__ import annotations

import csv
import time
from typing import Literal
from pathlib import Path

import cv2
import numpy as np

from handeye.calib.params import Bool, NonEmptyStr, Params
from handeye.drivers.errors import ConnectionLostError, DeviceError
from handeye.drivers.camera.base import Camera, CameraIntrinsics, RGBDFrame
from handeye.drivers.camera.depth import depth_from_mm, depth_to_mm
from handeye.drivers.camera.intrinsics import load_intrinsics, save_intrinsics
from handeye.drivers.camera.registry import CAMERAS

FIELDS = ["index", "t", "color", "depth"]


class RecordedCameraConfig(Params):
    """``[camera]`` table for ``backend = "recorded"``.

    Attributes
    ----------
    path : str
        The recording directory.
    loop : bool
        Start again after the last frame instead of reporting the end.
    realtime : bool
        Pace `read` by the recorded timestamps (False: as fast as asked).
    """

    backend: Literal["recorded"] = "recorded"
    path: NonEmptyStr
    loop: Bool = False
    realtime: Bool = False


@CAMERAS.register("recorded", RecordedCameraConfig)
class RecordedCamera(Camera):
    """Plays back a directory written by `RecordingWriter` (see module docstring).

    `read` returns the frames in order with their recorded timestamps and
    raises ConnectionLostError after the last one (unless ``loop``).
    """

    def __init__(self, config: RecordedCameraConfig):
        self.config = config
        self._rows: list[dict] | None = None
        self._intr: CameraIntrinsics | None = None
        self._pos = 0
        self._t0_wall = 0.0

    def identity(self) -> dict:
        return {"model": "recorded sequence (played back)", "source": str(self.config.path)}

    def connect(self) -> None:
        root = Path(self.config.path)
        if not (root / "frames.csv").is_file():
            raise DeviceError(f"no recording at {root}: frames.csv missing")
        self._intr = load_intrinsics(root / "intrinsics.yaml")
        with open(root / "frames.csv", newline="") as f:
            reader = csv.DictReader(f)
            if reader.fieldnames != FIELDS:
                raise DeviceError(f"{root / 'frames.csv'}: header must be {','.join(FIELDS)}, got {reader.fieldnames}")
            self._rows = list(reader)
        if not self._rows:
            raise DeviceError(f"recording {root} has no frames")
        self._pos = 0
        self._t0_wall = time.time()

    def disconnect(self) -> None:
        self._rows = None

    @property
    def is_connected(self) -> bool:
        return self._rows is not None

    @property
    def intrinsics(self) -> CameraIntrinsics:
        if self._intr is None:
            raise DeviceError("recorded camera is not connected")
        return self._intr

    def __len__(self) -> int:
        return 0 if self._rows is None else len(self._rows)

    def read(self) -> RGBDFrame:
        if self._rows is None:
            raise DeviceError("recorded camera is not connected")
        if self._pos >= len(self._rows):
            if not self.config.loop:
                raise ConnectionLostError(f"recording {self.config.path} ended after {len(self._rows)} frames")
            self._pos = 0
            self._t0_wall = time.time()
        row = self._rows[self._pos]
        root = Path(self.config.path)
        try:
            t = float(row["t"])
            index = int(row["index"])
        except ValueError as e:
            raise DeviceError(f"{root / 'frames.csv'} row {self._pos + 1}: {e}") from None
        color = cv2.imread(str(root / row["color"]), cv2.IMREAD_COLOR)
        depth_mm = cv2.imread(str(root / row["depth"]), cv2.IMREAD_UNCHANGED)
        if color is None or depth_mm is None:
            raise DeviceError(f"recording {root}: cannot read {row['color']} or {row['depth']}")
        if depth_mm.dtype != np.uint16 or depth_mm.ndim != 2:
            raise DeviceError(f"{row['depth']}: depth must be a 16-bit single-channel PNG in mm")
        if self.config.realtime:
            due = self._t0_wall + (t - float(self._rows[0]["t"]))
            time.sleep(max(0.0, due - time.time()))
        self._pos += 1
        return RGBDFrame(color, depth_from_mm(depth_mm), t, self._intr, index, {},
                         {"color": row["color"], "depth": row["depth"]})


class RecordingWriter:
    """Write frames into the recorded-sequence layout (see module docstring).

    Parameters
    ----------
    path : str or Path
        Directory to create (must not already hold a recording).
    intrinsics : CameraIntrinsics
    """

    def __init__(self, path, intrinsics: CameraIntrinsics):
        self.root = Path(path)
        if (self.root / "frames.csv").exists():
            raise DeviceError(f"{self.root} already holds a recording")
        (self.root / "color").mkdir(parents=True, exist_ok=True)
        (self.root / "depth").mkdir(exist_ok=True)
        save_intrinsics(self.root / "intrinsics.yaml", intrinsics)
        self._f = open(self.root / "frames.csv", "w", newline="")
        self._csv = csv.writer(self._f)
        self._csv.writerow(FIELDS)
        self._f.flush()
        self.count = 0

    def write(self, frame: RGBDFrame) -> None:
        """Append one frame (depth rounded to mm, clipped to 65.535 m)."""
        name = f"{self.count:06d}.png"
        depth_mm = depth_to_mm(frame.depth)
        if not (cv2.imwrite(str(self.root / "color" / name), frame.color)
                and cv2.imwrite(str(self.root / "depth" / name), depth_mm)):
            raise DeviceError(f"cannot write frame {name} into {self.root}")
        self._csv.writerow([frame.index, repr(float(frame.t)), f"color/{name}", f"depth/{name}"])
        self._f.flush()
        self.count += 1

    def close(self) -> None:
        self._f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
