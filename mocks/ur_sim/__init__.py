"""Simulated Universal Robots controller speaking RTDE, dashboard and script ports.

Run it in the foreground (until SIGINT/SIGTERM)::

    python -m handeye.mocks.ur_sim --host 127.0.0.2 --model ur10 --controller 5.11

and point the UR driver (``handeye.drivers.robot.ur.URRobot``) or any ur_rtde client
at ``127.0.0.2``. It has to be a separate process: ur_rtde's constructors
hold the GIL while they wait for the controller's answers.

From Python (tests, demo), `launch` starts it as a subprocess and waits until
the ports accept connections::

    with launch("127.0.0.2", model="ur10", controller="5.11") as sim:
        ...                       # drive it with ur_rtde / URRobot
        sim.state()["T_base_flange"]   # ground truth
        sim.protective_stop()     # fault injection, see handeye.mocks.ur_sim.server
"""

from __future__ import annotations

import argparse
import collections
import json
import logging
import os
import shlex
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from handeye.drivers.errors import DeviceError

__all__ = ["main", "add_arguments", "run", "launch", "SimProcess", "PortsTakenError", "dashboard"]


class PortsTakenError(DeviceError):
    """The simulator cannot bind its address: another simulator (or another program) holds its ports."""


def main(argv: list[str] | None = None) -> int:
    """Command line entry: run one simulated controller in the foreground; returns the exit code."""
    ap = argparse.ArgumentParser(prog="python -m handeye.mocks.ur_sim", description=__doc__.splitlines()[0])
    add_arguments(ap)
    ap.add_argument("-v", "--verbose", action="store_true")
    return run(ap.parse_args(argv))


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The simulator's options (``handeye sim-robot`` lists them in its --help too)."""
    ap.add_argument("--host", default="127.0.0.1", help="address to bind (ports 29999, 30003, 30004)")
    ap.add_argument("--model", default="ur10", help="ur3, ur5, ur10, ur3e, ur5e, ur10e, ur16e")
    ap.add_argument("--controller", default="5.11", help="PolyScope version: 3.x = CB3 (125 Hz), 5.x = e-Series (500 Hz)")
    ap.add_argument("--initial-q", type=float, nargs=6, metavar="Q", help="start joint positions, rad")
    ap.add_argument("--tcp-offset", type=float, nargs=6, metavar="P", default=[0.0, 0.0, 0.1, 0.0, 0.0, 0.0],
                    help="active TCP in the flange frame: x y z (m) rx ry rz (rad)")
    ap.add_argument("--robot-error", metavar="JSON",
                    help="the arm's true kinematics differ from the nominal ones "
                    "(JSON of handeye.mocks.ur_sim.truth.SimRobotError)")
    ap.add_argument("--program", help="JSON file: a looping production program to run (handeye.mocks.ur_sim.program)")
    ap.add_argument("--parent-pid", type=int, metavar="PID",
                    help="stop as soon as this process is no longer our parent (it died); SIGINT is then "
                    "ignored (the parent stops the simulator with SIGTERM)")


def run(args: argparse.Namespace) -> int:
    """Run one simulated controller in the foreground with the options of `add_arguments` (and ``verbose``)
    until SIGINT or SIGTERM; returns the exit code."""
    from handeye.mocks.ur_sim.controller import SimController
    from handeye.mocks.ur_sim.server import SimServer

    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="ur_sim: %(message)s")
    try:
        robot_error = None
        if args.robot_error:
            from handeye.mocks.ur_sim.truth import SimRobotError

            robot_error = SimRobotError.model_validate(json.loads(args.robot_error))
        ctl = SimController(args.model, args.controller, args.initial_q, args.tcp_offset, robot_error)
    except Exception as exc:  # bad model / version: one line, exit 2 like argparse
        print(f"ur_sim: {exc}", file=sys.stderr)
        return 2
    if args.program:
        from handeye.mocks.ur_sim.program import Program

        try:
            with open(args.program) as f:
                ctl.program = Program.from_dict(json.load(f))
        except (OSError, ValueError) as exc:
            print(f"ur_sim: --program {args.program}: {exc}", file=sys.stderr)
            return 2
    server = SimServer(args.host, ctl)
    server.parent_pid = args.parent_pid
    if args.parent_pid is not None and os.getppid() != args.parent_pid:
        print(f"ur_sim: parent process {args.parent_pid} is already gone", file=sys.stderr)
        return 1
    try:
        server.open_listeners()
    except OSError as exc:
        print(f"ur_sim: cannot bind {args.host}: {exc}", file=sys.stderr)
        return 1

    def _stop(*_):
        server.stopping = True  # async-signal-safe: no lock, re-entry harmless (see SimServer.stopping)

    if threading.current_thread() is threading.main_thread():
        # A launched simulator (--parent-pid) is stopped by its parent, with SIGTERM, after the parent
        # has stopped the robot: a Ctrl-C meant for the parent (a terminal's, or a service manager's
        # KillSignal=SIGINT to the whole group) must not take the controller away first.
        signal.signal(signal.SIGINT, _stop if args.parent_pid is None else signal.SIG_IGN)
        signal.signal(signal.SIGTERM, _stop)
    print(f"ur_sim ready on {args.host}: {ctl.model} controller {'.'.join(map(str, ctl.version))} "
          f"at {ctl.frequency:.0f} Hz", flush=True)
    server.run()
    if threading.current_thread() is threading.main_thread():
        # Stopping: more signals of the storm that stopped it (one per exiting thread of a dying parent) are
        # ignored. Python puts back the default action of a signal it handles when it shuts down, and one landing
        # then killed the simulator (exit -15 instead of 0, 1 run of the suite in 3 with two workers).
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return 0


