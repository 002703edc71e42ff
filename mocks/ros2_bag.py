"""ROS 2 bags of the rendered demo cell, written with ``rosbags`` in standard message types.

What a ``ros2 bag record /tf /tf_static /camera/...`` of a stop-and-go
calibration run holds: the robot moving between flange poses of
`handeye.calib.simulate.realistic_cell` and holding each for ``stop_s``, its tf at
``tf_hz`` (``robot_state_publisher`` style: ``base_link -> base`` and
``wrist_3_link -> flange`` on ``/tf_static``, ``base_link -> wrist_3_link``
on ``/tf``; the camera driver's ``camera_link -> camera_color_optical_frame``
on ``/tf_static``, in a tree of its own until calibrated), the rendered
RGB-D camera (`handeye.mocks.render.camera.RenderedCamera`, eye-to-hand) at ``fps``
(colour ``rgb8``, depth registered to it, its ``CameraInfo``), and
optionally the marker pose a detector would publish.

`write_demo_bag` also returns the equivalent session's candidates: for each
stop, the first ``tries`` frames after the robot has been still for
``sample_after_s``, with the exact flange pose and the frames' pixels; a live
run takes the first of them in which the marker is found (`session_frames`).
Tests compare an import of the bag with that session.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from handeye.calib import simulate
from handeye.calib import transforms as tf
from handeye.calib.setup import Setup
from handeye.mocks.render.camera import RenderedCamera, RenderedCameraConfig
from handeye.mocks.ur_sim.motion import trapezoid_position

#: UR's ``base_link -> base``: a half turn about z (REP 103 base_link vs the controller's base).
T_BASE_LINK_BASE = tf.make_transform(Rotation.from_euler("z", np.pi).as_matrix(), [0.0, 0.0, 0.0])
#: ``wrist_3_link -> flange`` of the UR description (x along the last joint axis).
T_WRIST3_FLANGE = tf.make_transform(Rotation.from_euler("xyz", [0.0, -np.pi / 2, -np.pi / 2]).as_matrix(),
                                    [0.0, 0.0, 0.0])
#: ``camera_link -> camera_color_optical_frame`` as realsense2_camera publishes it: the colour camera 15 mm
#: beside the depth origin, turned from REP 103's x forward / z up to the optical z forward / y down.
T_CAMERA_LINK_OPTICAL = tf.make_transform(Rotation.from_quat([-0.5, 0.5, -0.5, 0.5]).as_matrix(), [0.0, 0.015, 0.0])
#: Start of the recording (s since the epoch): large stamps test the time arithmetic.
T0 = 1_700_000_000.0
COLOR_FRAME = "camera_color_optical_frame"


@dataclass
class SessionFrame:
    """A frame a live run may take at one stop (its ``attempt``-th still frame): exact flange pose and pixels."""

    stop: int
    attempt: int
    message: int
    t: float
    T_base_flange: np.ndarray
    color: np.ndarray
    depth: np.ndarray


@dataclass
class DemoBag:
    """What `write_demo_bag` wrote: the bag and the equivalent session."""

    path: Path
    candidates: list[SessionFrame] = field(default_factory=list)
    n_images: int = 0
    duration_s: float = 0.0
    intrinsics: object = None
    truth: dict = field(default_factory=dict)


def _trajectory(A: np.ndarray, stop_s: float, move_s: float, start: float):
    """``pose(t)`` of a stop-and-go run through the poses ``A`` (N, 4, 4) whose first stop ends at
    ``start + stop_s`` (the robot stands at ``A[0]`` from t = 0), its stops [(from, to)], duration."""
    v = 1.0 / (0.75 * move_s)  # a normalised trapezoid: a quarter of the move accelerates
    acc = v / (0.25 * move_s)
    cycle = stop_s + move_s
    stops = [(start + i * cycle if i else 0.0, start + i * cycle + stop_s) for i in range(len(A))]
    slerps = [Slerp([0.0, 1.0], Rotation.from_matrix(A[i:i + 2, :3, :3])) for i in range(len(A) - 1)]

    def pose(t: float) -> np.ndarray:
        i = min(max(int((t - start) // cycle), 0), len(A) - 1)
        tau = t - stops[i][1]
        if tau <= 0 or i == len(A) - 1:
            return A[i]
        s = min(trapezoid_position(tau, 1.0, v, acc), 1.0)
        return tf.make_transform(slerps[i]([s]).as_matrix()[0], (1 - s) * A[i, :3, 3] + s * A[i + 1, :3, 3])

    return pose, stops, stops[-1][1]


def write_demo_bag(path, *, storage: str = "mcap", n_poses: int = 12, seed: int = 0, fps: float = 30.0,
                   tf_hz: float = 125.0, stop_s: float = 0.8, move_s: float = 0.6, sample_after_s: float = 0.3,
                   depth_encoding: str = "16UC1", compressed: bool = False, marker_topic: bool = False,
                   render_moving: bool = True, camera_clock_offset_s: float = 0.0, tries: int = 3,
                   spread: tuple[float, float] = (0.15, 40.0), camera: RenderedCameraConfig | None = None) -> DemoBag:
    """Write a bag of the demo cell at ``path`` (a new directory).

    Parameters
    ----------
    storage : {"mcap", "sqlite3"}
    depth_encoding : {"16UC1", "32FC1"}
        Depth in mm (uint16) or m (float32).
    compressed : bool
        Colour as ``sensor_msgs/CompressedImage`` (png, lossless) instead of ``Image``.
    marker_topic : bool
        Also publish the true marker pose as ``geometry_msgs/PoseStamped`` on ``/marker_pose``.
    render_moving : bool
        Render every frame; False reuses the last stop's pixels while the robot moves (an importer
        never measures those frames: for long benchmark bags).
    camera_clock_offset_s : float
        Image stamps lag the tf clock by this (``t_tf = t_image + offset``).
    tries : int
        Session candidates kept per stop.
    spread : (float, float)
        The poses' translation (m per axis) and rotation (deg) range about the start pose.
    camera : RenderedCameraConfig, optional
        The rendered camera (default: the demo's, eye-to-hand).

    Returns
    -------
    DemoBag
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    M = ts.types
    path = Path(path)
    cfg = camera or RenderedCameraConfig()
    A = simulate.realistic_cell(n_poses, np.random.default_rng(seed), translation_range=spread[0],
                                angle_range=np.deg2rad(spread[1])).A_true
    # Stops start a tenth of a frame period before a frame is sample_after_s into them (the cycle a whole
    # number of frames): the live run's first frame is unambiguous, the one before sees the arrival.
    cycle = round((stop_s + move_s) * fps) / fps
    if cycle <= stop_s:
        raise ValueError(f"stop_s + move_s must exceed stop_s by at least a frame period (1/{fps:g} s)")
    first = np.ceil((sample_after_s + 0.1 / fps) * fps - 0.5) + 0.5
    pose, stops, duration = _trajectory(A, stop_s, cycle - stop_s, first / fps - sample_after_s - 0.1 / fps)
    now = {"t": 0.0}
    cam = RenderedCamera(cfg, lambda: pose(now["t"]))
    cam.connect()
    intr = cfg.intrinsics
    out = DemoBag(path, intrinsics=intr, truth=cam.truth())

    def header(t: float, frame: str):
        sec = int(np.floor(T0 + t))
        return M["std_msgs/msg/Header"](stamp=M["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=int(round((T0 + t - sec) * 1e9)) % 1_000_000_000), frame_id=frame)

    def transform(t: float, parent: str, child: str, T: np.ndarray):
        xyz, q = tf.to_xyz_quat(T)
        return M["geometry_msgs/msg/TransformStamped"](header=header(t, parent), child_frame_id=child,
                                                       transform=M["geometry_msgs/msg/Transform"](
            translation=M["geometry_msgs/msg/Vector3"](*map(float, xyz)),
            rotation=M["geometry_msgs/msg/Quaternion"](*map(float, q))))

    def image(t: float, arr: np.ndarray, encoding: str):
        flat = np.ascontiguousarray(arr).view(np.uint8).reshape(-1)
        return M["sensor_msgs/msg/Image"](header=header(t, COLOR_FRAME), height=arr.shape[0], width=arr.shape[1],
                                          encoding=encoding, is_bigendian=0, step=flat.size // arr.shape[0],
                                          data=flat)

    K = intr.K
    info = M["sensor_msgs/msg/CameraInfo"](
        header=header(0.0, COLOR_FRAME), height=intr.height, width=intr.width, distortion_model="plumb_bob",
        d=np.zeros(5), k=K.reshape(-1), r=np.eye(3).reshape(-1),
        p=np.column_stack([K, np.zeros(3)]).reshape(-1), binning_x=0, binning_y=0,
        roi=M["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))

    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    events = [(k / tf_hz, "tf") for k in range(int(duration * tf_hz) + 1)]
    # Frames half a period off the stops and tf ticks: no frame sits exactly where a stop starts.
    events += [((k + 0.5) / fps, "cam") for k in range(int(duration * fps))]
    events.sort()
    taken: dict[int, int] = {}
    last = None
    with Writer(path, version=9, storage_plugin=plugin) as w:
        c_tf = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
        c_static = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts)
        c_color = w.add_connection("/camera/color/" + ("image_raw/compressed" if compressed else "image_raw"),
                                   "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image",
                                   typestore=ts)
        c_info = w.add_connection("/camera/color/camera_info", "sensor_msgs/msg/CameraInfo", typestore=ts)
        c_depth = w.add_connection("/camera/aligned_depth_to_color/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        c_marker = w.add_connection("/marker_pose", "geometry_msgs/msg/PoseStamped", typestore=ts) \
            if marker_topic else None

        def put(conn, t: float, msg, msgtype: str):
            w.write(conn, int(round((T0 + t) * 1e9)), ts.serialize_cdr(msg, msgtype))

        put(c_static, 0.0, M["tf2_msgs/msg/TFMessage"](transforms=[
            transform(0.0, "base_link", "base", T_BASE_LINK_BASE),
            transform(0.0, "wrist_3_link", "flange", T_WRIST3_FLANGE),
            transform(0.0, "camera_link", COLOR_FRAME, T_CAMERA_LINK_OPTICAL)]), "tf2_msgs/msg/TFMessage")
        for t, kind in events:
            now["t"] = t
            if kind == "tf":
                T_bl_w3 = T_BASE_LINK_BASE @ pose(t) @ tf.invert(T_WRIST3_FLANGE)
                put(c_tf, t, M["tf2_msgs/msg/TFMessage"](transforms=[transform(t, "base_link", "wrist_3_link",
                                                                               T_bl_w3)]), "tf2_msgs/msg/TFMessage")
                continue
            stop = next((i for i, (a, b) in enumerate(stops) if a <= t <= b), None)
            if render_moving or stop is not None or last is None:
                frame = cam.read()
                last = frame
            frame = last
            t_img = t - camera_clock_offset_s
            k = out.n_images
            if compressed:
                ok, png = cv2.imencode(".png", frame.color)
                put(c_color, t, M["sensor_msgs/msg/CompressedImage"](header=header(t_img, COLOR_FRAME),
                                                                     format="png", data=png.reshape(-1)),
                    "sensor_msgs/msg/CompressedImage")
            else:
                put(c_color, t, image(t_img, cv2.cvtColor(frame.color, cv2.COLOR_BGR2RGB), "rgb8"),
                    "sensor_msgs/msg/Image")
            info.header = header(t_img, COLOR_FRAME)
            put(c_info, t, info, "sensor_msgs/msg/CameraInfo")
            if depth_encoding == "16UC1":
                depth_msg = image(t_img, np.round(frame.depth * 1000.0).astype(np.uint16), "16UC1")
            else:
                depth_msg = image(t_img, frame.depth.astype(np.float32), "32FC1")
            put(c_depth, t, depth_msg, "sensor_msgs/msg/Image")
            if c_marker is not None:  # the true marker pose at t, also while frames are not rendered
                T = pose(t)
                B = tf.invert(cfg.Y) @ T @ cfg.X if cfg.setup == Setup.EYE_TO_HAND else tf.invert(T @ cfg.X) @ cfg.Y
                xyz, q = tf.to_xyz_quat(B)
                put(c_marker, t, M["geometry_msgs/msg/PoseStamped"](
                    header=header(t_img, COLOR_FRAME), pose=M["geometry_msgs/msg/Pose"](
                        position=M["geometry_msgs/msg/Point"](*map(float, xyz)),
                        orientation=M["geometry_msgs/msg/Quaternion"](*map(float, q)))),
                    "geometry_msgs/msg/PoseStamped")
            # The live run's candidates: the first frames after sample_after_s of standstill.
            if stop is not None and taken.get(stop, 0) < tries and t - sample_after_s > stops[stop][0]:
                out.candidates.append(SessionFrame(stop, taken.get(stop, 0), k, t_img, A[stop], frame.color,
                                                   frame.depth.astype(float)))
                taken[stop] = taken.get(stop, 0) + 1
            out.n_images += 1
    cam.disconnect()
    out.duration_s = duration
    return out


def session_frames(bag: DemoBag, measure) -> list[tuple[SessionFrame, object]]:
    """The live run's samples: at each stop, the first candidate ``measure(frame)`` measures
    (``measure`` raises `handeye.calib.errors.ExtractionError` where the marker is not found)."""
    from handeye.calib.errors import ExtractionError

    out, done = [], set()
    for c in bag.candidates:
        if c.stop in done:
            continue
        try:
            m = measure(c)
        except ExtractionError:
            continue
        done.add(c.stop)
        out.append((c, m))
    return out
