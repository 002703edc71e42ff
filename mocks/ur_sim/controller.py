"""State of the simulated UR controller: arm, safety, registers, script protocol.

No sockets here (see `handeye.mocks.ur_sim.server`). The server calls `tick` once per
control cycle (125 Hz CB3, 500 Hz e-Series) and reads `snapshot` values for
the RTDE output recipes; the RTDE input packages of the clients land in the
input registers via `write_inputs`.

The uploaded control script (ur_rtde's ``rtde_control.script``) is not
interpreted as URScript: the controller carries out its register protocol
instead. The client writes a command number to ``input_int_register_0`` with
arguments in the input registers; the script answers 1 (ready) / 2 (done) in
``output_int_register_0``, results in ``output_double_register_0..5`` and async
progress in ``output_int_register_2``. Supported commands: 1 movej, 2 movej_ik,
3 movel, 4 movel_fk, 33 stopl, 34 stopj, 40 get_tcp_offset, 46/30
get_inverse_kin, 47 is_steady, 255 stop script. Any other command is logged
as ``unsupported`` and acknowledged without effect.
"""

from __future__ import annotations

import math
import re
import threading
from enum import IntEnum

import numpy as np
from scipy.spatial.transform import Rotation

from handeye.calib.transforms import from_ur_pose, invert, to_ur_pose
from handeye.drivers.robot import ur_kinematics as kin
from handeye.mocks.ur_sim.motion import BrakeMotion, JointMotion, LinearMotion
from handeye.mocks.ur_sim.truth import SimRobotError, TrueArm

# UR enumerations (RTDE guide).
ROBOT_MODE_RUNNING = 7
SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP, SAFETY_ROBOT_EMERGENCY_STOP = 1, 3, 7
RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2
SAFETY_BIT_NORMAL, SAFETY_BIT_PROTECTIVE = 1 << 0, 1 << 2
SAFETY_BITS_EMERGENCY = (1 << 6) | (1 << 7)
STATUS_POWER_ON, STATUS_PROGRAM_RUNNING = 1 << 0, 1 << 1

class Command(IntEnum):
    """Command codes of ur_rtde's control script (``input_int_register_0``) that the simulator executes."""

    NONE = 0
    MOVEJ = 1
    MOVEJ_IK = 2
    MOVEL = 3
    MOVEL_FK = 4
    GET_INVERSE_KIN = 30  # with q_near
    PROTECTIVE_STOP = 31
    STOPL = 33
    STOPJ = 34
    GET_TCP_OFFSET = 40
    GET_INVERSE_KIN_AT_Q = 46  # near the current joints
    IS_STEADY = 47
    STOP_SCRIPT = 255

    @property
    def log_name(self) -> str:
        """Name in the command log (``get_inverse_kin`` for both inverse-kinematics calls)."""
        return "get_inverse_kin" if self is Command.GET_INVERSE_KIN_AT_Q else self.name.lower()


class Reply(IntEnum):
    """Script state the controller reports in ``output_int_register_0``."""

    IDLE = 0
    READY = 1  # signal_ready(): the next command may be written
    DONE = 2  # signal_done_with_cmd()


MOTION_CMDS = {Command.MOVEJ, Command.MOVEJ_IK, Command.MOVEL, Command.MOVEL_FK}
N_REGISTERS = 48