def dashboard(host: str, line: str, timeout: float = 5.0) -> str:
    """Send one line to the dashboard port (29999) of the controller on ``host`` on a fresh connection and
    return the one-line answer (``"sim truth"``, ``"sim state"``: the simulator's own commands)."""
    with socket.create_connection((host, 29999), timeout=timeout) as s:
        f = s.makefile("rb")
        f.readline()  # greeting
        s.sendall(line.encode() + b"\n")
        return f.readline().decode().strip()


class SimProcess:
    """Handle on a simulator subprocess started by `launch`.

    Attributes
    ----------
    host : str
    proc : subprocess.Popen
    log_tail : deque of str
        The simulator's last output lines (warnings go to stderr).
    """

    def __init__(self, host: str, proc: subprocess.Popen):
        self.host, self.proc = host, proc
        # Drain the pipes so a chatty simulator never blocks on a full pipe; keep the
        # last lines of stderr for diagnostics.
        self.log_tail: collections.deque[str] = collections.deque(maxlen=50)
        for stream in (proc.stdout, proc.stderr):
            threading.Thread(target=self._drain, args=(stream,), daemon=True).start()

    def _drain(self, stream) -> None:
        for line in stream:
            self.log_tail.append(line.rstrip())

    def command(self, line: str, timeout: float = 5.0) -> str:
        """Send one dashboard line on a fresh connection and return the one-line answer."""
        return dashboard(self.host, line, timeout)

    def state(self) -> dict:
        """Ground truth: q, T_base_flange, tcp_offset, command log, script uploads ..."""
        return json.loads(self.command("sim state"))

    def true_flange_pose(self):
        """Where the flange really is, ``T_base_flange`` (4, 4) ndarray: the reported pose unless the
        simulator was given a robot error (``robot_error`` of `launch`)."""
        try:
            return np.array(json.loads(self.command("sim truth")), dtype=float)
        except (OSError, ValueError) as exc:
            raise DeviceError(f"simulated UR controller on {self.host}: no true flange pose: {exc}") from None

    def clear_log(self) -> None:
        self.command("sim clear_log")

    def protective_stop(self) -> None:
        self.command("sim protective_stop")

    def unlock_protective_stop(self) -> None:
        self.command("unlock protective stop")

    def drop(self, refuse_s: float = 0.0) -> None:
        """Close every connection; refuse new ones for ``refuse_s`` seconds."""
        self.command(f"sim drop {refuse_s}")

    def freeze(self, seconds: float) -> None:
        """Stop sending RTDE data for ``seconds`` while keeping the connections open."""
        self.command(f"sim freeze {seconds}")

    def set_q(self, q) -> None:
        self.command("sim set_q " + " ".join(f"{x:.12g}" for x in q))

    def start_program(self, program: dict) -> None:
        """Run a looping production program (JSON form of `handeye.mocks.ur_sim.program`) until `stop_program`."""
        reply = self.command("sim program " + json.dumps(program))
        if reply != "ok":
            raise DeviceError(f"simulated controller refused the production program: {reply}")

    def stop_program(self) -> None:
        self.command("sim program stop")

    def stop(self, timeout: float = 5.0) -> int:
        """SIGTERM the simulator and wait; returns its exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
        return False


def ports_free(host: str) -> bool:
    """Whether the simulator's ports (`handeye.mocks.ur_sim.server`'s dashboard, script and RTDE) can be
    bound on ``host`` now."""
    from handeye.mocks.ur_sim.server import PORT_DASHBOARD, PORT_RTDE, PORT_SCRIPT

    for port in (PORT_DASHBOARD, PORT_SCRIPT, PORT_RTDE):
        with socket.socket() as s:
            try:
                s.bind((host, port))
            except OSError:
                return False
    return True


def free_loopback(taken: str, tries: int = 64) -> str | None:
    """A loopback address other than ``taken`` whose simulator ports are free, or None.

    The candidates start in a /24 derived from this process's pid, so two runs started at once look in
    different places first instead of racing for the same next address."""
    pid = os.getpid()
    for k in range(tries):
        n = pid + 7919 * k
        host = f"127.{(n >> 16) % 250 + 1}.{(n >> 8) % 256}.{n % 250 + 2}"
        if host != taken and ports_free(host):
            return host
    return None


def ports_holder(host: str) -> str:
    """Who holds the simulator's ports on ``host``: the run that launched a simulator there (its pid and command
    line), a simulator started by hand, or another program."""
    try:
        reply = dashboard(host, "sim owner", timeout=1.0)
    except OSError:
        return "held by another program"
    try:
        owner = json.loads(reply)
        pid = owner["parent_pid"] or owner["pid"]
    except (ValueError, KeyError, TypeError):
        return "held by another simulator or UR controller, which does not say which process it is"
    what = "the simulated controller of process" if owner["parent_pid"] else "a simulator started by hand, process"
    try:
        argv = [a.decode(errors="replace") for a in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0") if a]
    except OSError:
        return f"held by {what} {pid}"
    if len(argv) > 1 and Path(argv[0]).name.startswith("python") and not argv[1].startswith("-"):
        argv = argv[1:]  # a console script (.venv/bin/handeye): its name, not the interpreter's
    return f"held by {what} {pid}: {shlex.join([Path(argv[0]).name, *argv[1:]])[:160]}"


def launch(host: str = "127.0.0.1", model: str = "ur10", controller: str = "5.11", initial_q=None,
           tcp_offset=None, timeout: float = 15.0, robot_error: dict | None = None) -> SimProcess:
    """Start ``python -m handeye.mocks.ur_sim`` and wait until its ports accept connections.

    ``robot_error``: fields of `handeye.mocks.ur_sim.truth.SimRobotError` (true DH parameters off the nominal ones,
    repeatability); None: the arm is exactly its nominal model.

    Raises
    ------
    DeviceError
        If the simulator exits or does not report ready within ``timeout`` s
        (message includes its stderr); `PortsTakenError` when its address is taken (the message
        names who holds it).
    """
    # The simulator watches this process (--parent-pid) and stops when it dies, even by SIGKILL.
    # Not PR_SET_PDEATHSIG: that fires when the launching *thread* exits (one signal per thread of
    # a dying many-threaded parent), and a preexec_fn may deadlock a forking many-threaded parent.
    cmd = [sys.executable, "-m", "handeye.mocks.ur_sim", "--host", host, "--model", model, "--controller", controller,
           "--parent-pid", str(os.getpid())]
    if initial_q is not None:
        cmd += ["--initial-q", *[f"{x:.12g}" for x in initial_q]]
    if tcp_offset is not None:
        cmd += ["--tcp-offset", *[f"{x:.12g}" for x in tcp_offset]]
    if robot_error is not None:
        cmd += ["--robot-error", json.dumps(robot_error)]
    # A simulator whose parent was just killed needs a moment (<= 0.1 s to notice, then its exit)
    # to free the ports: an immediate `--resume` waits for it instead of failing.
    bind_deadline = time.monotonic() + min(timeout, 5.0)
    while True:
        # Its own session: a terminal's Ctrl-C (SIGINT to the foreground process group) is for the
        # parent, which stops the robot, then the simulator (`SimProcess.stop`).
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)
        ready: list[str] = []
        reader = threading.Thread(target=lambda: ready.append(proc.stdout.readline()), daemon=True)
        reader.start()
        reader.join(timeout)
        if ready and ready[0].startswith("ur_sim ready"):
            break
        proc.kill()
        _, err = proc.communicate()
        if "in use" in err:
            if time.monotonic() < bind_deadline:
                time.sleep(0.2)
                continue
            raise PortsTakenError(f"simulated UR controller on {host} did not start: {err.strip()} "
                                  f"({ports_holder(host)})")
        raise DeviceError(f"simulated UR controller on {host} did not start: {err.strip() or 'timeout'}")
    sim = SimProcess(host, proc)
    # The ready line is printed after bind/listen; one dashboard round trip proves the loop runs.
    deadline = time.monotonic() + timeout
    while True:
        try:
            sim.command("robotmode", timeout=1.0)
            return sim
        except OSError:
            if time.monotonic() > deadline:
                sim.stop()
                raise DeviceError(f"simulated UR controller on {host} does not answer on port 29999") from None
            time.sleep(0.05)
