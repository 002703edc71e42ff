"""Universal Robots arm over RTDE (ur_rtde 1.6.5).

Reads the flange pose ``T_base_flange`` (the controller's ``actual_TCP_pose``
with the active TCP offset removed) into a ring buffer so that camera frames
can be matched to the pose at their exposure time, and moves the flange with
moveL / moveJ after checking every target, and the path to it, against the
configured workspace box, tilt cone and joint limits.

Which kinematics checks the limits: this module's own UR kinematics
(`handeye.drivers.robot.ur_kinematics`, nominal DH parameters) — nothing is sent to
the controller before a target passed, not even an IK query. A real robot's
factory calibration shifts the flange by a few mm against the nominal model;
that is far inside any sensible safety margin, and the pose used for
calibration is always the controller's measured one.

The TCP offset comes from the control interface (``getTCPOffset()``). ur_rtde
1.6.5 cannot decode the RTDE output ``tcp_offset``, so in read-only mode
(which never opens the control interface) it must be configured
(``tcp_offset``), or `connect` fails.

ur_rtde itself runs in a child process (`handeye.drivers.robot.ur_client`, which says
why): this module sees states and call results, never a ur_rtde object.
"""

from __future__ import annotations

import logging
import math
import socket
import threading
import time
from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from handeye.calib.errors import ParameterError
from handeye.calib.params import Bool, Float, NonEmptyStr, Params, PositiveFloat, Str, Vector3, Vector6
from handeye.drivers.errors import ConnectionLostError, DeviceError, LimitViolationError, RobotStoppedError
from handeye.calib.robot_error import UR_ALPHA, ur_dh_error_factor
from handeye.calib.transforms import from_ur_pose, invert, pose_error, to_ur_pose
from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.base import KinematicModel, Robot, RobotLimits, RobotState
from handeye.drivers.robot.registry import ROBOTS
from handeye.drivers.robot.buffer import ClockMapper, StateBuffer, pose_path
from handeye.drivers.robot.ur_client import ClientDied, RTDEClient

log = logging.getLogger(__name__)

#: The controller's dashboard server (model, serial number, software version: `URRobot.identity`).
DASHBOARD_PORT = 29999
DASHBOARD_TIMEOUT_S = 1.0

# UR safety modes (RTDE ``safety_mode``) that stop the arm.
SAFETY_STOPPED = {3: "protective stop", 5: "safeguard stop", 6: "system emergency stop", 7: "robot emergency stop",
                  8: "safety violation", 9: "safety fault"}
# safety_status_bits: 2 protective, 4 safeguard, 5-7 emergency stops, 8 violation, 9 fault, 10 stopped by safety.
SAFETY_STOP_BITS = 0x7F4

RTDE_VARIABLES = [
    "timestamp",
    "actual_q",
    "actual_qd",
    "actual_TCP_pose",
    "robot_mode",
    "safety_mode",
    "safety_status_bits",
    "runtime_state",
]

# Linear path check: largest joint step (rad) between two checked samples, and the shortest
# tool travel (m) a sample interval is bisected down to.
MAX_PATH_DQ, MIN_PATH_STEP = 0.02, 1e-5

# ur_rtde's own bounds for moveL / moveJ arguments.
MAX_TOOL_SPEED, MAX_TOOL_ACC = 3.0, 150.0
MAX_JOINT_SPEED, MAX_JOINT_ACC = 3.14, 40.0


class URKinematicError(Params):
    """1-sigma of a UR's DH parameters around the nominal ones the controller computes poses with.

    Kinematic identification of UR arms without their factory calibration
    reports joint zero offsets of a few hundredths of a degree and link
    errors of tenths of a mm (1-3 mm at the flange); a factory-calibrated arm
    is several times better.
    """

    joint_offset_deg: Annotated[Float, Field(ge=0, le=5)] = 0.03
    link_length_m: Annotated[Float, Field(ge=0, le=0.01)] = 0.0003
    twist_deg: Annotated[Float, Field(ge=0, le=5)] = 0.02


