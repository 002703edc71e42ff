"""Network side of the simulated UR controller: RTDE (30004), dashboard (29999), script (30003).

One process, one thread per connection plus the control loop in the main
thread, which ticks the `SimController` at the controller rate and pushes
RTDE data packages. Sends to RTDE clients never block the loop: a client
that stops reading has its packages queued, and its connection is closed
once the queue passes 1 MB (a real controller also hangs up on clients that
do not drain the socket).

Simulator-only dashboard commands (fault injection and ground truth), one
line each, answered with one line:

``sim state``                 JSON ground truth (q, T_base_flange, tcp_offset, command log ...)
``sim truth``                 JSON true ``T_base_flange`` (4x4): differs from the reported one with a robot error
``sim clear_log``             empty the command log
``sim protective_stop``       enter a protective stop (undo: ``unlock protective stop``)
``sim emergency_stop``        enter a robot emergency stop (undo: ``sim release``)
``sim release``               leave an emergency stop
``sim drop <seconds>``        close every client connection and refuse new ones for <seconds>
``sim freeze <seconds>``      keep connections open but send no RTDE data for <seconds>
``sim set_q q1 ... q6``       teleport the idle arm (rad)
``sim program <json>``        run a looping production program (`handeye.mocks.ur_sim.program`)
``sim program stop``          end it (the arm finishes its current motion)
``sim owner``                 JSON ``{"pid": ..., "parent_pid": ...}``: this simulator and the process that launched
                              it (``--parent-pid``; null when started by hand), for a second run that finds its
                              ports taken
"""

from __future__ import annotations

import json
import logging
import os
import re
import socket
import struct
import threading
import time
from enum import IntEnum

from handeye.mocks.ur_sim.controller import SimController

log = logging.getLogger("ur_sim")

PORT_DASHBOARD, PORT_SCRIPT, PORT_RTDE = 29999, 30003, 30004
MAX_QUEUE_BYTES = 1 << 20

class MessageType(IntEnum):
    """RTDE package types (RTDE guide), one ASCII letter each."""

    REQUEST_PROTOCOL_VERSION = ord("V")
    GET_URCONTROL_VERSION = ord("v")
    TEXT_MESSAGE = ord("M")
    DATA_PACKAGE = ord("U")
    CONTROL_PACKAGE_SETUP_OUTPUTS = ord("O")
    CONTROL_PACKAGE_SETUP_INPUTS = ord("I")
    CONTROL_PACKAGE_START = ord("S")
    CONTROL_PACKAGE_PAUSE = ord("P")


TYPE_FMT = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}

# Standard RTDE output variables (subset of the RTDE guide that ur_rtde decodes).
OUTPUT_TYPES = {
    "timestamp": "DOUBLE",
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "runtime_state": "UINT32",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "actual_digital_input_bits": "UINT64",
    "actual_digital_output_bits": "UINT64",
    "actual_tool_accelerometer": "VECTOR3D",
    "payload_cog": "VECTOR3D",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
}
for _name in (
    "target_q target_qd target_qdd target_current target_moment actual_q actual_qd actual_current "
    "actual_current_as_torque joint_control_output actual_TCP_pose actual_TCP_speed actual_TCP_force "
    "target_TCP_pose target_TCP_speed joint_temperatures actual_joint_voltage ft_raw_wrench "
    "payload_inertia tcp_offset"
).split():
    OUTPUT_TYPES[_name] = "VECTOR6D"
for _name in (
    "speed_scaling target_speed_fraction actual_momentum actual_main_voltage actual_robot_voltage "
    "actual_robot_current standard_analog_input0 standard_analog_input1 standard_analog_output0 "
    "standard_analog_output1 payload"
).split():
    OUTPUT_TYPES[_name] = "DOUBLE"

INPUT_TYPES = {
    "external_force_torque": "VECTOR6D",
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
}
for _i in range(48):
    INPUT_TYPES[f"input_int_register_{_i}"] = "INT32"
    INPUT_TYPES[f"input_double_register_{_i}"] = "DOUBLE"
    OUTPUT_TYPES[f"output_int_register_{_i}"] = "INT32"
    OUTPUT_TYPES[f"output_double_register_{_i}"] = "DOUBLE"
    # The controller also echoes input registers as outputs.
    OUTPUT_TYPES[f"input_int_register_{_i}"] = "INT32"
    OUTPUT_TYPES[f"input_double_register_{_i}"] = "DOUBLE"


