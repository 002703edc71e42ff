"""The simulated cell behind ROS 2: the driver nodes a production cell runs, and the backends that start them.

A ROS 2 production cell runs a camera driver (realsense2_camera) and
``ur_robot_driver``; handeye reads their topics (`handeye.drivers.camera.ros2`,
`handeye.drivers.robot.ros2`). Here each is a node process of this module, through
real DDS (rclpy, `handeye.drivers.ros2`), on the simulated cell:

- ``python -m handeye.mocks.ros2_cell camera SPEC``: realsense2_camera's stand-in. It
  renders the marker (`handeye.mocks.render.camera.RenderedCamera`) at the simulated
  controller's true flange pose (its dashboard's ``sim truth``, on
  ``robot_host``) and publishes colour (``rgb8``, or png on a ``.../compressed``
  topic), the depth registered to it (``16UC1`` mm) and the CameraInfo on the
  `handeye.drivers.camera.ros2.Ros2CameraConfig` topics, frame
  ``camera_color_optical_frame``, at ``fps`` (rendering takes ~50 ms a frame).
- ``python -m handeye.mocks.ros2_cell robot SPEC``: ur_robot_driver's stand-in. It
  reads the simulated controller over RTDE (`handeye.drivers.robot.ur_client`,
  receive only, as the driver does) and publishes every state on
  ``/joint_states`` (positions and velocities) and
  ``/tcp_pose_broadcaster/pose`` (``actual_TCP_pose`` in ``base``), stamped
  on arrival.

Each node prints ``ready`` once it publishes, answers JSON commands on stdin
one line each (the camera's: ``frame``, ``resume``, ``bump``, ``truth``) and exits when
stdin closes (its parent stopped it, or died); it ignores SIGINT, which a terminal's
Ctrl-C sends to the whole process group: its parent's clean stop needs it to the end. `NodeProcess` starts one.

Registered like every simulator (``simulated = True``), by `handeye.app.backends`:

- camera ``"ros2_sim"`` (`Ros2SimCamera`): starts the camera node, and reads
  it through the real ``ros2`` backend. Each `Ros2SimCamera.read` asks the
  node for a frame rendered now with the rendered camera's noise stream (the
  k-th read gets the k-th noise draw, as ``backend = "rendered"`` does, so the
  same poses give the same pixels as ``make demo``; the frames the node
  streams meanwhile use a noise stream of their own); it waits for that
  frame to come through DDS. `Ros2SimCamera.add_bump` knocks the node's camera.
- robot ``"ros2_sim"`` (`Ros2SimRobot`): ``type = "ur_sim"`` for ``calibrate``
  (moved and read over RTDE); read-only (``monitor``) it also starts the robot
  node and reads the arm from its topics through the real ``ros2`` backend.
"""

from __future__ import annotations

import argparse
import array
import json
import logging
import queue
import signal
import subprocess
import sys
import threading
import time
from typing import Literal

import cv2
import numpy as np
from pydantic import Field

from handeye.calib import transforms as tf
from handeye.calib.params import NonEmptyStr, PositiveFloat
from handeye.drivers.camera.base import Camera, CameraIntrinsics, RGBDFrame
from handeye.drivers.camera.depth import depth_to_mm
from handeye.drivers.camera.registry import CAMERAS
from handeye.drivers.camera.ros2 import Ros2Camera, Ros2CameraConfig
from handeye.drivers.errors import ConnectionLostError, DeviceError
from handeye.drivers.robot.base import RobotState
from handeye.drivers.robot.registry import ROBOTS
from handeye.drivers.robot.ros2 import UR_JOINTS, Ros2Robot, Ros2RobotConfig
from handeye.drivers.ros2 import Ros2Node, messages, set_stamp
from handeye.mocks.render.camera import MountBump, RenderedCamera, RenderedCameraConfig
from handeye.mocks.ur_sim.robot import URSimRobot, URSimRobotConfig