class URRobotConfig(Params):
    """Configuration of a UR arm reached over RTDE (real robot or ``handeye.mocks.ur_sim``).

    Units: SI (m, s, rad) except ``max_tilt_deg`` (degrees, labelled).

    Attributes
    ----------
    type : "ur"
        Backend name of a ``[robot]`` table.
    host : str
        Controller address.
    model : str
        UR model for the limit checks (``ur10``, ``ur5e`` ...).
    read_only : bool
        Never open the control interface (passive monitoring); `URRobot.move_to` raises.
    frequency : float
        RTDE output rate in Hz; -1 = controller default (125 Hz CB3, 500 Hz e-Series).
    speed, acceleration : float
        moveL tool speed (m/s) and acceleration (m/s^2).
    joint_speed, joint_acceleration : float
        moveJ leading-joint speed (rad/s) and acceleration (rad/s^2).
    motion : str
        Default motion of `URRobot.move_to`: ``"linear"`` (moveL) or ``"joint"`` (moveJ).
    stop_deceleration : float
        stopL deceleration (m/s^2) used by `URRobot.stop`.
    settle_time : float
        The arm counts as settled after its joint speeds stayed below
        ``settle_speed`` (rad/s) for this long (s).
    settle_speed : float
    workspace_min, workspace_max : 3 floats or None
        Box in the base frame (m) that the flange origin and the TCP must
        stay in along every motion. Required unless ``read_only``.
    tilt_reference : 3 floats
        Direction in the base frame the flange z axis is compared with
        (default straight down).
    max_tilt_deg : float
        Largest allowed angle (deg) between flange z and ``tilt_reference``.
    joint_min, joint_max : 6 floats
        Joint limits, rad.
    tcp_offset : 6 floats or None
        Active TCP as UR pose ``[x, y, z, rx, ry, rz]`` in the flange frame.
        None: ask the controller (not possible in read-only mode).
    reach_tolerance : float
        A move that settles farther (m) than this from its target raises.
    reach_tolerance_deg : float
        Same for the orientation, degrees.
    frozen_timeout : float
        No new controller timestamp for this long (s) means the stream froze
        (`ConnectionLostError`, also while a move or any control call runs);
        the RTDE client process is then killed (default 0.5 s).
    connect_timeout : float
        Seconds to wait for the first state after connecting.
    move_timeout : float
        Seconds a move may take before it is stopped and reported.
    buffer_seconds : float
        Length of the pose ring buffer for `URRobot.pose_at`, s.
    path_step : float
        Spacing (m of tool travel, or rad of the leading joint) of the
        samples at which a motion path is checked against the limits.
    kinematic_error : URKinematicError or None
        1-sigma of the arm's DH parameters around the nominal ones of
        ``model``: the calibration then treats the flange-pose error they
        cause as shared by all samples (`URRobot.shared_error_factor`).
        None: the robot's error is taken as white (repeatability).
    """

    type: Literal["ur"] = "ur"
    host: NonEmptyStr
    model: Str = "ur10"
    read_only: Bool = False
    frequency: Float = -1.0
    speed: Annotated[Float, Field(gt=0, le=MAX_TOOL_SPEED)] = 0.1
    acceleration: Annotated[Float, Field(gt=0, le=MAX_TOOL_ACC)] = 0.5
    joint_speed: Annotated[Float, Field(gt=0, le=MAX_JOINT_SPEED)] = 0.5
    joint_acceleration: Annotated[Float, Field(gt=0, le=MAX_JOINT_ACC)] = 1.0
    motion: Literal["linear", "joint"] = "linear"
    stop_deceleration: Annotated[Float, Field(gt=0, le=MAX_TOOL_ACC)] = 2.0
    settle_time: PositiveFloat = 0.1
    settle_speed: PositiveFloat = 0.002
    workspace_min: Vector3 | None = None
    workspace_max: Vector3 | None = None
    tilt_reference: Vector3 = (0.0, 0.0, -1.0)
    max_tilt_deg: Annotated[Float, Field(gt=0, le=180)] = 60.0
    joint_min: Vector6 = tuple(float(q) for q in kin.UR_JOINT_LIMITS[:, 0])
    joint_max: Vector6 = tuple(float(q) for q in kin.UR_JOINT_LIMITS[:, 1])
    tcp_offset: Vector6 | None = None
    reach_tolerance: PositiveFloat = 0.005
    reach_tolerance_deg: PositiveFloat = 1.0
    frozen_timeout: PositiveFloat = 0.5
    connect_timeout: PositiveFloat = 5.0
    move_timeout: PositiveFloat = 60.0
    buffer_seconds: PositiveFloat = 5.0
    # Finer than 1 mm (1 mrad) only costs time (docs/benchmarks-history.md, handeye.drivers.robot.ur); coarser
    # than 5 cm could step over a limit or a singular region between two checks.
    path_step: Annotated[Float, Field(ge=1e-3, le=0.05)] = 0.01
    kinematic_error: URKinematicError | None = None

    @field_validator("model")
    @classmethod
    def _known_model(cls, model: str) -> str:
        kin.geometry(model)
        return model.lower().replace("-", "")

    @field_validator("frequency")
    @classmethod
    def _rate(cls, hz: float) -> float:
        if not (hz == -1 or 0 < hz <= 500):
            raise ValueError(f"must be -1 or in (0, 500] Hz, got {hz!r}")
        return hz

    @field_validator("tilt_reference")
    @classmethod
    def _direction(cls, v):
        if np.linalg.norm(v) < 1e-9:
            raise ValueError("must be a non-zero direction")
        return v

    @model_validator(mode="after")
    def _limits(self):
        if (self.workspace_min is None) != (self.workspace_max is None):
            raise ValueError("workspace_min and workspace_max must be given together")
        if self.workspace_min is None:
            if not self.read_only:
                raise ValueError("workspace_min/workspace_max are required unless read_only is true")
        elif not np.all(np.less(self.workspace_min, self.workspace_max)):
            raise ValueError(f"workspace_min {self.workspace_min} must be below workspace_max "
                             f"{self.workspace_max} on every axis")
        lim = kin.UR_JOINT_LIMITS
        if not (np.all(np.less(self.joint_min, self.joint_max)) and np.all(np.greater_equal(self.joint_min, lim[:, 0]))
                and np.all(np.less_equal(self.joint_max, lim[:, 1]))):
            raise ValueError(f"joint_min/joint_max must satisfy -2pi <= joint_min < joint_max <= 2pi rad, "
                             f"got {self.joint_min} / {self.joint_max}")
        return self

    @property
    def max_tilt(self) -> float:
        """Tilt limit in rad."""
        return math.radians(self.max_tilt_deg)

    @property
    def joint_limits(self) -> np.ndarray:
        """Joint limits, shape (6, 2), rad."""
        return np.stack([self.joint_min, self.joint_max], axis=1)



