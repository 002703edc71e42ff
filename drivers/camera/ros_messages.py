"""``sensor_msgs`` images and camera info -> arrays and `CameraIntrinsics`, for every ROS 2 source.

One reading of ROS 2's image messages, shared by the live camera
(`handeye.drivers.camera.ros2`, rclpy messages) and the bag importer
(`handeye.app.formats.ros2_bag`, rosbags' messages): both have the same fields, and
nothing here imports either library.

- ``sensor_msgs/Image`` colour: ``bgr8 rgb8 bgra8 rgba8 mono8`` -> BGR (or gray) uint8;
- ``sensor_msgs/Image`` depth registered to it: ``16UC1`` / ``mono16`` in mm or ``32FC1``
  in m -> metres, 0 where there is no reading;
- ``sensor_msgs/CompressedImage``: ``jpeg``, ``png`` colour; depth as image_transport's
  ``16UC1; compressedDepth png``;
- ``sensor_msgs/CameraInfo``: ``k`` and ``d`` of the ``plumb_bob`` (5) or
  ``rational_polynomial`` (8) model, OpenCV's coefficient order.

Each function raises the error class it is given (``error``: the importer's
`handeye.app.errors.SessionError`, the camera's `handeye.drivers.errors.DeviceError`) with
``where`` (topic and message) in front of what is wrong.
"""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np

from handeye.drivers.camera.base import CameraIntrinsics

#: Largest image side (px).
MAX_IMAGE_SIDE = 16384
#: Depth and colour frames paired if their stamps differ by at most this (s).
MAX_SKEW_S = 0.02
#: Colour encodings: channels and the conversion to BGR (None: already BGR or gray).
COLOR_ENCODINGS = {"bgr8": (3, None),
                   "rgb8": (3, cv2.COLOR_RGB2BGR), "bgra8": (4, cv2.COLOR_BGRA2BGR),
                   "rgba8": (4, cv2.COLOR_RGBA2BGR), "mono8": (1, None)}
#: Depth encodings: pixel type and metres per count.
DEPTH_ENCODINGS = {"16UC1": (np.uint16, 1e-3), "mono16": (np.uint16, 1e-3), "32FC1": (np.float32, 1.0)}
#: CameraInfo distortion models and their coefficient counts ("": no model named).
DISTORTION_MODELS = {"plumb_bob": (5,), "rational_polynomial": (8,), "": (0, 4, 5, 8, 12, 14)}
#: image_transport's compressedDepth header: int32 format + two float32 depth-quantisation parameters.
COMPRESSED_DEPTH_HEADER = 12


def camera_intrinsics(msg, where: str, error: type[Exception], size: tuple[int, int] | None = None
                      ) -> CameraIntrinsics:
    """`CameraIntrinsics` of a ``sensor_msgs/CameraInfo``; ``size`` (width, height) of the images it goes with.

    A CameraInfo of 0 x 0 (no size given) takes ``size``.
    """
    K = np.asarray(msg.k, dtype=float).reshape(-1)
    dist = np.asarray(msg.d, dtype=float).reshape(-1)
    if K.size != 9 or not np.isfinite(K).all() or K[0] <= 0 or K[4] <= 0:
        raise error(f"{where}: k must be 9 finite numbers with fx, fy > 0, got {K.tolist()!r:.100}")
    model = msg.distortion_model
    if model not in DISTORTION_MODELS or dist.size not in DISTORTION_MODELS[model]:
        raise error(f"{where}: distortion_model {model!r:.40} with {dist.size} coefficients is not one "
                    f"OpenCV's pinhole model reads (plumb_bob: 5, rational_polynomial: 8)")
    if not np.isfinite(dist).all():
        raise error(f"{where}: distortion coefficients are not finite")
    width, height = int(msg.width), int(msg.height)
    if size is not None and (width, height) != size and (width, height) != (0, 0):
        raise error(f"{where}: {width}x{height}, but the images are {size[0]}x{size[1]}")
    if (width, height) == (0, 0) and size is not None:
        width, height = size
    return CameraIntrinsics(width, height, float(K[0]), float(K[4]), float(K[2]), float(K[5]),
                            tuple(float(x) for x in dist) if dist.size else (0.0,) * 5)