def _rotvec(R: np.ndarray) -> np.ndarray:
    """UR rotation vector of a rotation matrix; plain math except near 180 deg (scipy)."""
    c = (R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0
    th = math.acos(min(1.0, max(-1.0, c)))
    if th > math.pi - 1e-3:
        return Rotation.from_matrix(R).as_rotvec()
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return v * (0.5 if th < 1e-9 else th / (2.0 * math.sin(th)))


def parse_version(text: str) -> tuple[int, int, int, int]:
    """``"5.11"`` -> (5, 11, bugfix, build) with plausible defaults for the missing parts."""
    try:
        parts = [int(p) for p in str(text).split(".")]
    except ValueError as exc:
        raise ValueError(f"controller version must look like 5.11 or 3.15.7, got {text!r}") from exc
    if not 1 <= len(parts) <= 4 or parts[0] not in (3, 5):
        raise ValueError(f"controller version must be 3.x (CB3) or 5.x (e-Series), got {text!r}")
    defaults = [parts[0], 0, 1, 100000]
    return tuple(parts + defaults[len(parts) :])  # type: ignore[return-value]


class SimController:
    """One simulated UR arm and its controller.

    Parameters
    ----------
    model : str
        UR model name (``ur10``, ``ur5e`` ...), see `handeye.drivers.robot.ur_kinematics.UR_MODELS`.
    controller : str
        PolyScope version, e.g. ``"5.11"`` (e-Series, 500 Hz) or ``"3.15"`` (CB3, 125 Hz).
    initial_q : array_like, shape (6,)
        Start joint positions, rad.
    tcp_offset : array_like, shape (6,)
        Active TCP as a UR pose ``[x, y, z, rx, ry, rz]`` in the flange frame (m, rad).
    robot_error : SimRobotError, optional
        The arm's true kinematics differ from the nominal ones it reports
        through (`handeye.mocks.ur_sim.truth`); None: the nominal model is exact.
    """

    def __init__(self, model="ur10", controller="5.11", initial_q=None, tcp_offset=(0.0, 0.0, 0.1, 0.0, 0.0, 0.0),
                 robot_error: SimRobotError | None = None):
        kin.geometry(model)  # validates the name
        self.model = str(model).lower().replace("-", "")
        self.version = parse_version(controller)
        self.frequency = 500.0 if self.version[0] > 3 else 125.0
        self.dt = 1.0 / self.frequency
        self.limits = kin.UR_JOINT_LIMITS.copy()
        q = np.array([0.0, -1.2, 1.6, -1.97, -1.5708, 0.0]) if initial_q is None else np.asarray(initial_q, float)
        self.q = kin.check_q(q, "initial_q").copy()
        self.qd = np.zeros(6)
        self.tcp_offset = np.asarray(tcp_offset, dtype=float)
        self.T_flange_tcp = from_ur_pose(self.tcp_offset)
        self.lock = threading.RLock()
        self.ticks = 0
        self.safety_mode = SAFETY_NORMAL
        self.script_running = False
        self.script_uploads = 0
        self.reg_offset = 0
        self.in_int = np.zeros(N_REGISTERS, dtype=np.int64)
        self.in_double = np.zeros(N_REGISTERS)
        self.out_int = np.zeros(N_REGISTERS, dtype=np.int64)
        self.out_double = np.zeros(N_REGISTERS)
        self.external_force_torque = np.zeros(6)
        self.log: list[dict] = []
        self.motion = None
        self.motion_t0 = 0.0
        # A looping production program (handeye.mocks.ur_sim.program.Program) the controller runs by itself.
        self.program = None
        self.motion_async = False
        self.executing = False
        self.pending_done = False
        self.async_count = 0
        self.async_op = 0
        self.geometry = kin.geometry(self.model)
        self.true_arm = None if robot_error is None else TrueArm(self.model, robot_error)
        self._tcp_speed = np.zeros(6)
        self._refresh()

    # ------------------------------------------------------------------ state
    @property
    def timestamp(self) -> float:
        """Controller time, s since start (advances exactly ``dt`` per tick)."""
        return self.ticks * self.dt

    @property
    def T_base_flange(self) -> np.ndarray:
        return self._T_flange.copy()

    @property
    def T_base_flange_true(self) -> np.ndarray:
        """Where the flange really is (what a camera sees); `T_base_flange` is what the controller reports."""
        with self.lock:
            return self.T_base_flange if self.true_arm is None else self.true_arm.flange(self.q)

    @property
    def T_base_tcp(self) -> np.ndarray:
        return self._T_tcp.copy()

    def _refresh(self, T_tcp_prev: np.ndarray | None = None) -> None:
        """Recompute the cached kinematic state after ``q`` changed (once per tick)."""
        self._T_flange = kin.forward_one(self.q, self.geometry)
        self._T_tcp = self._T_flange @ self.T_flange_tcp
        self._tcp_pose = np.concatenate([self._T_tcp[:3, 3], _rotvec(self._T_tcp[:3, :3])])
        if T_tcp_prev is None:
            self._tcp_speed = np.zeros(6)
        else:
            lin = (self._T_tcp[:3, 3] - T_tcp_prev[:3, 3]) / self.dt
            dR = self._T_tcp[:3, :3] @ T_tcp_prev[:3, :3].T
            # one tick turns by far less than a degree: the small-angle vee is exact enough
            ang = 0.5 * np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]]) / self.dt
            self._tcp_speed = np.concatenate([lin, ang])

    @property
    def safety_status_bits(self) -> int:
        if self.safety_mode == SAFETY_PROTECTIVE_STOP:
            return SAFETY_BIT_PROTECTIVE
        if self.safety_mode == SAFETY_ROBOT_EMERGENCY_STOP:
            return SAFETY_BITS_EMERGENCY
        return SAFETY_BIT_NORMAL

    @property
    def robot_status_bits(self) -> int:
        return STATUS_POWER_ON | (STATUS_PROGRAM_RUNNING if self.script_running else 0)

    @property
    def runtime_state(self) -> int:
        return RUNTIME_PLAYING if self.script_running else RUNTIME_STOPPED

    def snapshot(self) -> dict:
        """Values of the RTDE output variables this simulator provides, except registers (see `register`)."""
        tcp, speed = self._tcp_pose, self._tcp_speed
        return {
            "timestamp": self.timestamp,
            "actual_q": self.q,
            "target_q": self.q,
            "actual_qd": self.qd,
            "target_qd": self.qd,
            "actual_TCP_pose": tcp,
            "target_TCP_pose": tcp,
            "actual_TCP_speed": speed,
            "target_TCP_speed": speed,
            "tcp_offset": self.tcp_offset,
            "robot_mode": ROBOT_MODE_RUNNING,
            "joint_mode": (253,) * 6,
            "safety_mode": self.safety_mode,
            "safety_status": self.safety_mode,
            "safety_status_bits": self.safety_status_bits,
            "robot_status_bits": self.robot_status_bits,
            "runtime_state": self.runtime_state,
            "speed_scaling": 1.0,
            "target_speed_fraction": 1.0,
            "actual_execution_time": 0.1,
            "actual_main_voltage": 48.0,
            "actual_robot_voltage": 48.0,
            "actual_robot_current": 0.5,
            "joint_temperatures": (30.0,) * 6,
            "payload": 0.0,
        }

    REGISTER_BANKS = ("output_int_register_", "output_double_register_", "input_int_register_",
                      "input_double_register_")

    def register(self, name: str):
        """Current value of an RTDE register variable (``output_int_register_3`` ...), or None."""
        for bank, arr in zip(self.REGISTER_BANKS, (self.out_int, self.out_double, self.in_int, self.in_double)):
            if name.startswith(bank):
                return arr[int(name[len(bank):])].item()
        return None

    # -------------------------------------------------------------- registers
    def write_inputs(self, values: dict) -> None:
        """Store one RTDE input package (name -> value) from a client."""
        with self.lock:
            for name, value in values.items():
                if name.startswith("input_int_register_"):
                    self.in_int[int(name.rsplit("_", 1)[1])] = int(value)
                elif name.startswith("input_double_register_"):
                    self.in_double[int(name.rsplit("_", 1)[1])] = float(value)
                elif name == "external_force_torque":
                    self.external_force_torque = np.asarray(value, dtype=float)

    def _in_i(self, i: int) -> int:
        return int(self.in_int[self.reg_offset + i])

    def _in_d(self, i: int, n: int = 1) -> np.ndarray:
        return self.in_double[self.reg_offset + i : self.reg_offset + i + n].copy()

    def _out_i(self, i: int, value: int) -> None:
        self.out_int[self.reg_offset + i] = value

    def _out_d(self, i: int, values) -> None:
        values = np.atleast_1d(values)
        self.out_double[self.reg_offset + i : self.reg_offset + i + len(values)] = values

    def _async_progress(self, running: bool) -> None:
        # Same bit layout as ur_rtde's script: bit 15 running, 16-23 change count, 24-30 op id.
        self.async_count = (self.async_count + 1) % 128
        if running:
            self.async_op = (self.async_op + 1) % 128
        value = self.async_count * 65536 + self.async_op * 16777216 + (32768 if running else 0)
        self._out_i(2, value)

    # ----------------------------------------------------------------- script
    def upload_script(self, text: str) -> None:
        """A program arrived on the script port: (re)start the control-script protocol."""
        with self.lock:
            self.script_uploads += 1
            name = text.split("def ", 1)[1].split("(", 1)[0].strip() if "def " in text else "?"
            self.log.append({"t": self.timestamp, "cmd": None, "name": f"upload:{name}", "args": []})
            if name != "rtde_control":
                return
            # ur_rtde injects the register offset (0, or 24 for the upper range).
            m = re.search(r"^\s*global\s+reg_offset_int\s*=\s*(\d+)", text, re.M)
            self.reg_offset = int(m.group(1)) if m else 0
            self._stop_motion(decel=None)
            self.script_running = True
            self.executing = False
            self.pending_done = False
            self._out_i(0, Reply.READY)

    def stop_script(self, reason: str) -> None:
        with self.lock:
            if self.script_running:
                self.log.append({"t": self.timestamp, "cmd": None, "name": f"script_stopped:{reason}", "args": []})
            self.script_running = False
            self.executing = False
            self.pending_done = False
            self._out_i(0, Reply.IDLE)
            if self.motion is not None and self.motion.kind != "stop":
                self._stop_motion(decel=None)

    # ----------------------------------------------------------------- safety
    def protective_stop(self, reason: str = "injected") -> None:
        with self.lock:
            self.log.append({"t": self.timestamp, "cmd": None, "name": f"protective_stop:{reason}", "args": []})
            self.safety_mode = SAFETY_PROTECTIVE_STOP
            self._halt()

    def emergency_stop(self) -> None:
        with self.lock:
            self.log.append({"t": self.timestamp, "cmd": None, "name": "emergency_stop", "args": []})
            self.safety_mode = SAFETY_ROBOT_EMERGENCY_STOP
            self._halt()

    def unlock(self) -> bool:
        """Dashboard ``unlock protective stop`` / releasing the e-stop; False if not stopped."""
        with self.lock:
            if self.safety_mode == SAFETY_NORMAL:
                return False
            self.safety_mode = SAFETY_NORMAL
            return True

    def _halt(self) -> None:
        # A safety stop freezes the arm where it is and stops the program.
        self.motion = None
        self.qd = np.zeros(6)
        self._tcp_speed = np.zeros(6)
        self.stop_script("safety stop")

    # ---------------------------------------------------------------- motions
    def _start_motion(self, motion, asynchronous: bool) -> None:
        self.motion, self.motion_t0, self.motion_async = motion, self.timestamp, asynchronous
        if asynchronous:
            self._async_progress(True)
        self.pending_done = not asynchronous

    def _stop_motion(self, decel: float | None, linear: bool = False) -> None:
        """Decelerate to rest (``decel`` rad/s^2 or m/s^2 for stopl; None: controller default)."""
        if self.motion is None:
            return
        qd = self.qd.copy()
        if linear:
            v_tcp = float(np.linalg.norm(self._tcp_speed[:3]))
            duration = v_tcp / (decel or 1.2) if v_tcp > 1e-6 else np.max(np.abs(qd)) / 4.0
        else:
            duration = np.max(np.abs(qd)) / (decel or 4.0)
        was_async = self.motion_async and self.motion.kind != "stop"
        self.motion, self.motion_t0 = BrakeMotion(self.q, qd, duration), self.timestamp
        if was_async:
            self._async_progress(False)
        self.motion_async = False

    def _process(self, code: int) -> None:
        """Start one script command (the register protocol of rtde_control.script)."""
        try:
            cmd = Command(code)
        except ValueError:
            cmd = None
        name = "unsupported" if cmd is None else cmd.log_name
        args = self._in_d(0, 8).tolist()
        self.log.append({"t": self.timestamp, "cmd": code, "name": name, "args": args})
        if cmd in MOTION_CMDS:
            target = self._in_d(0, 6)
            v, a = float(self._in_d(6)[0]), float(self._in_d(7)[0])
            asynchronous = self._in_i(1) == 1
            if cmd is Command.MOVEJ_IK:
                q1 = kin.inverse_nearest(from_ur_pose(target) @ invert(self.T_flange_tcp), self.q, self.model, self.limits)
                if q1 is None:
                    self.protective_stop("movej_ik: no inverse kinematics solution")
                    return
                target, cmd = q1, Command.MOVEJ
            if cmd is Command.MOVEL_FK:
                target, cmd = to_ur_pose(kin.forward(target, self.model) @ self.T_flange_tcp), Command.MOVEL
            if v <= 0 or a <= 0:
                self.protective_stop(f"{name}: speed and acceleration must be positive")
                return
            if cmd is Command.MOVEJ:
                if np.any(target < self.limits[:, 0]) or np.any(target > self.limits[:, 1]):
                    self.protective_stop("movej: target outside joint limits")
                    return
                motion = JointMotion(self.q, target, v, a)
            else:
                motion = LinearMotion(self.q, from_ur_pose(target), v, a, self.model, self.T_flange_tcp, self.limits)
            self._start_motion(motion, asynchronous)
        elif cmd in (Command.STOPL, Command.STOPJ):
            self._stop_motion(decel=float(self._in_d(0)[0]) or None, linear=cmd is Command.STOPL)
        elif cmd is Command.GET_TCP_OFFSET:
            self._out_d(0, self.tcp_offset)
        elif cmd in (Command.GET_INVERSE_KIN, Command.GET_INVERSE_KIN_AT_Q):
            pose = self._in_d(0, 6)
            q_near = self._in_d(6, 6) if cmd is Command.GET_INVERSE_KIN else self.q
            q = kin.inverse_nearest(from_ur_pose(pose) @ invert(self.T_flange_tcp), q_near, self.model, self.limits)
            if q is None:
                self.stop_script("get_inverse_kin: no solution")
                return
            self._out_d(0, q)
        elif cmd is Command.IS_STEADY:
            self._out_i(1, int(self.motion is None))
        elif cmd is Command.PROTECTIVE_STOP:
            self.protective_stop("triggerProtectiveStop")
            return
        if not self.pending_done:
            self._out_i(0, Reply.DONE)

    def tick(self) -> None:
        """Advance one control cycle: script protocol, then arm motion."""
        with self.lock:
            self.ticks += 1
            if self.script_running:
                cmd = self._in_i(0)
                if cmd == Command.STOP_SCRIPT:
                    self.log.append({"t": self.timestamp, "cmd": int(Command.STOP_SCRIPT), "name": "stop_script",
                                     "args": []})
                    self.stop_script("stopScript")
                elif not self.executing:
                    if cmd != Command.NONE:
                        self.executing = True
                        self._process(cmd)
                elif cmd == Command.NONE and not self.pending_done and self.script_running:
                    self.executing = False
                    self._out_i(0, Reply.READY)
            elif self.program is not None and self.safety_mode == SAFETY_NORMAL:
                self.program.tick(self)
            self._advance()

    def _advance(self) -> None:
        if self.motion is None:
            if self.qd.any():
                self.qd = np.zeros(6)
                self._tcp_speed = np.zeros(6)
            return
        t = self.timestamp - self.motion_t0
        q = self.motion.q_at(t)
        if q is None:
            self.protective_stop(f"{self.motion.kind}: {self.motion.failure}")
            return
        if np.any(q < self.limits[:, 0]) or np.any(q > self.limits[:, 1]):
            self.protective_stop("joint limit")
            return
        self.qd = (q - self.q) / self.dt
        self.q = q
        self._refresh(self._T_tcp)
        if t >= self.motion.duration:
            finished = self.motion
            self.motion = None
            if self.true_arm is not None:
                self.true_arm.new_stop()
            if self.motion_async and finished.kind != "stop":
                self._async_progress(False)
            if self.pending_done and self.script_running:
                self.pending_done = False
                self._out_i(0, Reply.DONE)

    # ------------------------------------------------------------------ tools
    def set_q(self, q) -> None:
        """Teleport the idle arm (test setup); refused while moving."""
        with self.lock:
            if self.motion is not None:
                raise ValueError("cannot set q while the arm moves")
            self.q = kin.check_q(q).copy()
            self._refresh()

    def state(self) -> dict:
        """Ground truth for tests and the demo (JSON-serialisable)."""
        with self.lock:
            return {
                "model": self.model,
                "version": list(self.version),
                "frequency": self.frequency,
                "timestamp": self.timestamp,
                "q": self.q.tolist(),
                "qd": self.qd.tolist(),
                "T_base_flange": self.T_base_flange.tolist(),
                "T_base_flange_true": self.T_base_flange_true.tolist(),
                "kinematics": None if self.true_arm is None else self.true_arm.state(),
                "T_base_tcp": self.T_base_tcp.tolist(),
                "tcp_offset": self.tcp_offset.tolist(),
                "moving": self.motion is not None,
                "safety_mode": self.safety_mode,
                "script_running": self.script_running,
                "script_uploads": self.script_uploads,
                "program": None if self.program is None else self.program.state(),
                "commands": list(self.log),
            }