def _width(type_name: str) -> int:
    fmt = TYPE_FMT[type_name]
    return int(fmt[:-1]) if len(fmt) > 1 else 1


def _zero(type_name: str):
    n = _width(type_name)
    return [0] * n if n > 1 else 0


def _frame(msg_type: int, payload: bytes = b"") -> bytes:
    return struct.pack(">HB", len(payload) + 3, msg_type) + payload


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("peer closed")
        buf += chunk
    return bytes(buf)


class Connection:
    """A client socket of any of the three servers; sends are serialised and non-blocking."""

    def __init__(self, server: "SimServer", sock: socket.socket, port: int):
        self.server, self.sock, self.port = server, sock, port
        self.queue = bytearray()
        self.send_lock = threading.Lock()
        self.closed = False

    def send(self, data: bytes) -> None:
        with self.send_lock:
            if self.closed:
                return
            self.queue += data
            try:
                while self.queue:
                    n = self.sock.send(self.queue, socket.MSG_DONTWAIT)
                    del self.queue[:n]
            except BlockingIOError:
                if len(self.queue) > MAX_QUEUE_BYTES:
                    log.warning("client on %d does not read; closing", self.port)
                    self.close()
            except OSError:
                self.close()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()
        self.server.forget(self)


class RTDEConnection(Connection):
    """RTDE protocol v1/v2 server side for one client."""

    def __init__(self, server, sock, port):
        super().__init__(server, sock, port)
        self.out_names: list[str] = []
        self.out_struct: struct.Struct | None = None
        self.out_every = 1
        self.out_vector: list[bool] = []
        self.out_register: list[bool] = []
        self.last_sent = -(10**9)
        self.in_recipes: dict[int, tuple[list[str], struct.Struct]] = {}
        self.next_in_id = 1
        self.started = False
        self.protocol = 1

    def serve(self) -> None:
        try:
            while not self.closed:
                size, msg_type = struct.unpack(">HB", _recv_exact(self.sock, 3))
                body = _recv_exact(self.sock, size - 3) if size > 3 else b""
                self.handle(msg_type, body)
        except (ConnectionError, OSError, struct.error):
            pass
        finally:
            self.close()

    def handle(self, msg_type: int, body: bytes) -> None:
        ctl = self.server.controller
        if msg_type == MessageType.REQUEST_PROTOCOL_VERSION:
            (version,) = struct.unpack(">H", body[:2])
            ok = version in (1, 2)
            self.protocol = version if ok else self.protocol
            self.send(_frame(MessageType.REQUEST_PROTOCOL_VERSION, struct.pack(">B", int(ok))))
        elif msg_type == MessageType.GET_URCONTROL_VERSION:
            self.send(_frame(MessageType.GET_URCONTROL_VERSION, struct.pack(">IIII", *ctl.version)))
        elif msg_type == MessageType.CONTROL_PACKAGE_SETUP_OUTPUTS:
            freq = struct.unpack(">d", body[:8])[0] if self.protocol >= 2 else ctl.frequency
            names = [n for n in body[8 if self.protocol >= 2 else 0 :].decode().split(",") if n]
            types = [OUTPUT_TYPES.get(n, "NOT_FOUND") for n in names]
            if "NOT_FOUND" not in types:
                self.out_names = names
                self.out_struct = struct.Struct(">B" + "".join(TYPE_FMT[t] for t in types))
                self.out_vector = [_width(t) > 1 for t in types]
                self.out_register = [ctl.register(n) is not None for n in names]
                freq = min(max(freq, 1.0), ctl.frequency)
                self.out_every = max(1, int(round(ctl.frequency / freq)))
            self.send(_frame(MessageType.CONTROL_PACKAGE_SETUP_OUTPUTS,
                             struct.pack(">B", 1 if "NOT_FOUND" not in types else 0) + ",".join(types).encode()))
        elif msg_type == MessageType.CONTROL_PACKAGE_SETUP_INPUTS:
            names = [n for n in body.decode().split(",") if n]
            types = [INPUT_TYPES.get(n, "NOT_FOUND") for n in names]
            in_use = self.server.claim_inputs(self, names)
            types = ["IN_USE" if n in in_use else t for n, t in zip(names, types)]
            recipe_id = 0
            if not in_use and "NOT_FOUND" not in types:
                recipe_id = self.next_in_id
                self.next_in_id += 1
                self.in_recipes[recipe_id] = (names, struct.Struct(">B" + "".join(TYPE_FMT[t] for t in types)))
            self.send(_frame(MessageType.CONTROL_PACKAGE_SETUP_INPUTS,
                             struct.pack(">B", recipe_id) + ",".join(types).encode()))
        elif msg_type == MessageType.CONTROL_PACKAGE_START:
            self.started = self.out_struct is not None or bool(self.in_recipes)
            self.send(_frame(MessageType.CONTROL_PACKAGE_START, struct.pack(">B", int(self.started))))
        elif msg_type == MessageType.CONTROL_PACKAGE_PAUSE:
            self.started = False
            self.send(_frame(MessageType.CONTROL_PACKAGE_PAUSE, struct.pack(">B", 1)))
        elif msg_type == MessageType.DATA_PACKAGE and body:
            recipe = self.in_recipes.get(body[0])
            if recipe is None or len(body) < recipe[1].size:
                log.warning("input package for unknown recipe %d or too short (%d bytes)", body[0], len(body))
                return
            names, st = recipe
            flat = st.unpack_from(body)[1:]
            values, k = {}, 0
            for n in names:
                width = _width(INPUT_TYPES[n])
                values[n] = flat[k] if width == 1 else list(flat[k : k + width])
                k += width
            ctl.write_inputs(values)

    def push(self, tick: int, snapshot: dict) -> None:
        """Send one data package if this client subscribed and is due at ``tick``."""
        if not self.started or self.out_struct is None or tick - self.last_sent < self.out_every:
            return
        self.last_sent = tick
        ctl = self.server.controller
        flat: list = [1]
        for name, vector, register in zip(self.out_names, self.out_vector, self.out_register):
            val = ctl.register(name) if register else snapshot.get(name)
            if val is None:
                val = _zero(OUTPUT_TYPES[name])
            if vector:
                flat.extend(val)
            else:
                flat.append(val)
        self.send(_frame(MessageType.DATA_PACKAGE, self.out_struct.pack(*flat)))