def raw_image(msg, where: str, encodings: dict, error: type[Exception]) -> tuple[np.ndarray, str]:
    """(H, W[, C]) array of a ``sensor_msgs/Image`` and its encoding (one of ``encodings``)."""
    enc = msg.encoding
    if enc not in encodings:
        raise error(f"{where}: encoding {enc!r:.40} is not one of {', '.join(encodings)}")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if not (0 < h <= MAX_IMAGE_SIDE and 0 < w <= MAX_IMAGE_SIDE):
        raise error(f"{where}: image size {w}x{h} is not 1..{MAX_IMAGE_SIDE} px per side")
    dtype, channels = (np.dtype(encodings[enc][0]), 1) if encodings is DEPTH_ENCODINGS \
        else (np.dtype(np.uint8), encodings[enc][0])
    row = w * channels * dtype.itemsize
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < row or data.size < step * h:
        raise error(f"{where}: {data.size} data bytes for {w}x{h} {enc} with step {step} "
                    f"(needs {row} <= step and step x height bytes)")
    rows = data[:step * h].reshape(h, step)[:, :row]
    arr = np.ascontiguousarray(rows).view(dtype.newbyteorder(">") if msg.is_bigendian else dtype)
    arr = arr.astype(dtype, copy=False).reshape((h, w) if channels == 1 else (h, w, channels))
    return arr, enc


def color_image(msg, where: str, error: type[Exception]) -> np.ndarray:
    """BGR (or gray) uint8 image of an ``Image`` or ``CompressedImage``."""
    if hasattr(msg, "encoding"):
        img, enc = raw_image(msg, where, COLOR_ENCODINGS, error)
        code = COLOR_ENCODINGS[enc][1]
        return img if code is None else cv2.cvtColor(img, code)
    return decode(msg, where, cv2.IMREAD_COLOR, error)


def decode(msg, where: str, flags, error: type[Exception]) -> np.ndarray:
    """``cv2.imdecode`` of a ``CompressedImage``'s data."""
    data = np.asarray(msg.data, dtype=np.uint8)
    try:
        img = cv2.imdecode(data, flags) if data.size else None
    except cv2.error:
        img = None
    if img is None:
        raise error(f"{where}: cannot decode the {msg.format!r:.40} image")
    if img.shape[0] > MAX_IMAGE_SIDE or img.shape[1] > MAX_IMAGE_SIDE:
        raise error(f"{where}: image size {img.shape[1]}x{img.shape[0]} is above {MAX_IMAGE_SIDE} px")
    return img


def depth_image(msg, where: str, error: type[Exception]) -> np.ndarray:
    """Depth in metres (float64, 0 = no reading) of an Image (16UC1 mm / 32FC1 m) or a compressedDepth png."""
    if hasattr(msg, "encoding"):
        raw, enc = raw_image(msg, where, DEPTH_ENCODINGS, error)
        depth = raw.astype(np.float64) * DEPTH_ENCODINGS[enc][1]
    else:
        fmt = msg.format.replace(" ", "")
        if not fmt.startswith(("16UC1;compressedDepth", "mono16;compressedDepth")):
            raise error(f"{where}: depth format {msg.format!r:.40} is not '16UC1; compressedDepth png' "
                        "(32FC1 compressedDepth is quantised inverse depth: publish 16UC1 or raw)")
        inner = SimpleNamespace(data=np.asarray(msg.data, np.uint8)[COMPRESSED_DEPTH_HEADER:], format=msg.format)
        raw = decode(inner, where, cv2.IMREAD_UNCHANGED, error)
        if raw.dtype != np.uint16 or raw.ndim != 2:
            raise error(f"{where}: compressedDepth image is not 16-bit single-channel")
        depth = raw.astype(np.float64) * 1e-3
    return np.where(np.isfinite(depth) & (depth > 0), depth, 0.0)
