"""An RGB-D camera read from ROS 2 topics, beside the production stack that owns the device.

``[camera] backend = "ros2"``. In a production cell the camera belongs to the
vision software, and a RealSense, an Orbbec or a Zivid opens for one process
at a time; its ROS 2 driver publishes what handeye needs, so handeye
subscribes (`handeye.drivers.ros2`: rclpy, imported at connect) to:

- the colour image (``color_topic``: ``sensor_msgs/Image``, or
  ``sensor_msgs/CompressedImage`` when the name ends in ``/compressed``);
- the depth registered to it (``depth_topic``, e.g. realsense2_camera's
  ``aligned_depth_to_color``: ``16UC1`` mm or ``32FC1`` m);
- the colour camera's ``sensor_msgs/CameraInfo`` (``info_topic``;
  ``plumb_bob`` or ``rational_polynomial``): the intrinsics.

The defaults are realsense2_camera's (4.54 on: ``/camera/camera/...``; older
versions publish ``/camera/...``). Images are decoded as the bag importer
decodes them (`handeye.drivers.camera.ros_messages`), and only for the frames `read`
returns: the callbacks keep the newest ``queue_size`` messages per topic
(memory bounded however fast a publisher floods). `read` pairs the newest
colour image not yet returned with the depth image nearest its stamp (within
``max_skew_s``); the frame time is the colour image's header stamp, at which
the robot's poses are interpolated.

Typed errors (`handeye.drivers.errors`; in ``monitor`` each is an outage, ridden out
by reconnecting): no publisher on a topic, nothing within ``timeout_s``
(`ConnectionLostError`); depth that is not registered to the colour image
(another ``frame_id`` or size); colour and depth stamps that never pair; a
stamp further than ``max_clock_offset_s`` from this host's clock (another
clock, ``use_sim_time``). A message whose stamp is not after the previous
one's on its topic is a logged skip (`handeye.drivers.ros2.SkipLog`).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from dataclasses import dataclass
from typing import Annotated, Literal

import cv2
import numpy as np
from pydantic import Field

from handeye.calib.params import Int, Params, PositiveFloat
from handeye.drivers.camera.base import Camera, CameraIntrinsics, RGBDFrame
from handeye.drivers.camera.registry import CAMERAS
from handeye.drivers.camera.ros_messages import MAX_SKEW_S, camera_intrinsics, color_image, depth_image
from handeye.drivers.errors import ConnectionLostError, DeviceError
from handeye.drivers.ros2 import NodeDevice, NodeName, SkipLog, TopicName, messages, stamp_seconds

log = logging.getLogger(__name__)


class Ros2CameraConfig(Params):
    """``[camera]`` table for ``backend = "ros2"``.

    Attributes
    ----------
    color_topic, depth_topic, info_topic : str
        Colour image (``.../compressed``: CompressedImage), depth registered to it, colour CameraInfo.
    max_skew_s : float
        Colour and depth images are one frame when their stamps differ by at most this, s.
    max_clock_offset_s : float
        A frame stamped further than this from this host's clock when it arrives is out of sync, s.
    timeout_s : float
        No paired frame within this: `ConnectionLostError` (an outage in ``monitor``), s.
    connect_timeout_s : float
        How long `connect` waits for the publishers (discovery) and the first frame, s.
    queue_size : int
        Messages kept per topic for pairing (the newest).
    node_name : str
        This subscriber's ROS 2 node name.
    """

    backend: Literal["ros2"] = "ros2"
    color_topic: TopicName = "/camera/camera/color/image_raw"
    depth_topic: TopicName = "/camera/camera/aligned_depth_to_color/image_raw"
    info_topic: TopicName = "/camera/camera/color/camera_info"
    max_skew_s: PositiveFloat = MAX_SKEW_S
    max_clock_offset_s: PositiveFloat = 5.0
    timeout_s: PositiveFloat = 2.0
    connect_timeout_s: PositiveFloat = 10.0
    queue_size: Annotated[Int, Field(ge=2, le=100)] = 10
    node_name: NodeName = "handeye_camera"

    @property
    def compressed(self) -> bool:
        """Colour as ``sensor_msgs/CompressedImage`` (image_transport's ``.../compressed`` topic)."""
        return self.color_topic.endswith("/compressed")


@dataclass(frozen=True)
class StampedMessage:
    """A message as it arrived: its header stamp and host arrival time (s, ``time.time()`` clock)."""

    stamp: float
    arrival: float
    msg: object


class Stream:
    """The newest ``size`` messages of one topic, stamps increasing (an older or equal stamp is a skip)."""

    def __init__(self, topic: str, size: int, skips: SkipLog):
        self.topic, self.skips = topic, skips
        self.queue: collections.deque[StampedMessage] = collections.deque(maxlen=size)
        self.received = 0

    def add(self, stamp: float, arrival: float, msg) -> bool:
        """Keep the message (True), or count it as a skip when its stamp is not after the newest one's."""
        self.received += 1
        if self.queue and stamp <= self.queue[-1].stamp:
            self.skips(f"{self.topic}: stamp not after the previous message's (out of order or repeated)")
            return False
        self.queue.append(StampedMessage(stamp, arrival, msg))
        return True


class FramePairer:
    """Colour and depth streams of one camera, paired by stamp; pure (the camera feeds it under its lock).

    `take` hands out the newest colour message after the last one handed out that has a depth message
    within ``max_skew_s``, with that depth message: colour stamps handed out only increase.
    """

    def __init__(self, color_topic: str, depth_topic: str, size: int, max_skew_s: float, skips: SkipLog):
        self.color, self.depth = Stream(color_topic, size, skips), Stream(depth_topic, size, skips)
        self.max_skew_s = max_skew_s
        self.last = -np.inf  # stamp of the last colour message handed out

    def pair(self) -> tuple[StampedMessage, StampedMessage] | None:
        """The pair `take` would hand out, without taking it."""
        for color in reversed(self.color.queue):
            if color.stamp <= self.last:
                return None
            depth = self.nearest_depth(color.stamp)
            if depth is not None and abs(depth.stamp - color.stamp) <= self.max_skew_s:
                return color, depth
        return None

    def take(self) -> tuple[StampedMessage, StampedMessage] | None:
        pair = self.pair()
        if pair is not None:
            self.last = pair[0].stamp
        return pair

    def nearest_depth(self, stamp: float) -> StampedMessage | None:
        return min(self.depth.queue, key=lambda d: abs(d.stamp - stamp), default=None)


@CAMERAS.register("ros2", Ros2CameraConfig)
class Ros2Camera(NodeDevice, Camera):
    """Colour, registered depth and CameraInfo from ROS 2 topics; see the module docstring.

    Parameters
    ----------
    config : Ros2CameraConfig
    """

    def __init__(self, config: Ros2CameraConfig):
        self.config = config
        self._cv = threading.Condition()
        self.skips = SkipLog(f"ROS 2 camera {config.color_topic}")
        self._reset()

    def _reset(self) -> None:
        c = self.config
        self._frames = FramePairer(c.color_topic, c.depth_topic, c.queue_size, c.max_skew_s, self.skips)
        self._info = None
        self._intr: CameraIntrinsics | None = None
        self._intr_key: tuple | None = None
        self._index = 0

    # ------------------------------------------------------------ connection
    def connect(self) -> None:
        """Subscribe and wait (``connect_timeout_s``) for the CameraInfo and a first colour + depth pair.

        Raises
        ------
        DeviceError
            rclpy missing (with the install line), or nothing usable arrives: the message names the topic
            without a publisher, or what else is wrong (`read`).
        """
        if self._node is not None:
            return
        c = self.config
        self._reset()
        node = self.open_node()
        try:
            Image, CompressedImage, CameraInfo = messages("sensor_msgs", "Image", "CompressedImage", "CameraInfo")
            missing = node.wait_for_publishers((c.color_topic, c.depth_topic, c.info_topic), c.connect_timeout_s)
            if missing:
                raise DeviceError(f"ROS 2 camera: no publisher on {missing[0]} (is the camera driver running, in "
                                  "this ROS_DOMAIN_ID?)")
            node.subscribe(CompressedImage if c.compressed else Image, c.color_topic, self._on(self._frames.color))
            node.subscribe(Image, c.depth_topic, self._on(self._frames.depth))
            node.subscribe(CameraInfo, c.info_topic, self._on_info)
            self._wait_first()
        except BaseException:
            self.disconnect()
            raise

    def _wait_first(self) -> None:
        deadline = time.monotonic() + self.config.connect_timeout_s
        with self._cv:
            while self._info is None or self._frames.pair() is None:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise DeviceError(f"ROS 2 camera: {self._why(self.config.connect_timeout_s)}")
                self._cv.wait(left)


    def queues(self) -> tuple:
        """The colour and depth messages held for pairing (at most ``queue_size`` each)."""
        with self._cv:
            return tuple(self._frames.color.queue), tuple(self._frames.depth.queue)

    @property
    def intrinsics(self) -> CameraIntrinsics:
        """The colour camera's intrinsics from the newest CameraInfo."""
        if self._node is None:
            raise DeviceError("ROS 2 camera is not connected")
        with self._cv:
            info = self._info
        return self._intrinsics(info, None)

    # ------------------------------------------------------------- callbacks
    def _on(self, stream: Stream):
        def callback(msg) -> None:
            with self._cv:
                if stream.add(stamp_seconds(msg.header), time.time(), msg):
                    self._cv.notify_all()

        return callback

    def _on_info(self, msg) -> None:
        with self._cv:
            self._info = msg
            self._cv.notify_all()

    # --------------------------------------------------------------- reading
    def _why(self, waited: float | None = None) -> str:
        """Why no frame came within ``timeout_s`` (under the lock): the first topic without a publisher or a
        message, else the stamps that do not pair."""
        c = self.config
        waited = c.timeout_s if waited is None else waited
        frames = self._frames
        for topic, got in ((c.color_topic, frames.color.received), (c.depth_topic, frames.depth.received),
                           (c.info_topic, self._info is not None)):
            if got:
                continue
            n = self._node.publishers(topic) if self._node is not None else 0
            if not n:
                return f"no publisher on {topic} (is the camera driver running, in this ROS_DOMAIN_ID?)"
            return f"no message on {topic} within {waited:g} s ({n} publisher{'s' * (n > 1)})"
        color = frames.color.queue[-1]
        depth = frames.nearest_depth(color.stamp)
        if time.time() - color.arrival > c.timeout_s:
            return f"no new message on {c.color_topic} for {time.time() - color.arrival:.1f} s (publisher stopped?)"
        if depth is not None:
            return (f"colour and depth stamps out of sync: the newest colour image ({color.stamp:.3f} s) is "
                    f"{abs(depth.stamp - color.stamp) * 1e3:.0f} ms from the nearest depth image (camera.max_skew_s "
                    f"= {c.max_skew_s:g} s)")
        return f"no new depth on {c.depth_topic}"

    def read(self) -> RGBDFrame:
        """The newest colour + depth pair not yet returned (waiting up to ``timeout_s`` for one).

        Raises
        ------
        ConnectionLostError
            No pair within ``timeout_s`` (the message says which topic is silent or that the stamps do not pair).
        DeviceError
            Depth not registered to colour, a stamp off this host's clock, an undecodable image.
        """
        if self._node is None:
            raise DeviceError("ROS 2 camera is not connected")
        deadline = time.monotonic() + self.config.timeout_s
        with self._cv:
            while (pair := self._frames.take()) is None:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise ConnectionLostError(f"ROS 2 camera: {self._why()}")
                self._cv.wait(left)
            info = self._info
        return self._frame(*pair, info)

    def _frame(self, color: StampedMessage, depth: StampedMessage, info) -> RGBDFrame:
        c = self.config
        offset = color.arrival - color.stamp
        if abs(offset) > c.max_clock_offset_s:
            raise DeviceError(f"ROS 2 camera: {c.color_topic} is stamped {offset:+.3f} s off this host's clock "
                              f"(camera.max_clock_offset_s = {c.max_clock_offset_s:g} s): the camera driver's clock "
                              "is not the system clock (use_sim_time? an unsynchronised camera host?)")
        where = f"ROS 2 camera: {c.color_topic} at {color.stamp:.3f} s"
        frame_c, frame_d = color.msg.header.frame_id, depth.msg.header.frame_id
        if frame_c and frame_d and frame_c != frame_d:
            raise DeviceError(f"ROS 2 camera: depth ({c.depth_topic}) is in frame {frame_d!r}, colour in {frame_c!r}: "
                              "depth must be registered to colour (realsense2_camera: align_depth.enable:=true "
                              "and its aligned_depth_to_color topic)")
        t0 = time.perf_counter()
        rgb = color_image(color.msg, where, DeviceError)
        bgr = cv2.cvtColor(rgb, cv2.COLOR_GRAY2BGR) if rgb.ndim == 2 else rgb
        depth_m = depth_image(depth.msg, f"ROS 2 camera: {c.depth_topic} at {depth.stamp:.3f} s", DeviceError)
        if depth_m.shape != bgr.shape[:2]:
            raise DeviceError(f"ROS 2 camera: depth ({c.depth_topic}) is {depth_m.shape[1]}x{depth_m.shape[0]}, "
                              f"colour {bgr.shape[1]}x{bgr.shape[0]}: depth must be registered to colour")
        intr = self._intrinsics(info, (bgr.shape[1], bgr.shape[0]))
        frame = RGBDFrame(color=bgr, depth=depth_m.astype(np.float32), t=color.stamp, intrinsics=intr,
                          index=self._index,
                          meta={"source": "ros2", "color_topic": c.color_topic, "frame_id": frame_c,
                                "depth_skew_ms": (depth.stamp - color.stamp) * 1e3,
                                "arrival_ms": offset * 1e3, "decode_ms": (time.perf_counter() - t0) * 1e3})
        self._index += 1
        return frame

    def _intrinsics(self, info, size: tuple[int, int] | None) -> CameraIntrinsics:
        """Of a CameraInfo, checked once per distinct message content (it comes with every frame)."""
        intr = self._intr
        key = (tuple(info.k), tuple(info.d), info.distortion_model, info.width, info.height)
        if intr is None or self._intr_key != key or (size is not None and (intr.width, intr.height) != size):
            intr = camera_intrinsics(info, f"ROS 2 camera: {self.config.info_topic}", DeviceError, size)
            self._intr, self._intr_key = intr, key
        return intr