class SimServer:
    """Listeners + connections + control loop around one `SimController`."""

    def __init__(self, host: str, controller: SimController):
        self.host, self.controller = host, controller
        self.conns: set[Connection] = set()
        self.conns_lock = threading.Lock()
        self.listeners: dict[int, socket.socket] = {}
        self.input_owner: dict[str, Connection] = {}
        self.freeze_until = 0.0
        self.refuse_until = 0.0
        # Set by the signal handler of `handeye.mocks.ur_sim.main`: a plain attribute store is all a
        # handler may do (an Event.set() there deadlocks when a second signal interrupts the first
        # handler inside the Event's lock, e.g. one SIGTERM per exiting thread of a dying parent).
        self.stopping = False
        self.parent_pid: int | None = None

    # ---------------------------------------------------------- connections
    def open_listeners(self) -> None:
        """Bind and listen on the three UR ports (all or none; OSError if one cannot be bound)."""
        try:
            for port in (PORT_DASHBOARD, PORT_SCRIPT, PORT_RTDE):
                ls = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                ls.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                self.listeners[port] = ls
                ls.bind((self.host, port))
                ls.listen(8)
        except OSError:
            self.close_listeners()
            raise
        for port, ls in self.listeners.items():
            threading.Thread(target=self._accept, args=(ls, port), daemon=True).start()

    def close_listeners(self) -> None:
        for ls in self.listeners.values():
            try:
                ls.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            ls.close()
        self.listeners.clear()

    def _accept(self, ls: socket.socket, port: int) -> None:
        while True:
            try:
                sock, _ = ls.accept()
            except OSError:
                return
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            if port == PORT_RTDE:
                conn: Connection = RTDEConnection(self, sock, port)
                target = conn.serve
            elif port == PORT_DASHBOARD:
                conn = Connection(self, sock, port)
                target = lambda c=conn: self._serve_dashboard(c)  # noqa: E731
            else:
                conn = Connection(self, sock, port)
                target = lambda c=conn: self._serve_script(c)  # noqa: E731
            with self.conns_lock:
                self.conns.add(conn)
            threading.Thread(target=target, daemon=True).start()

    def forget(self, conn: Connection) -> None:
        with self.conns_lock:
            self.conns.discard(conn)
            for name in [n for n, c in self.input_owner.items() if c is conn]:
                del self.input_owner[name]

    def claim_inputs(self, conn: Connection, names: list[str]) -> set[str]:
        """Reserve input variables for ``conn``; returns those another live client holds."""
        with self.conns_lock:
            taken = {n for n in names if self.input_owner.get(n, conn) is not conn}
            if not taken:
                for n in names:
                    self.input_owner[n] = conn
            return taken

    def drop_all(self, refuse_s: float) -> None:
        """Fault: every connection drops; the ports refuse connections for ``refuse_s``."""
        # refuse_until first: the control loop reopens closed listeners once it has passed.
        self.refuse_until = time.monotonic() + refuse_s
        self.close_listeners()
        with self.conns_lock:
            conns = list(self.conns)
        for c in conns:
            c.close()

    # ------------------------------------------------------------ dashboard
    def _serve_dashboard(self, conn: Connection) -> None:
        conn.send(b"Connected: Universal Robots Dashboard Server\n")
        f = conn.sock.makefile("rb")
        try:
            for raw in f:
                line = raw.decode(errors="replace").strip()
                reply, after = self.dashboard(line)
                conn.send((reply + "\n").encode())
                if after is not None:
                    after()
                if line == "quit":
                    break
        except (OSError, ValueError):
            pass
        finally:
            conn.close()

    def dashboard(self, line: str):
        """Answer one dashboard line; returns (reply, action to run after replying or None)."""
        ctl = self.controller
        low = line.lower()
        major, minor, bugfix, build = ctl.version
        if low.startswith("sim "):
            return self._sim_command(line[4:].split())
        if low == "polyscopeversion":
            return f"URSoftware {major}.{minor}.{bugfix}.{build} (Jan 01 2024)", None
        if low == "get serial number":
            return "20235500001", None
        if low == "is in remote control":
            return "true", None
        if low == "get robot model":
            return ctl.model.upper().rstrip("E") + ("e" if ctl.model.endswith("e") else ""), None
        if low == "robotmode":
            return "Robotmode: RUNNING", None
        if low in ("safetymode", "safetystatus"):
            name = {1: "NORMAL", 3: "PROTECTIVE_STOP", 7: "ROBOT_EMERGENCY_STOP"}[ctl.safety_mode]
            return f"{'Safetymode' if low == 'safetymode' else 'Safetystatus'}: {name}", None
        if low == "unlock protective stop":
            if ctl.safety_mode == 3 and ctl.unlock():
                return "Protective stop releasing", None
            return "Cannot unlock protective stop, robot is not in protective stop", None
        if low == "stop":
            ctl.stop_script("dashboard stop")
            return "Stopped", None
        if low == "running":
            return f"Program running: {str(ctl.script_running).lower()}", None
        if low == "programstate":
            return ("PLAYING rtde_control" if ctl.script_running else "STOPPED <unnamed>"), None
        if low in ("power on", "brake release", "close popup", "close safety popup") or low.startswith("popup"):
            return {"power on": "Powering on", "brake release": "Brake releasing"}.get(low, "closing popup"), None
        if low == "quit":
            return "Disconnected", None
        return f"could not understand: '{line}'", None

    def _sim_command(self, words: list[str]):
        ctl = self.controller
        cmd = words[0] if words else ""
        try:
            if cmd == "state":
                return json.dumps(ctl.state()), None
            if cmd == "truth":
                return json.dumps(ctl.T_base_flange_true.tolist()), None
            if cmd == "clear_log":
                with ctl.lock:
                    ctl.log.clear()
                return "ok", None
            if cmd == "protective_stop":
                ctl.protective_stop()
                return "ok", None
            if cmd == "emergency_stop":
                ctl.emergency_stop()
                return "ok", None
            if cmd == "release":
                ctl.unlock()
                return "ok", None
            if cmd == "freeze":
                self.freeze_until = time.monotonic() + float(words[1])
                return "ok", None
            if cmd == "drop":
                seconds = float(words[1]) if len(words) > 1 else 0.0
                return "ok", lambda: self.drop_all(seconds)
            if cmd == "program":
                return self._program_command(" ".join(words[1:])), None
            if cmd == "owner":
                return json.dumps({"pid": os.getpid(), "parent_pid": self.parent_pid}), None
            if cmd == "set_q":
                ctl.set_q([float(w) for w in words[1:7]])
                return "ok", None
        except (IndexError, ValueError) as exc:
            return f"error: {exc}", None
        return f"error: unknown sim command {cmd!r}", None

    def _program_command(self, arg: str) -> str:
        from handeye.mocks.ur_sim.program import Program

        ctl = self.controller
        if arg == "stop":
            with ctl.lock:
                ctl.program = None
            return "ok"
        try:
            program = Program.from_dict(json.loads(arg))
        except ValueError as exc:  # json.JSONDecodeError is a ValueError too
            return f"error: {exc}"
        with ctl.lock:
            ctl.program = program
        return "ok"

    # --------------------------------------------------------------- script
    def _serve_script(self, conn: Connection) -> None:
        buf = ""
        try:
            while True:
                chunk = conn.sock.recv(65536)
                if not chunk:
                    break
                buf += chunk.decode(errors="replace")
                # A program is complete at a top-level (unindented) ``end`` line.
                m = re.search(r"^end[ \t]*$", buf, re.M)
                while m:
                    self.controller.upload_script(buf[: m.end()])
                    buf = buf[m.end() :].lstrip("\n")
                    m = re.search(r"^end[ \t]*$", buf, re.M)
        except OSError:
            pass
        finally:
            conn.close()

    # ---------------------------------------------------------- control loop
    def run(self) -> None:
        """Tick until `stopping` is set (SIGINT/SIGTERM in `handeye.mocks.ur_sim.main`) or, when
        ``parent_pid`` is set, until that process is no longer our parent (it died: we were
        re-parented), so that no simulator outlives the test run or app that started it.

        Controller time stays locked to the wall clock: when the process was
        starved, the missed ticks are simulated at once and only the newest
        state is sent (a real controller also skips packages it cannot send).
        """
        ctl = self.controller
        t0 = time.perf_counter() - ctl.ticks * ctl.dt
        next_parent_check = 0.0
        while not self.stopping:
            due = int((time.perf_counter() - t0) / ctl.dt) - ctl.ticks
            for _ in range(min(max(due, 1), 50)):
                ctl.tick()
            if due > 50:  # hopelessly behind (suspended process): drop the backlog
                t0 = time.perf_counter() - ctl.ticks * ctl.dt
            now_m = time.monotonic()
            if self.parent_pid is not None and now_m >= next_parent_check:
                next_parent_check = now_m + 0.1
                if os.getppid() != self.parent_pid:
                    log.warning("parent process %d is gone; stopping", self.parent_pid)
                    break
            if not self.listeners and now_m >= self.refuse_until:
                try:
                    self.open_listeners()
                except OSError as exc:  # e.g. another process took the address meanwhile: retry
                    log.warning("cannot reopen the ports on %s: %s", self.host, exc)
                    self.refuse_until = now_m + 0.5
            if now_m >= self.freeze_until:
                with self.conns_lock:
                    rtde = [c for c in self.conns if isinstance(c, RTDEConnection) and c.started]
                if rtde:
                    with ctl.lock:
                        snap = ctl.snapshot()
                        for c in rtde:
                            c.push(ctl.ticks, snap)
            delay = t0 + (ctl.ticks + 1) * ctl.dt - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        self.close_listeners()
        with self.conns_lock:
            conns = list(self.conns)
        for c in conns:
            c.close()
