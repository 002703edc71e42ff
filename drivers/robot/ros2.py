"""A UR arm read from ROS 2 topics, read-only, beside ``ur_robot_driver`` (``[robot] type = "ros2"``).

In a cell that runs ROS 2, ``ur_robot_driver`` owns the controller's External
Control program and publishes what handeye reads here (`handeye.drivers.ros2`:
rclpy, imported at connect):

- ``source = "pose"`` (default): the flange pose from the TCP pose
  (``geometry_msgs/PoseStamped`` on ``pose_topic``, ``tcp_pose_broadcaster``:
  the controller's ``actual_TCP_pose`` from its own calibrated kinematics, in
  the ``base`` frame) with the TCP offset removed as ``tcp_offset`` says (the
  pendant's active TCP; its zero is the flange, ROS's ``tool0``); the joints
  from ``/joint_states``;
- ``source = "joints"``: the flange pose from ``/joint_states`` through the UR
  kinematics (`handeye.drivers.robot.ur_kinematics`, nominal DH of ``model``).

Either way every state carries the joints and their speeds (``velocity``, or
the difference of two positions when a publisher leaves it empty), and the
robot stands still as `handeye.drivers.robot.base.RobotState.is_still` says for the RTDE
driver (every joint slower than 1e-3 rad/s). States are stamped with the
messages' header stamps (ROS time = the host's ``time.time()`` clock) into the
pose buffer `pose_at` interpolates (`handeye.drivers.robot.buffer.StateBuffer`); a
message whose stamp is not after the previous one's is a logged skip.

Read-only: `move_to`, `stop` and `check_target` refuse (``calibrate`` moves a
UR over RTDE with ``type = "ur"``; docs/monitor-service.md). Typed errors: no
publisher, nothing new for ``frozen_timeout`` (`ConnectionLostError`: an
outage in ``monitor``), joint names missing from ``/joint_states``, a pose in
another frame than ``base_frame``, stamps off this host's clock. The robot and
safety modes are not on these topics: states carry ``-1`` for both.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Literal

import numpy as np
from pydantic import field_validator, model_validator

from handeye.calib.params import Params, PositiveFloat, Str, Vector6
from handeye.calib.transforms import from_ur_pose, from_xyz_quat, invert
from handeye.drivers.errors import ConnectionLostError, DeviceError, LimitViolationError
from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.base import Robot, RobotLimits, RobotState
from handeye.drivers.robot.buffer import StateBuffer
from handeye.drivers.robot.registry import ROBOTS
from handeye.drivers.robot.ur import URKinematicError, URKinematics
from handeye.drivers.ros2 import NodeDevice, NodeName, SkipLog, TopicName, messages, stamp_seconds

log = logging.getLogger(__name__)

#: ur_robot_driver's joint names, in the kinematic order (``/joint_states`` lists them in any order).
UR_JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
             "wrist_3_joint")
#: What a state says of the robot and safety modes, which these topics do not carry.
UNKNOWN_MODE = -1


class Ros2RobotConfig(Params):
    """``[robot]`` table for ``type = "ros2"``.

    Attributes
    ----------
    source : {"pose", "joints"}
        The flange pose from ``pose_topic`` (TCP offset removed) or from the joints through the UR kinematics.
    pose_topic, joint_states_topic : str
        ``tcp_pose_broadcaster``'s PoseStamped and the joint states.
    joint_prefix : str
        ur_robot_driver's ``tf_prefix`` in front of the joint names (e.g. ``"ur_"``).
    base_frame : str
        The pose topic's ``frame_id`` (``""``: not checked).
    tcp_offset : 6 floats or None
        The pendant's active TCP as a UR pose ``[x, y, z, rx, ry, rz]`` (m, rad) in the flange frame;
        required with ``source = "pose"``.
    model : str
        UR model (``ur10``, ``ur5e`` ...): the kinematics of ``source = "joints"`` and of the error model.
    kinematic_error : URKinematicError or None
        1-sigma of the arm's DH parameters (as for ``type = "ur"``).
    frozen_timeout : float
        No new message for this long (s): `ConnectionLostError`.
    connect_timeout : float
        `connect` waits this long for the first state, s.
    max_clock_offset_s : float
        A state stamped further than this from this host's clock when it arrives is out of sync, s.
    buffer_seconds : float
        Length of the pose buffer `pose_at` interpolates in, s.
    speed, acceleration : float
        The arm's typical tool speed (m/s) and acceleration (m/s^2), for the planner's travel-time model only.
    node_name : str
    """

    type: Literal["ros2"] = "ros2"
    source: Literal["pose", "joints"] = "pose"
    pose_topic: TopicName = "/tcp_pose_broadcaster/pose"
    joint_states_topic: TopicName = "/joint_states"
    joint_prefix: Str = ""
    base_frame: Str = "base"
    tcp_offset: Vector6 | None = None
    model: Str = "ur10"
    kinematic_error: URKinematicError | None = None
    frozen_timeout: PositiveFloat = 0.5
    connect_timeout: PositiveFloat = 5.0
    max_clock_offset_s: PositiveFloat = 5.0
    buffer_seconds: PositiveFloat = 5.0
    speed: PositiveFloat = 0.25
    acceleration: PositiveFloat = 1.2
    node_name: NodeName = "handeye_robot"

    @field_validator("model")
    @classmethod
    def _known_model(cls, model: str) -> str:
        kin.geometry(model)
        return model.lower().replace("-", "")

    @model_validator(mode="after")
    def _tcp_for_pose(self):
        if self.source == "pose" and self.tcp_offset is None:
            raise ValueError("tcp_offset is required with source = 'pose': tcp_pose_broadcaster publishes the "
                             "TCP, whose offset from the flange must be removed ([0, 0, 0, 0, 0, 0] if the "
                             "pendant's TCP is the flange)")
        return self

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(self.joint_prefix + n for n in UR_JOINTS)

    @property
    def topics(self) -> list[str]:
        """The topics read: the joint states, and the TCP pose with ``source = "pose"``."""
        return [self.joint_states_topic] + ([self.pose_topic] if self.source == "pose" else [])


@ROBOTS.register("ros2", Ros2RobotConfig)
class Ros2Robot(NodeDevice, Robot):
    """Read-only UR arm from ROS 2 topics; see the module docstring.

    Parameters
    ----------
    config : Ros2RobotConfig
    """

    def __init__(self, config: Ros2RobotConfig):
        self.config = config
        self._buffer = StateBuffer(config.buffer_seconds)
        self._cv = threading.Condition()
        self._T_tcp_flange = invert(from_ur_pose(config.tcp_offset)) if config.tcp_offset is not None else None
        topic = config.pose_topic if config.source == "pose" else config.joint_states_topic
        self.skips = SkipLog(f"ROS 2 robot {topic}")
        self._reset()

    def _reset(self) -> None:
        self._buffer.clear()
        self._joints: tuple[float, np.ndarray, np.ndarray] | None = None  # (stamp, q, qd) of the newest
        self._last_arrival = None  # monotonic time of the newest message of the state topic
        self._offset = 0.0         # arrival - stamp of it (s)
        self._received = {self.config.pose_topic: 0, self.config.joint_states_topic: 0}
        self._error: str | None = None

    @classmethod
    def limits_for(cls, config: Ros2RobotConfig) -> RobotLimits:
        """No workspace box (nothing is ever moved); the configured speed and acceleration."""
        return RobotLimits(None, None, float(config.speed), float(config.acceleration))

    @classmethod
    def kinematics_for(cls, config: Ros2RobotConfig) -> URKinematics:
        return URKinematics(config.model, config.kinematic_error)

    # ------------------------------------------------------------ connection
    def connect(self) -> None:
        """Subscribe and wait (``connect_timeout``) for a first state.

        Raises
        ------
        DeviceError
            rclpy missing (with the install line), or no state: the message names the silent topic.
        """
        if self._node is not None:
            return
        c = self.config
        self._reset()
        node = self.open_node()
        try:
            (JointState,) = messages("sensor_msgs", "JointState")
            missing = node.wait_for_publishers(c.topics, c.connect_timeout)
            if missing:
                raise DeviceError(f"ROS 2 robot: no publisher on {missing[0]} (is ur_robot_driver running, in this "
                                  "ROS_DOMAIN_ID?)")
            node.subscribe(JointState, c.joint_states_topic, self._on_joints, depth=50)
            if c.source == "pose":
                (PoseStamped,) = messages("geometry_msgs", "PoseStamped")
                node.subscribe(PoseStamped, c.pose_topic, self._on_pose, depth=50)
            deadline = time.monotonic() + c.connect_timeout
            with self._cv:
                while self._buffer.latest is None and self._error is None:
                    if time.monotonic() > deadline:
                        raise DeviceError(f"ROS 2 robot: {self._silent()}")
                    self._cv.wait(0.05)
            self._check()
        except BaseException:
            self.disconnect()
            raise


    def _silent(self) -> str:
        """The first topic without a message: no publisher, or a publisher that sends nothing."""
        c = self.config
        for topic in c.topics:
            if self._received[topic]:
                continue
            n = self._node.publishers(topic) if self._node is not None else 0
            if not n:
                return f"no publisher on {topic} (is ur_robot_driver running, in this ROS_DOMAIN_ID?)"
            return f"no message on {topic} within {c.connect_timeout:g} s ({n} publisher{'s' * (n > 1)})"
        return "no state yet"

    # ------------------------------------------------------------- callbacks
    def _on_joints(self, msg) -> None:
        t, arrival = stamp_seconds(msg.header), time.monotonic()
        with self._cv:
            self._received[self.config.joint_states_topic] += 1
            try:
                q, v = self._joint_values(msg)
            except DeviceError as e:  # never raised into the executor: read() reports it
                self._error = str(e)
                return
            prev = self._joints
            if prev is not None and t <= prev[0]:
                self.skips(f"{self.config.joint_states_topic}: stamp not after the previous message's")
                return
            qd = v if v is not None else (np.zeros(6) if prev is None else (q - prev[1]) / (t - prev[0]))
            self._joints = (t, q, qd)
            if self.config.source == "joints":
                self._append(t, arrival, kin.forward(q, self.config.model))

    def _on_pose(self, msg) -> None:
        t, arrival = stamp_seconds(msg.header), time.monotonic()
        c = self.config
        with self._cv:
            self._received[c.pose_topic] += 1
            if c.base_frame and msg.header.frame_id.strip("/") != c.base_frame:
                self._error = (f"{c.pose_topic} is in frame {msg.header.frame_id!r}, not {c.base_frame!r} "
                               "(robot.base_frame)")
                return
            p, o = msg.pose.position, msg.pose.orientation
            v = np.array([p.x, p.y, p.z, o.x, o.y, o.z, o.w], dtype=float)
            n = np.linalg.norm(v[3:])
            if not np.isfinite(v).all() or abs(n - 1.0) > 1e-3:
                self.skips(f"{c.pose_topic}: not a pose (NaN or a quaternion of norm {n:.4f})")
                return
            if self._joints is None:
                return  # the joints (speeds, standstill) come with the first /joint_states
            self._append(t, arrival, from_xyz_quat(v[:3], v[3:] / n) @ self._T_tcp_flange)

    def _joint_values(self, msg) -> tuple[np.ndarray, np.ndarray | None]:
        """Positions (6,) and velocities (6,) or None, in the kinematic order (under the lock)."""
        c = self.config
        index = {name: i for i, name in enumerate(msg.name)}
        missing = [n for n in c.joint_names if n not in index]
        if missing:
            raise DeviceError(f"{c.joint_states_topic} has no joint {missing[0]!r} (it has "
                              f"{', '.join(list(msg.name)[:8]) or 'none'}); set robot.joint_prefix")
        order = [index[n] for n in c.joint_names]
        pos, vel = np.asarray(msg.position, dtype=float), np.asarray(msg.velocity, dtype=float)
        if pos.size != len(msg.name) or not np.isfinite(pos[order]).all():
            raise DeviceError(f"{c.joint_states_topic}: {pos.size} positions for {len(msg.name)} joints, or NaN")
        v = vel[order] if vel.size == len(msg.name) and np.isfinite(vel[order]).all() else None
        return pos[order], v

    def _append(self, t: float, arrival: float, T: np.ndarray) -> None:
        """A state at stamp ``t`` with the newest joints (under the lock)."""
        latest = self._buffer.latest
        if latest is not None and t <= latest.t_host:
            self.skips(f"{self.config.pose_topic if self.config.source == 'pose' else self.config.joint_states_topic}"
                       ": stamp not after the previous message's")
            return
        _, q, qd = self._joints
        self._buffer.append(RobotState(t, t, T, q, qd, UNKNOWN_MODE, UNKNOWN_MODE))
        self._last_arrival, self._offset = arrival, time.time() - t
        self._cv.notify_all()

    # --------------------------------------------------------------- reading
    def _check(self) -> None:
        """Raise for a stored error, a frozen stream, or stamps off this host's clock."""
        c = self.config
        if self._node is None:
            raise DeviceError("ROS 2 robot is not connected; call connect()")
        with self._cv:
            error, last, offset = self._error, self._last_arrival, self._offset
        if error is not None:
            raise DeviceError(f"ROS 2 robot: {error}")
        topic = c.pose_topic if c.source == "pose" else c.joint_states_topic
        if last is None:
            raise ConnectionLostError(f"ROS 2 robot: {self._silent()}")
        age = time.monotonic() - last
        if age > c.frozen_timeout:
            n = self._node.publishers(topic)
            raise ConnectionLostError(f"ROS 2 robot: no new message on {topic} for {age * 1e3:.0f} ms (limit "
                                      f"{c.frozen_timeout * 1e3:.0f} ms; {n} publisher{'s' * (n != 1)})")
        if abs(offset) > c.max_clock_offset_s:
            raise DeviceError(f"ROS 2 robot: {topic} is stamped {offset:+.3f} s off this host's clock "
                              f"(robot.max_clock_offset_s = {c.max_clock_offset_s:g} s): ur_robot_driver's "
                              "clock is not the system clock (use_sim_time? another host unsynchronised?)")

    def read(self) -> RobotState:
        """The newest state; `ConnectionLostError` when the stream stopped, `DeviceError` for bad data."""
        self._check()
        return self._buffer.latest

    def pose_at(self, t_host: float) -> np.ndarray:
        """``T_base_flange`` (4, 4) interpolated at ``t_host`` (the ``time.time()`` clock: ROS time)."""
        if self._node is None:
            raise DeviceError("ROS 2 robot is not connected; call connect()")
        try:
            return self._buffer.pose_at(t_host)
        except DeviceError:
            self._check()  # a stopped stream is the reason, not the time asked for
            raise

    def buffered_span(self) -> tuple[float, float] | None:
        """(oldest, newest) stamp in the pose buffer, or None if empty."""
        return self._buffer.span()

    # ------------------------------------------------------------- read-only
    def check_target(self, T_base_flange, q_start=None) -> np.ndarray:
        raise LimitViolationError("the ROS 2 robot is read-only: it plans and sends no motion (calibrate moves a "
                                  "UR over RTDE: robot.type = \"ur\")")

    def move_to(self, T_base_flange) -> RobotState:
        raise DeviceError("the ROS 2 robot is read-only: it cannot move the arm (robot.type = \"ur\" moves it "
                          "over RTDE)")

    def stop(self) -> None:
        raise DeviceError("the ROS 2 robot is read-only: it cannot stop the arm")