log = logging.getLogger(__name__)

#: realsense2_camera's colour optical frame (also the aligned depth's).
COLOR_FRAME = "camera_color_optical_frame"
#: ur_robot_driver's TCP pose topic and frame.
POSE_TOPIC, BASE_FRAME = "/tcp_pose_broadcaster/pose", "base"
#: After a requested frame the stream pauses until the next command (``resume``), at most this long (s): no
#: streamed frame may overtake the requested one while DDS still repairs its lost fragments (a reliable
#: writer resends them after its next heartbeat, which on a loaded host takes up to a few seconds).
PAUSE_AFTER_REQUEST_S = 12.0
#: How long `Ros2SimCamera.read` waits for the frame it asked for (s).
REQUEST_TIMEOUT_S = 10.0


# ----------------------------------------------------------------- messages
def image_message(Image, arr: np.ndarray, encoding: str, t: float, frame_id: str):
    """A ``sensor_msgs/Image`` of ``arr`` (H, W[, C]) in ``encoding``, stamped ``t``."""
    msg = Image()
    set_stamp(msg.header, t)
    msg.header.frame_id = frame_id
    msg.height, msg.width = int(arr.shape[0]), int(arr.shape[1])
    msg.encoding, msg.is_bigendian = encoding, 0
    msg.step = int(arr.strides[0]) if arr.flags.c_contiguous else int(arr[0].nbytes)
    data = array.array("B")
    data.frombytes(np.ascontiguousarray(arr).tobytes())  # array.array: rclpy takes it without a per-byte check
    msg.data = data
    return msg


def compressed_message(CompressedImage, bgr: np.ndarray, t: float, frame_id: str):
    """A png ``sensor_msgs/CompressedImage`` of a BGR image, stamped ``t``."""
    msg = CompressedImage()
    set_stamp(msg.header, t)
    msg.header.frame_id, msg.format = frame_id, "png"
    data = array.array("B")
    data.frombytes(cv2.imencode(".png", bgr)[1].tobytes())
    msg.data = data
    return msg


def camera_info_message(CameraInfo, intr: CameraIntrinsics, t: float, frame_id: str):
    """A ``plumb_bob`` ``sensor_msgs/CameraInfo`` of ``intr``, stamped ``t``."""
    msg = CameraInfo()
    set_stamp(msg.header, t)
    msg.header.frame_id = frame_id
    msg.width, msg.height, msg.distortion_model = intr.width, intr.height, "plumb_bob"
    K = intr.K
    msg.k = K.reshape(-1).tolist()
    msg.d = [float(x) for x in intr.dist]
    msg.r = np.eye(3).reshape(-1).tolist()
    msg.p = np.column_stack([K, np.zeros(3)]).reshape(-1).tolist()
    return msg


def pose_message(PoseStamped, T: np.ndarray, t: float, frame_id: str):
    """A ``geometry_msgs/PoseStamped`` of ``T`` (4, 4), stamped ``t``."""
    msg = PoseStamped()
    set_stamp(msg.header, t)
    msg.header.frame_id = frame_id
    xyz, q = tf.to_xyz_quat(T)
    p, o = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in xyz)
    o.x, o.y, o.z, o.w = (float(v) for v in q)
    return msg


def joint_state_message(JointState, q, qd, t: float, names=UR_JOINTS):
    """A ``sensor_msgs/JointState`` of positions ``q`` and velocities ``qd`` (rad, rad/s), stamped ``t``."""
    msg = JointState()
    set_stamp(msg.header, t)
    msg.name = list(names)
    msg.position = [float(v) for v in q]
    msg.velocity = [float(v) for v in qd]
    return msg