#: How far (m) the controller's flange pose may be from the nominal kinematics before `URRobot` says why.
MODEL_CHECK_M = 0.01


def _ur_pose_text(pose) -> str:
    """A UR pose (x y z m, rx ry rz rad) for a log line: ``[0.0000 0.0000 0.1000 0.0000 0.0000 0.0000]``."""
    return "[" + " ".join(f"{0.0 if abs(v) < 5e-5 else v:.4f}" for v in pose) + "]"   # (no "-0.0000")

@dataclass(frozen=True)
class URKinematics(KinematicModel):
    """A UR model's nominal kinematics (`handeye.drivers.robot.ur_kinematics`) and the 1-sigma of its DH parameters.

    Attributes
    ----------
    name : str
        UR model (``ur10``, ``ur5e`` ...).
    kinematic_error : URKinematicError or None
        None: the nominal model is taken as exact (no shared error).
    """

    name: str
    kinematic_error: URKinematicError | None = None

    def forward(self, q) -> np.ndarray:
        return kin.forward(q, self.name)

    def inverse_nearest(self, T_base_flange: np.ndarray, q_near) -> np.ndarray | None:
        return kin.inverse_nearest(T_base_flange, q_near, self.name)

    def shared_error_factor(self, q) -> np.ndarray | None:
        """The flange-pose error of joints ``q`` (N, 6) that ``kinematic_error`` causes: the factor
        (N, 6, 24) of `handeye.calib.auto.solve_auto`'s ``robot_shared_error``; None when not configured."""
        err = self.kinematic_error
        if err is None:
            return None
        g = kin.geometry(self.name)
        return ur_dh_error_factor(kin.check_q(q), math.radians(err.joint_offset_deg), err.link_length_m,
                                  math.radians(err.twist_deg), dh={"d": g.d, "a": g.a, "alpha": UR_ALPHA})