class FramePublisher:
    """Publishes RGB-D frames as realsense2_camera does: colour, aligned depth (16UC1 mm), CameraInfo.

    Parameters
    ----------
    node : handeye.drivers.ros2.Ros2Node
        An open node.
    topics : Ros2CameraConfig
        The topic names (a colour topic ending in ``/compressed`` gets png CompressedImages).
    frame_id : str
    """

    def __init__(self, node: Ros2Node, topics: Ros2CameraConfig, frame_id: str = COLOR_FRAME):
        self.Image, self.CompressedImage, self.CameraInfo = messages("sensor_msgs", "Image", "CompressedImage",
                                                                    "CameraInfo")
        self.topics, self.frame_id = topics, frame_id
        self.color = node.publisher(self.CompressedImage if topics.compressed else self.Image, topics.color_topic,
                                    depth=5)
        self.depth = node.publisher(self.Image, topics.depth_topic, depth=5)
        self.info = node.publisher(self.CameraInfo, topics.info_topic, depth=5)

    def publish(self, color: np.ndarray, depth_m: np.ndarray, intr: CameraIntrinsics, t: float,
                depth_t: float | None = None, depth_frame: str | None = None) -> None:
        """One frame stamped ``t`` (its depth stamped ``depth_t``, in ``depth_frame``: defaults ``t`` and the
        colour frame); colour BGR (H, W, 3) uint8, depth (H, W) m."""
        if self.topics.compressed:
            cmsg = compressed_message(self.CompressedImage, color, t, self.frame_id)
        else:
            cmsg = image_message(self.Image, cv2.cvtColor(color, cv2.COLOR_BGR2RGB), "rgb8", t, self.frame_id)
        dmsg = image_message(self.Image, depth_to_mm(depth_m), "16UC1", t if depth_t is None else depth_t,
                             depth_frame or self.frame_id)
        self.info.publish(camera_info_message(self.CameraInfo, intr, t, self.frame_id))
        self.depth.publish(dmsg)
        self.color.publish(cmsg)


# -------------------------------------------------------------------- nodes
def _lines(stream) -> queue.Queue:
    """The lines of ``stream`` (None at its end) as a queue filled by a reader thread."""
    q: queue.Queue = queue.Queue()

    def read() -> None:
        for line in stream:
            q.put(line)
        q.put(None)

    threading.Thread(target=read, daemon=True).start()
    return q


def _reply(obj) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def run_camera_node(spec: dict) -> int:
    """The camera node (see the module docstring) until stdin closes."""
    from handeye.mocks.ur_sim import dashboard

    cfg = RenderedCameraConfig.model_validate(spec["camera"])
    topics = Ros2CameraConfig.model_validate(spec["topics"])
    host, period = spec["robot_host"], 1.0 / float(spec["fps"])

    def flange() -> np.ndarray:
        return np.array(json.loads(dashboard(host, "sim truth", timeout=2.0)), dtype=float)

    main = RenderedCamera(cfg, flange)
    # The streamed frames draw their noise from a stream of their own; the mount (drift, bumps) is shared.
    stream = RenderedCamera(cfg.model_copy(update={"seed": cfg.seed + 1}), flange)
    main.connect()
    stream.connect()
    commands = _lines(sys.stdin)
    with Ros2Node(spec["node_name"]) as node:
        out = FramePublisher(node, topics, spec["frame_id"])
        _reply("ready")
        due, failed = time.monotonic(), False
        while True:
            try:
                line = commands.get(timeout=max(due - time.monotonic(), 0.0))
            except queue.Empty:
                line = ""
            if line is None:
                return 0
            try:
                if line.strip():
                    cmd = json.loads(line)
                    _reply(_camera_command(cmd, main, out))
                    pause = PAUSE_AFTER_REQUEST_S if cmd["cmd"] == "frame" else 0.0
                    due = time.monotonic() + max(period, pause)
                    continue
                f = stream.read()
                out.publish(f.color, f.depth, f.intrinsics, f.t)
                failed = False
            except (OSError, ValueError, DeviceError) as e:  # the controller away: say so once, keep trying
                if not failed:
                    print(f"ros2_cell camera: {e}", file=sys.stderr, flush=True)
                failed = True
                if line.strip():
                    _reply({"error": str(e)})
            due = max(due + period, time.monotonic())


def _camera_command(cmd: dict, camera: RenderedCamera, out: FramePublisher) -> dict:
    if cmd["cmd"] == "frame":
        f = camera.read()
        out.publish(f.color, f.depth, f.intrinsics, f.t)
        return {"t": f.t}
    if cmd["cmd"] == "resume":
        return {}
    if cmd["cmd"] == "bump":
        camera.add_bump(cmd["translation_mm"], cmd["rotation_deg"], cmd["direction"], cmd["axis"])
    return {k: np.asarray(v).tolist() for k, v in camera.truth().items()}


def run_robot_node(spec: dict) -> int:
    """The robot node (see the module docstring) until stdin closes."""
    from handeye.drivers.robot.ur import RTDE_VARIABLES
    from handeye.drivers.robot.ur_client import ClientDied, RTDEClient

    JointState, = messages("sensor_msgs", "JointState")
    PoseStamped, = messages("geometry_msgs", "PoseStamped")
    with Ros2Node(spec["node_name"]) as node:
        joints = node.publisher(JointState, "/joint_states", depth=50)
        pose = node.publisher(PoseStamped, POSE_TOPIC, depth=50)

        def on_state(t_recv, ts, q, qd, tcp, *modes) -> None:
            pose.publish(pose_message(PoseStamped, tf.from_ur_pose(np.asarray(tcp)), t_recv, BASE_FRAME))
            joints.publish(joint_state_message(JointState, q, qd, t_recv))

        client = RTDEClient(spec["host"], -1.0, True, RTDE_VARIABLES, on_state)
        try:
            client.start(10.0)
        except ClientDied as e:
            print(f"ros2_cell robot: {e}", file=sys.stderr, flush=True)
            return 1
        _reply("ready")
        try:
            for _ in iter(sys.stdin.readline, ""):
                pass
        finally:
            client.close(2.0)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m handeye.mocks.ros2_cell", description=__doc__.splitlines()[0])
    ap.add_argument("role", choices=("camera", "robot"))
    ap.add_argument("spec", help="JSON: the node's settings (NodeProcess writes it)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="ros2_cell: %(message)s")
    # A terminal's Ctrl-C reaches the whole process group: the node lives on until its parent, which
    # stops cleanly, closes its stdin (or dies).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    spec = json.loads(args.spec)
    try:
        return run_camera_node(spec) if args.role == "camera" else run_robot_node(spec)
    except DeviceError as e:
        print(f"ros2_cell {args.role}: {e}", file=sys.stderr, flush=True)
        return 1


class NodeProcess:
    """A node of this module in a child process: started, asked (JSON lines), stopped.

    Raises `DeviceError` when it does not report ready within ``timeout`` (with its stderr).
    """

    def __init__(self, role: Literal["camera", "robot"], spec: dict, timeout: float = 30.0):
        self.role = role
        self.proc = subprocess.Popen([sys.executable, "-m", "handeye.mocks.ros2_cell", role, json.dumps(spec)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, bufsize=1)
        self.stderr: list[str] = []
        threading.Thread(target=lambda: self.stderr.extend(self.proc.stderr), daemon=True).start()
        self.replies = _lines(self.proc.stdout)
        self.lock = threading.Lock()
        if self._next(timeout) != "ready":
            self.stop()
            raise DeviceError(f"simulated ROS 2 {role} node did not start: {''.join(self.stderr[-5:]).strip()}")

    def _next(self, timeout: float):
        try:
            line = self.replies.get(timeout=timeout)
        except queue.Empty:
            return None
        return None if line is None else json.loads(line)

    def request(self, cmd: dict, timeout: float = 10.0) -> dict:
        """Send one command and return its reply; `DeviceError` if the node is gone or says why not."""
        with self.lock:
            if self.proc.poll() is not None:
                raise DeviceError(f"simulated ROS 2 {self.role} node exited: {''.join(self.stderr[-3:]).strip()}")
            self.proc.stdin.write(json.dumps(cmd) + "\n")
            self.proc.stdin.flush()
            reply = self._next(timeout)
        if not isinstance(reply, dict) or "error" in reply:
            raise DeviceError(f"simulated ROS 2 {self.role} node: no answer to {cmd['cmd']}"
                              + (f": {reply['error']}" if isinstance(reply, dict) else ""))
        return reply

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout: float = 5.0) -> None:
        """Close its stdin (it exits), kill it if it does not."""
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


# ----------------------------------------------------------------- backends
class Ros2SimCameraConfig(RenderedCameraConfig):
    """``[camera]`` table for ``backend = "ros2_sim"``: the rendered camera's cell (`RenderedCameraConfig`)
    published by the camera node and read through ``[camera.ros2]`` (`Ros2CameraConfig`).

    Attributes
    ----------
    robot_host : str
        The simulated controller whose true flange pose the node renders at (``[robot] host``).
    fps : float
        Frames the node streams per second besides the ones `Ros2SimCamera.read` asks for.
    frame_id : str
        The images' ``frame_id``.
    ros2 : Ros2CameraConfig
        The subscriber (the real ``ros2`` backend): topics, pairing, timeouts.
    """

    backend: Literal["ros2_sim"] = "ros2_sim"
    robot_host: NonEmptyStr = "127.0.0.2"
    fps: PositiveFloat = 5.0
    frame_id: NonEmptyStr = COLOR_FRAME
    ros2: Ros2CameraConfig = Field(default_factory=Ros2CameraConfig)

    def rendered(self) -> RenderedCameraConfig:
        """The rendered camera of this table."""
        return RenderedCameraConfig.model_validate(
            self.model_dump(exclude={"backend", "robot_host", "fps", "frame_id", "ros2"}))


@CAMERAS.register("ros2_sim", Ros2SimCameraConfig)
class Ros2SimCamera(Camera):
    """The rendered camera through ROS 2: the camera node publishes, the ``ros2`` backend reads."""

    simulated = True

    def __init__(self, config: Ros2SimCameraConfig):
        self.config = config
        self.node: NodeProcess | None = None
        self.ros = Ros2Camera(config.ros2)

    def connect(self) -> None:
        c = self.config
        if self.node is None or not self.node.alive:
            self.node = NodeProcess("camera", {"camera": c.rendered().model_dump(mode="json"),
                                               "topics": c.ros2.model_dump(mode="json"), "robot_host": c.robot_host,
                                               "fps": c.fps, "frame_id": c.frame_id,
                                               "node_name": "sim_camera"})
        self.ros.connect()

    def reconnect(self) -> None:
        """Subscribe again; the node (its camera, mount and noise streams) lives on unless it died."""
        self.ros.disconnect()
        self.connect()

    def disconnect(self) -> None:
        self.ros.disconnect()
        if self.node is not None:
            self.node.stop()
            self.node = None

    @property
    def is_connected(self) -> bool:
        return self.ros.is_connected

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self.ros.intrinsics

    def read(self) -> RGBDFrame:
        """A frame rendered now, with the next draw of the rendered camera's noise, as it came through DDS."""
        if self.node is None:
            raise DeviceError("simulated ROS 2 camera is not connected")
        t = self.node.request({"cmd": "frame"})["t"]
        deadline = time.monotonic() + REQUEST_TIMEOUT_S
        try:
            while True:  # the node streams nothing newer until it is told to resume
                try:
                    frame = self.ros.read()
                except ConnectionLostError:
                    if time.monotonic() > deadline:
                        raise
                    continue  # a fragment lost on a loaded host: DDS resends it within seconds
                if frame.t >= t - 1e-6:  # stamps carry nanoseconds
                    return frame
        finally:
            self.node.request({"cmd": "resume"})

    def truth(self) -> dict:
        """The node's true camera and marker transforms (after any bump)."""
        if self.node is None:
            return {}
        return {k: np.asarray(v) for k, v in self.node.request({"cmd": "truth"}).items()}

    def camera_transform(self) -> np.ndarray:
        """The true camera transform now (``T_base_cam`` / ``T_flange_cam``)."""
        return self.truth()[self.config.setup.camera_name]

    def add_bump(self, translation_mm: float, rotation_deg: float, direction=(1.0, 0.0, 0.0),
                 axis=(0.0, 1.0, 0.0)) -> MountBump:
        """Knock the node's camera mount now (`RenderedCamera.add_bump`)."""
        self.node.request({"cmd": "bump", "translation_mm": translation_mm, "rotation_deg": rotation_deg,
                           "direction": list(direction), "axis": list(axis)})
        return MountBump(at_s=0.0, translation_mm=translation_mm, rotation_deg=rotation_deg,
                         direction=tuple(direction), axis=tuple(axis))


class Ros2SimRobotConfig(URSimRobotConfig):
    """``[robot]`` table for ``type = "ros2_sim"``: `URSimRobotConfig` plus how read-only runs read it.

    Attributes
    ----------
    ros2_source : {"pose", "joints"}
        Read-only: the flange pose from the TCP pose topic (``tcp_offset`` removed) or the joint states
        (`handeye.drivers.robot.ros2.Ros2RobotConfig.source`).
    """

    type: Literal["ros2_sim"] = "ros2_sim"
    ros2_source: Literal["pose", "joints"] = "pose"

    def ros2(self) -> Ros2RobotConfig:
        """The ``ros2`` robot that reads this arm from the robot node's topics."""
        return Ros2RobotConfig(source=self.ros2_source, tcp_offset=self.tcp_offset, model=self.model,
                               kinematic_error=self.kinematic_error)


@ROBOTS.register("ros2_sim", Ros2SimRobotConfig)
class Ros2SimRobot(URSimRobot):
    """The simulated UR beside a simulated ur_robot_driver: RTDE when it may move, ROS 2 topics read-only."""

    def __init__(self, config: Ros2SimRobotConfig):
        super().__init__(config)
        self.node: NodeProcess | None = None
        self.ros = Ros2Robot(config.ros2()) if config.read_only else None

    def connect(self) -> None:
        if self.ros is None:
            super().connect()
            return
        self.launch_controller()
        if self.node is None or not self.node.alive:
            self.node = NodeProcess("robot", {"host": self.config.host, "node_name": "sim_ur_robot_driver"})
        self.ros.connect()

    def reconnect(self) -> None:
        if self.ros is None:
            super().reconnect()
            return
        self.ros.disconnect()
        self.connect()

    def disconnect(self) -> None:
        if self.ros is None:
            super().disconnect()
            return
        self.ros.disconnect()
        if self.node is not None:
            self.node.stop()
            self.node = None
        if self.sim is not None:
            self.sim.stop()
            self.sim = None

    @property
    def is_connected(self) -> bool:
        return super().is_connected if self.ros is None else self.ros.is_connected

    def read(self) -> RobotState:
        return super().read() if self.ros is None else self.ros.read()

    def pose_at(self, t_host: float) -> np.ndarray:
        return super().pose_at(t_host) if self.ros is None else self.ros.pose_at(t_host)

    def buffered_span(self) -> tuple[float, float] | None:
        return super().buffered_span() if self.ros is None else self.ros.buffered_span()

    def move_to(self, T_base_flange, *args, **kwargs) -> RobotState:
        return super().move_to(T_base_flange, *args, **kwargs) if self.ros is None else self.ros.move_to(T_base_flange)

    def stop(self) -> None:
        super().stop() if self.ros is None else self.ros.stop()


if __name__ == "__main__":
    raise SystemExit(main())