@ROBOTS.register("ur", URRobotConfig)
class URRobot(Robot):
    """A UR arm over RTDE; see the module docstring. Eye-to-hand or eye-in-hand alike:
    it only provides ``T_base_flange`` (the paper's ``A_i``).

    Parameters
    ----------
    config : URRobotConfig
    """

    def __init__(self, config: URRobotConfig):
        if not isinstance(config, URRobotConfig):
            raise ParameterError(f"URRobot needs a URRobotConfig, got {type(config).__name__}")
        self.config = config
        self._client: RTDEClient | None = None
        self._T_flange_tcp = np.eye(4)
        self._buffer = StateBuffer(config.buffer_seconds)
        self._clock = ClockMapper(config.buffer_seconds)
        self._new_state = threading.Condition()
        self._state_lock = threading.Lock()  # the TCP offset and the states computed with it
        self._last_ts = None
        self._last_change = 0.0
        self._safety_bits = 0
        self._stop_requested = False

    @classmethod
    def limits_for(cls, config: URRobotConfig) -> RobotLimits:
        """The workspace box and the moveL speed and acceleration of ``config``."""
        return RobotLimits(config.workspace_min, config.workspace_max, float(config.speed),
                           float(config.acceleration))

    @classmethod
    def kinematics_for(cls, config: URRobotConfig) -> URKinematics:
        """The nominal model of ``config.model`` with the configured ``kinematic_error``."""
        return URKinematics(config.model, config.kinematic_error)

    # ------------------------------------------------------------ connection
    @property
    def is_connected(self) -> bool:
        return self._client is not None

    @property
    def T_flange_tcp(self) -> np.ndarray:
        """Active TCP offset in use (4, 4)."""
        return self._T_flange_tcp.copy()

    def connect(self) -> None:
        """Start the RTDE client process (receive and, unless read-only, control) and buffer states.

        Raises
        ------
        ParameterError
            Read-only without a configured ``tcp_offset``.
        DeviceError
            The controller cannot be reached, or sends no state within ``connect_timeout``.
        """
        if self.is_connected:
            return
        cfg = self.config
        if cfg.read_only and cfg.tcp_offset is None:
            raise ParameterError(
                "URRobotConfig.tcp_offset is required in read_only mode: ur_rtde reads the active TCP only "
                "through the control interface, which read-only mode never opens"
            )
        self._buffer.clear()
        self._clock.reset()
        self._last_ts = None
        self._last_change = time.monotonic()  # the stream's age counts from now, not from an old stream
        client = RTDEClient(cfg.host, cfg.frequency, cfg.read_only, RTDE_VARIABLES, self._on_state)
        try:
            client.start(cfg.connect_timeout)
        except ClientDied as exc:
            client.close(0.0)
            raise DeviceError(str(exc)) from None
        self._client = client
        try:
            # First a live stream, then the control calls (which watch the stream while they run).
            self._wait_first_state()
            if not cfg.read_only:
                tcp = np.asarray(self._call("getTCPOffset"), dtype=float)
                if tcp.shape != (6,):
                    raise DeviceError(f"UR controller {cfg.host} did not report its TCP offset")
                if cfg.tcp_offset is not None and not np.allclose(tcp, cfg.tcp_offset, atol=1e-6):
                    log.warning("configured tcp_offset %s differs from the controller's %s; using the controller's",
                                cfg.tcp_offset, tcp.tolist())
            else:
                tcp = np.asarray(cfg.tcp_offset)
            with self._state_lock:  # states before the TCP was known carry the wrong flange pose
                self._T_flange_tcp = from_ur_pose(tcp)
                self._buffer.clear()
            self._wait_first_state()
        except BaseException:
            self._close_interfaces()
            raise
        self._check_model()

    def identity(self) -> dict:
        """The arm's model, serial number and software as its dashboard server (port `DASHBOARD_PORT`) answers
        them; read-only queries, also in read-only mode. What it does not answer (a CB3 before 3.2, no network
        path to the port) is left out; ``model`` is then the configured one."""
        info = {"model": f"{self.config.model.upper()} (configured)"}
        try:
            with socket.create_connection((self.config.host, DASHBOARD_PORT), timeout=DASHBOARD_TIMEOUT_S) as s:
                reply = s.makefile("rb")
                reply.readline()                                 # the server's greeting
                for key, query in (("model", "get robot model"), ("serial", "get serial number"),
                                   ("software", "PolyscopeVersion")):
                    s.sendall(query.encode() + b"\n")
                    answer = reply.readline().decode(errors="replace").strip()
                    if answer and not answer.lower().startswith(("could not understand", "error")):
                        info[key] = answer
                s.sendall(b"quit\n")
        except OSError as e:
            log.info("UR at %s: no identity from the dashboard server (%s)", self.config.host, e)
        return info

    def _check_model(self) -> None:
        # Nominal FK against the controller's pose: catches a wrong `model` or, read-only, a configured
        # `tcp_offset` that is not the controller's (decimetres); tolerates the factory calibration (millimetres).
        cfg, st = self.config, self.read()
        flange = kin.forward(st.q, cfg.model)
        _, dt = pose_error(flange, st.T_base_flange)
        if dt <= MODEL_CHECK_M:
            return
        fits = [m for m in kin.UR_MODELS if m != cfg.model
                and pose_error(kin.forward(st.q, m), st.T_base_flange)[1] <= MODEL_CHECK_M]
        if fits:
            log.warning("UR at %s: the measured flange pose is %.1f mm from the nominal %s kinematics and fits %s: "
                        "set robot.model", cfg.host, dt * 1e3, cfg.model, " or ".join(fits))
        elif cfg.read_only:
            # The controller's TCP pose with the configured offset taken off: what is left is the offset it uses.
            used = to_ur_pose(invert(flange) @ st.T_base_flange @ self._T_flange_tcp)
            log.warning("UR at %s: the flange pose (the controller's TCP pose less robot.tcp_offset) is %.1f mm from "
                        "the nominal %s kinematics: the controller's active TCP offset looks like %s (x y z m, rx ry "
                        "rz rad), robot.tcp_offset says %s; set robot.tcp_offset to the controller's (the pendant's "
                        "Installation > General > TCP, the one the program sets)", cfg.host, dt * 1e3, cfg.model,
                        _ur_pose_text(used), _ur_pose_text(cfg.tcp_offset))
        else:
            log.warning("UR at %s: the measured flange pose is %.1f mm from the nominal %s kinematics and no other UR "
                        "model fits it: check robot.model and the arm's calibration", cfg.host, dt * 1e3, cfg.model)

    def disconnect(self) -> None:
        """Stop the control script and close both interfaces (idempotent).

        On a stale or dropped stream the client process is killed instead:
        see `handeye.drivers.robot.ur_client` for why no ur_rtde teardown may run then.
        """
        self._close_interfaces()

    def _close_interfaces(self) -> None:
        client, self._client = self._client, None
        if client is None:
            return
        if client.error is None and self._stream_age() > self.config.frozen_timeout:
            client.kill("stream frozen at disconnect")
        client.close(timeout=self.config.connect_timeout)

    def reconnect(self) -> None:
        """Close whatever is left of the connection and connect again (re-uploads the control script)."""
        self._close_interfaces()
        self.connect()

    # --------------------------------------------------------------- reading
    def _wait_first_state(self) -> None:
        deadline = time.monotonic() + self.config.connect_timeout
        with self._new_state:
            while self._buffer.latest is None:
                if self._client.error is not None or time.monotonic() > deadline:
                    raise DeviceError(
                        f"no RTDE data from UR controller {self.config.host} within {self.config.connect_timeout} s"
                        + (f": {self._client.error}" if self._client.error else "")
                    )
                self._new_state.wait(0.01)

    def _on_state(self, t_recv, ts, q, qd, tcp, robot_mode, safety_mode, safety_bits) -> None:
        """One new controller state from the client process (its reader thread)."""
        if self._last_ts is not None and ts <= self._last_ts:
            return
        self._last_ts = ts
        self._safety_bits = safety_bits
        with self._state_lock:
            self._buffer.append(
                RobotState(
                    t_host=self._clock.update(ts, t_recv),
                    t_controller=ts,
                    T_base_flange=from_ur_pose(np.asarray(tcp)) @ invert(self._T_flange_tcp),
                    q=np.asarray(q),
                    qd=np.asarray(qd),
                    robot_mode=robot_mode,
                    safety_mode=safety_mode,
                )
            )
        with self._new_state:
            self._last_change = time.monotonic()
            self._new_state.notify_all()

    def _stream_age(self) -> float:
        """Seconds since the controller timestamp last advanced."""
        return time.monotonic() - self._last_change

    def _require_connected(self) -> None:
        if not self.is_connected:
            raise DeviceError(f"UR robot {self.config.host} is not connected; call connect()")

    def _check_stream(self) -> None:
        """Raise ConnectionLostError if the client died, the stream dropped, or the timestamp went stale."""
        client = self._client
        if client.error is not None:
            raise ConnectionLostError(f"RTDE connection to UR controller {self.config.host} lost: {client.error}")
        limit = self.config.frozen_timeout
        age = self._stream_age()
        if age > limit:
            # Our reader thread may just have been starved of CPU: give it a moment to catch up.
            with self._new_state:
                self._new_state.wait(0.05)
            age = self._stream_age()
            if age > limit:
                msg = (f"RTDE stream from UR controller {self.config.host} is frozen: no new controller timestamp "
                       f"for {age * 1e3:.0f} ms (limit {limit * 1e3:.0f} ms)")
                client.kill(msg)
                raise ConnectionLostError(msg)

    def read(self) -> RobotState:
        """Latest state.

        Raises
        ------
        ConnectionLostError
            The RTDE connection dropped, or no new controller timestamp arrived
            for ``frozen_timeout`` (frozen stream; the client is then killed
            and `reconnect` is needed).
        """
        self._require_connected()
        self._check_stream()
        return self._buffer.latest

    def pose_at(self, t_host: float) -> np.ndarray:
        """``T_base_flange`` (4, 4) at host time ``t_host`` (``time.time()`` clock).

        Interpolated from the ring buffer (last ``buffer_seconds``): linear on
        the translation, SLERP on the rotation. Sample times are the
        controller timestamps mapped to the host clock (`ClockMapper`).

        Raises
        ------
        ConnectionLostError
            ``t_host`` is not buffered because the stream dropped or froze.
        DeviceError
            ``t_host`` outside the buffered interval.
        """
        self._require_connected()
        try:
            return self._buffer.pose_at(t_host)
        except DeviceError:
            self._check_stream()  # a frozen stream is the reason, not the time asked for
            raise

    def buffered_span(self) -> tuple[float, float] | None:
        """(oldest, newest) host time in the pose buffer, or None if empty."""
        return self._buffer.span()

    # ---------------------------------------------------------------- limits
    def check_pose(self, T_base_flange: np.ndarray, what: str) -> None:
        """`LimitViolationError` (message starting with ``what``) if the flange or TCP leaves the box or the tilt cone."""
        cfg = self.config
        T_tcp = T_base_flange @ self._T_flange_tcp
        lo, hi = np.asarray(cfg.workspace_min), np.asarray(cfg.workspace_max)
        for label, p in (("flange", T_base_flange[:3, 3]), ("TCP", T_tcp[:3, 3])):
            if np.any(p < lo) or np.any(p > hi):
                raise LimitViolationError(
                    f"{what}: {label} at {np.round(p * 1e3, 1).tolist()} mm is outside the workspace box "
                    f"{np.round(lo * 1e3, 1).tolist()}..{np.round(hi * 1e3, 1).tolist()} mm"
                )
        ref = np.asarray(cfg.tilt_reference) / np.linalg.norm(cfg.tilt_reference)
        tilt = math.acos(float(np.clip(T_base_flange[:3, 2] @ ref, -1.0, 1.0)))
        if tilt > cfg.max_tilt:
            raise LimitViolationError(
                f"{what}: flange z axis is tilted {math.degrees(tilt):.1f} deg from {list(cfg.tilt_reference)} "
                f"(max_tilt_deg = {cfg.max_tilt_deg})"
            )

    def check_target(self, T_base_flange, motion: str | None = None, q_start=None, q_target=None) -> np.ndarray:
        """Check a move to ``T_base_flange`` against every configured limit, sending nothing.

        The target and samples along the path (every ``path_step``) must keep
        the flange origin and the TCP inside the workspace box and the flange
        z axis inside the tilt cone; the joint solution (nominal IK nearest to
        the start) must respect the joint limits, and a linear path must keep
        its IK branch and stay `ur_kinematics.SINGULARITY_REFUSE` away from the
        wrist, elbow and shoulder singularities (sampled more finely wherever
        the joints move fast, see `_check_linear_path`).

        Parameters
        ----------
        T_base_flange : array_like, shape (4, 4)
        motion : {"linear", "joint"} or None (config default)
        q_start : array_like, shape (6,) or None
            Start joints; None = the robot's current ones.
        q_target : array_like, shape (6,) or None
            For ``motion="joint"``: the joint solution to use (must be within
            the joint limits); None = the nominal IK solution nearest ``q_start``.

        Returns
        -------
        q_target : ndarray, shape (6,)
            Joint solution of the target, rad.

        Raises
        ------
        LimitViolationError
            With the first violated limit; also for a malformed target.
        """
        cfg = self.config
        if cfg.workspace_min is None:
            raise LimitViolationError("no workspace box is configured (workspace_min/workspace_max)")
        motion = motion or cfg.motion
        if motion not in ("linear", "joint"):
            raise LimitViolationError(f"motion must be 'linear' or 'joint', got {motion!r}")
        T = np.asarray(T_base_flange, dtype=float)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise LimitViolationError(f"target T_base_flange must be a finite (4, 4) array, got shape {T.shape}")
        R = T[:3, :3]
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or abs(np.linalg.det(R) - 1) > 1e-6 or np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-9:
            raise LimitViolationError("target T_base_flange is not a rigid transform")
        q0 = np.asarray(self.read().q if q_start is None else q_start, dtype=float)
        limits = cfg.joint_limits
        self.check_pose(T, "target")
        if q_target is not None:
            q1 = kin.check_q(q_target, "q_target")
            if np.any(q1 < limits[:, 0]) or np.any(q1 > limits[:, 1]):
                raise LimitViolationError(f"target q {np.round(q1, 4).tolist()} is outside joint_min/joint_max")
        else:
            q1 = kin.inverse_nearest(T, q0, cfg.model, limits)
        if q1 is None:
            raise LimitViolationError(
                f"target: no {cfg.model.upper()} joint solution within joint_min/joint_max (unreachable pose)"
            )
        if motion == "joint":
            n = max(1, math.ceil(np.max(np.abs(q1 - q0)) / cfg.path_step))
            for s in np.linspace(0.0, 1.0, n + 1)[1:-1]:
                self.check_pose(kin.forward(q0 + s * (q1 - q0), cfg.model), f"moveJ path at {s:.0%}")
        else:
            T0 = kin.forward(q0, cfg.model)
            T0_tcp, T1_tcp = T0 @ self._T_flange_tcp, T @ self._T_flange_tcp
            angle = pose_error(T0_tcp, T1_tcp)[0]
            length = max(float(np.linalg.norm(T1_tcp[:3, 3] - T0_tcp[:3, 3])), 0.1 * float(angle))
            q1 = self._check_linear_path(q0, T0_tcp, T1_tcp, length)
        return q1

    def _check_linear_path(self, q0: np.ndarray, T0_tcp: np.ndarray, T1_tcp: np.ndarray, length: float) -> np.ndarray:
        # Samples every path_step, bisected wherever the joints move more than MAX_PATH_DQ between
        # two samples: near a singularity the joints turn fast for little tool travel, and a
        # controller that samples the line more finely than path_step would meet what a coarse
        # check jumps over. Every sample must keep the limits and SINGULARITY_REFUSE margins.
        cfg = self.config
        limits = cfg.joint_limits
        T_tcp_flange = invert(self._T_flange_tcp)
        path = pose_path(T0_tcp, T1_tcp)
        n = max(1, math.ceil(length / cfg.path_step))
        todo = list(np.linspace(0.0, 1.0, n + 1)[:0:-1])  # stack, next sample last
        # A sample refused for a large joint step comes back after the finer ones: its IK solutions are kept.
        solved: dict[float, tuple] = {}
        q, s_prev = q0, 0.0
        while todo:
            s = todo.pop()
            if s not in solved:
                Ts = path(s) @ T_tcp_flange
                solved[s] = Ts, kin.inverse_all(Ts, cfg.model)
            Ts, solutions = solved[s]
            qs = kin.nearest_solution(solutions, q, limits)
            dq = np.inf if qs is None else float(np.max(np.abs(qs - q)))
            if dq > MAX_PATH_DQ and (s - s_prev) * length > MIN_PATH_STEP:
                todo += [s, 0.5 * (s_prev + s)]
                continue
            where = f"moveL path at {s:.0%}"
            if qs is None or dq > 0.5:
                raise LimitViolationError(f"{where}: leaves the joint limits or passes a singularity; use motion='joint'")
            self.check_pose(Ts, where)
            margins = kin.singularity_margins(qs, cfg.model)
            low = margins < kin.SINGULARITY_REFUSE
            if low.any():
                i = int(np.argmax(low))
                raise LimitViolationError(
                    f"{where}: passes near a {kin.SINGULARITIES[i]} singularity (margin {margins[i]:.3f} < "
                    f"{kin.SINGULARITY_REFUSE[i]}); use motion='joint'"
                )
            q, s_prev = qs, s
        return q

    # ---------------------------------------------------------------- motion
    def _call(self, name: str, *args):
        """One control-interface call in the client process, watching the stream while it runs.

        A call that blocks in ur_rtde (e.g. moveL waiting for the controller's
        acknowledgement during a frozen stream) still ends after ``frozen_timeout``.
        """
        self._require_connected()
        try:
            return self._client.call(name, *args, timeout=self.config.connect_timeout, watch=self._check_stream)
        except ClientDied as exc:
            raise ConnectionLostError(f"RTDE connection to UR controller {self.config.host} lost: {exc}") from None
        except RuntimeError as exc:  # ur_rtde's own error, raised in the client
            raise DeviceError(f"UR controller {self.config.host}: {name} failed: {exc}") from None

    def _require_control(self) -> None:
        self._require_connected()
        if self.config.read_only:
            raise DeviceError(f"UR robot {self.config.host} is read-only: it cannot move or stop the arm")

    def _raise_if_stopped(self, state: RobotState, doing: str) -> None:
        if state.safety_mode in SAFETY_STOPPED or self._safety_bits & SAFETY_STOP_BITS:
            what = SAFETY_STOPPED.get(state.safety_mode, f"safety stop (status bits {self._safety_bits:#x})")
            raise RobotStoppedError(f"UR robot {self.config.host} is in {what} ({doing})")

    def move_to(self, T_base_flange, motion: str | None = None, *, q_target=None) -> RobotState:
        """Move the flange to ``T_base_flange`` (4, 4, m), blocking until settled.

        ``motion="linear"`` sends moveL (``speed``, ``acceleration``) to the
        TCP pose ``T_base_flange @ T_flange_tcp``; ``"joint"`` sends moveJ
        (``joint_speed``, ``joint_acceleration``) to the checked joint
        solution (or ``q_target``, see `check_target`). Everything is checked
        first (`check_target`).

        Returns
        -------
        RobotState
            The settled state.

        Raises
        ------
        LimitViolationError
            Before anything is sent.
        RobotStoppedError
            Protective / emergency stop before or during the move.
        ConnectionLostError
            The stream dropped or froze.
        DeviceError
            Read-only mode; the control script is not running (after a stop:
            call `reconnect`); timeout; stopped by `stop`; settled off target.
        """
        self._require_control()
        cfg = self.config
        motion = motion or cfg.motion
        state = self.read()
        self._raise_if_stopped(state, "before the move")
        q_target = self.check_target(T_base_flange, motion, state.q, q_target)
        T = np.asarray(T_base_flange, dtype=float)
        if not self._call("isProgramRunning"):
            # A safety stop ends the script; its state package may trail the script flag by a cycle.
            time.sleep(0.02)
            self._raise_if_stopped(self.read(), "before the move")
            raise DeviceError(
                f"the ur_rtde control script is not running on {cfg.host} (after a protective stop?); call reconnect()"
            )
        self._stop_requested = False
        if motion == "linear":
            ok = self._call("moveL", to_ur_pose(T @ self._T_flange_tcp).tolist(), cfg.speed, cfg.acceleration, True)
        else:
            ok = self._call("moveJ", q_target.tolist(), cfg.joint_speed, cfg.joint_acceleration, True)
        if not ok:
            self._raise_if_stopped(self.read(), "the controller refused the move")
            raise DeviceError(f"UR controller {cfg.host} refused the {motion} move")
        state = self._wait_settled(motion)
        rot, dist = pose_error(state.T_base_flange, T)
        if dist > cfg.reach_tolerance or math.degrees(rot) > cfg.reach_tolerance_deg:
            raise DeviceError(
                f"UR robot {cfg.host} settled {dist * 1e3:.1f} mm / {math.degrees(rot):.2f} deg from the target"
            )
        return state

    def move_joints(self, q) -> RobotState:
        """moveJ to joint positions ``q`` (6,) rad, checked like `move_to` (target pose by nominal FK)."""
        try:
            q = kin.check_q(q, "q")
        except DeviceError as exc:
            raise LimitViolationError(str(exc)) from None
        if q.shape != (6,):
            raise LimitViolationError(f"q must have shape (6,), got {q.shape}")
        return self.move_to(kin.forward(q, self.config.model), motion="joint", q_target=q)

    def _wait_settled(self, motion: str) -> RobotState:
        cfg = self.config
        deadline = time.monotonic() + cfg.move_timeout
        still_since = None
        while True:
            state = self.read()
            self._raise_if_stopped(state, f"during the {motion} move")
            if self._stop_requested:
                raise DeviceError(f"{motion} move on {cfg.host} was interrupted by stop()")
            running = self._call("asyncRunning")
            now = time.monotonic()
            if not running and np.max(np.abs(state.qd)) < cfg.settle_speed:
                still_since = still_since or now
                if now - still_since >= cfg.settle_time:
                    return state
            else:
                still_since = None
            if now > deadline:
                self.stop()
                raise DeviceError(f"{motion} move on {cfg.host} did not settle within move_timeout={cfg.move_timeout} s")
            time.sleep(0.002)

    def stop(self) -> None:
        """Decelerate (stopL at ``stop_deceleration``) and stop any motion now.

        Raises
        ------
        DeviceError
            In read-only mode (nothing could be stopped from here).
        """
        self._require_control()
        self._stop_requested = True
        self._call("stopL", self.config.stop_deceleration, False)
