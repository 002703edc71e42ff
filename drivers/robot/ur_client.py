"""The RTDE client process: the only place where ur_rtde runs (see `handeye.drivers.robot.ur`).

Why a separate process. ur_rtde 1.6.5's ``RTDEControlInterface`` repairs
itself from its own receive thread: when a read waits 2.5 s without data (a
frozen stream) that thread disconnects and calls ``reconnect()``, which
replaces the socket, the recipes, the robot state and its own thread object.
Nothing serialises this against the application thread, which at that moment
is typically inside ``stopScript()``, ``disconnect()``, ``moveL()`` (whose
acknowledgement wait blocks for the whole freeze) or a getter of the same
object. The result is heap corruption ("malloc(): mismatching
next->prev_size", SIGABRT) or SIGFPE. The application cannot lock against a
thread it does not own, so the driver never calls ur_rtde in its own process:

- this child owns both interfaces, and each interface is used by exactly one
  of its threads (receive getters: the poller; control calls, construction
  and teardown: the main thread, one request at a time, poller joined first);
- the driver watches the controller timestamp itself and, when it stops
  advancing (``frozen_timeout``, default 0.5 s, well before ur_rtde's 2.5 s),
  SIGKILLs the child: no ur_rtde teardown ever runs next to ur_rtde's own
  recovery, and a native crash of the child can only become a
  `ConnectionLostError` in the driver;
- the child exits when its parent dies (socket EOF, or re-parenting), and runs
  in its own session: a terminal's Ctrl-C is for the parent, which stops the
  robot and then closes the child.

Wire protocol over a socketpair (`multiprocessing.connection` framing).
Child -> parent: ``("ready",)``, ``("fatal", msg)``, ``("lost", msg)``,
``("state", t_recv, t_controller, q, qd, tcp_pose, robot_mode, safety_mode,
safety_status_bits)``, ``("ret", id, value)``, ``("err", id, msg)``.
Parent -> child: ``("call", id, name, args)`` with a name from `CALLS`,
``("close",)``.

This module imports nothing from the project at module level, so that
``python -m handeye.drivers.robot.ur_client`` starts fast.
"""

from __future__ import annotations

import collections
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from multiprocessing.connection import Connection

# Control-interface calls the driver may make (name -> call on RTDEControlInterface).
CALLS = {
    "getTCPOffset": lambda c: list(c.getTCPOffset()),
    "isProgramRunning": lambda c: bool(c.isProgramRunning()),
    "moveL": lambda c, pose, v, a, asynchronous: bool(c.moveL(pose, v, a, asynchronous)),
    "moveJ": lambda c, q, v, a, asynchronous: bool(c.moveJ(q, v, a, asynchronous)),
    "stopL": lambda c, a, asynchronous: c.stopL(a, asynchronous),
    "asyncRunning": lambda c: bool(c.getAsyncOperationProgressEx().isAsyncOperationRunning()),
}


# ------------------------------------------------------------------- child
def _poll(rtde_r, send, stop: threading.Event, period: float) -> None:
    # ur_rtde keeps only the newest package: poll faster than the stream (4x) so none is missed.
    last = None
    try:
        while not stop.is_set():
            if not rtde_r.isConnected():
                send(("lost", "RTDE connection dropped"))
                return
            ts = rtde_r.getTimestamp()
            if ts != last:
                t_recv = time.time()
                state = (list(rtde_r.getActualQ()), list(rtde_r.getActualQd()), list(rtde_r.getActualTCPPose()),
                         int(rtde_r.getRobotMode()), int(rtde_r.getSafetyMode()), int(rtde_r.getSafetyStatusBits()))
                if rtde_r.getTimestamp() == ts:  # else a newer package arrived between the getters: read again
                    last = ts
                    send(("state", t_recv, ts, *state))
                    continue
            time.sleep(period)
    except RuntimeError as exc:
        send(("lost", f"RTDE read failed: {exc}"))
    except OSError:
        pass  # the parent is gone; the main thread notices and exits


def serve(conn: Connection, host: str, frequency: float, read_only: bool, variables: list[str]) -> int:
    """Child main: open the interfaces, stream states, answer calls until closed or orphaned."""
    import rtde_receive

    send_lock = threading.Lock()

    def send(msg) -> None:
        with send_lock:
            conn.send(msg)

    parent = os.getppid()
    rtde_c = None
    try:
        rtde_r = rtde_receive.RTDEReceiveInterface(host, frequency, variables)
    except RuntimeError as exc:
        send(("fatal", f"cannot open RTDE receive on UR controller {host} (robot.host): {exc}; check that the "
                       f"controller is on and reachable (ping {host}), on port 30004, and that robot.host is its "
                       "address"))
        return 1
    try:
        if not read_only:
            import rtde_control

            rtde_c = rtde_control.RTDEControlInterface(host, frequency)
    except RuntimeError as exc:
        rtde_r.disconnect()
        send(("fatal", f"cannot open RTDE control on UR controller {host} (robot.host): {exc}; check that the "
                       "robot is in remote control (e-Series: the pendant's Remote Control mode), powered on with "
                       "its brakes released, and not in a protective stop"))
        return 1
    stop = threading.Event()
    period = 0.25 / (500.0 if frequency <= 0 else frequency)
    poller = threading.Thread(target=_poll, args=(rtde_r, send, stop, period), daemon=True)
    poller.start()
    send(("ready",))
    try:
        while True:
            if not conn.poll(0.2):
                if os.getppid() != parent:
                    return 0  # orphaned: no one will ever close us
                continue
            msg = conn.recv()
            if msg[0] == "close":
                break
            _, rid, name, args = msg
            try:
                if rtde_c is None:
                    raise RuntimeError("read-only client: no control interface")
                send(("ret", rid, CALLS[name](rtde_c, *args)))
            except (RuntimeError, ValueError, TypeError, KeyError) as exc:  # what ur_rtde's C++ errors become
                send(("err", rid, f"{type(exc).__name__}: {exc}"))
    except (EOFError, OSError):
        return 0  # parent gone
    # Orderly teardown, only ever on a live stream (the driver kills a stale client instead).
    stop.set()
    poller.join()
    try:
        if rtde_c is not None:
            if rtde_c.isConnected() and rtde_c.isProgramRunning():
                rtde_c.stopScript()
            rtde_c.disconnect()
        rtde_r.disconnect()
    except RuntimeError as exc:
        print(f"ur_client: closing: {exc}", file=sys.stderr)
    send(("closed",))
    return 0


def _main(argv: list[str]) -> int:
    fd, spec = int(argv[0]), json.loads(argv[1])
    # Ctrl-C is the parent's to handle; it closes us. Our own session (`RTDEClient.start`) keeps a
    # terminal's SIGINT away from the start on; this also ignores a service manager's SIGINT to the group.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    code = serve(Connection(fd), spec["host"], spec["frequency"], spec["read_only"], spec["variables"])
    # Skip interpreter teardown: ur_rtde's destructors would disconnect again, and an orphaned
    # client must not block on a dead stream. The kernel closes the sockets.
    sys.stderr.flush()
    os._exit(code)


# ------------------------------------------------------------------ parent
class ClientDied(Exception):
    """The client process is gone or reported the stream lost (message says why)."""


class RTDEClient:
    """Parent-side handle on one client process.

    Parameters
    ----------
    host, frequency, read_only, variables
        As for ur_rtde's interfaces.
    on_state : callable
        Called from the reader thread with ``(t_recv, t_controller, q, qd,
        tcp_pose, robot_mode, safety_mode, safety_status_bits)`` for every
        new controller timestamp.
    """

    def __init__(self, host: str, frequency: float, read_only: bool, variables: list[str], on_state):
        self.host = host
        self._spec = json.dumps({"host": host, "frequency": float(frequency), "read_only": bool(read_only),
                                 "variables": list(variables)})
        self._on_state = on_state
        self._cv = threading.Condition()
        self._replies: dict[int, tuple] = {}
        self._next_id = 0
        self._send_lock = threading.Lock()
        self.error: str | None = None  # why the client is unusable, once it is
        self._ready = False
        self._closed = False
        self.stderr_tail: collections.deque[str] = collections.deque(maxlen=20)
        self.proc: subprocess.Popen | None = None
        self._conn: Connection | None = None
        self._reader: threading.Thread | None = None

    def start(self, timeout: float) -> None:
        """Start the process and wait until both interfaces are open; ClientDied with the reason otherwise."""
        ours, theirs = socket.socketpair()
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "handeye.drivers.robot.ur_client", str(theirs.fileno()), self._spec],
                pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE, text=True, start_new_session=True)
        finally:
            theirs.close()
        self._conn = Connection(ours.detach())
        threading.Thread(target=self._drain, daemon=True, name=f"ur-client-err-{self.host}").start()
        self._reader = threading.Thread(target=self._read, daemon=True, name=f"ur-client-{self.host}")
        self._reader.start()
        deadline = time.monotonic() + timeout
        with self._cv:
            while not self._ready and self.error is None:
                if time.monotonic() > deadline:
                    self.kill(f"the RTDE client did not connect to {self.host} within {timeout} s")
                    break
                self._cv.wait(0.05)
        if self.error is not None:
            raise ClientDied(self.error)

    def _drain(self) -> None:
        for line in self.proc.stderr:
            self.stderr_tail.append(line.rstrip())

    def _fail(self, reason: str) -> None:
        with self._cv:
            if self.error is None:
                self.error = reason
            self._cv.notify_all()

    def _read(self) -> None:
        try:
            while True:
                msg = self._conn.recv()
                kind = msg[0]
                if kind == "state":
                    try:
                        self._on_state(*msg[1:])
                    except Exception as exc:  # a malformed state must not silently end the stream
                        self.kill(f"bad state from the RTDE client for {self.host}: {exc!r}")
                elif kind in ("ret", "err"):
                    with self._cv:
                        self._replies[msg[1]] = msg
                        self._cv.notify_all()
                elif kind == "ready":
                    with self._cv:
                        self._ready = True
                        self._cv.notify_all()
                elif kind == "closed":
                    with self._cv:
                        self._closed = True
                        self._cv.notify_all()
                else:  # "lost", "fatal"
                    self._fail(msg[1])
        except (EOFError, OSError):
            pass
        code = self.proc.wait()
        if code < 0:
            how = f"was killed by {signal.Signals(-code).name}"
        else:
            how = f"exited with code {code}"
        tail = f" ({self.stderr_tail[-1]})" if self.stderr_tail and code != 0 else ""
        self._fail(f"the RTDE client process for {self.host} {how}{tail}")

    def call(self, name: str, *args, timeout: float, watch=None):
        """Run ``CALLS[name](control, *args)`` in the client and return its value.

        ``watch()`` is called every 10 ms while waiting; an exception from it
        kills the client and propagates (a frozen stream during a blocking
        ur_rtde call). RuntimeError: ur_rtde raised; ClientDied: the client is gone.
        """
        with self._cv:
            if self.error is not None:
                raise ClientDied(self.error)
            self._next_id += 1
            rid = self._next_id
        try:
            with self._send_lock:
                self._conn.send(("call", rid, name, args))
        except OSError:
            pass  # the reader reports why
        deadline = time.monotonic() + timeout
        while True:
            with self._cv:
                reply = self._replies.pop(rid, None)
                if reply is None and self.error is None:
                    self._cv.wait(0.01)
                    reply = self._replies.pop(rid, None)
                error = self.error
            if reply is not None:
                if reply[0] == "err":
                    raise RuntimeError(reply[2])
                return reply[2]
            if error is not None:
                raise ClientDied(error)
            if watch is not None:
                try:
                    watch()
                except BaseException:
                    self.kill(f"killed while waiting for {name}")
                    raise
            if time.monotonic() > deadline:
                self.kill(f"{name} on {self.host} did not return within {timeout} s")
                raise ClientDied(self.error)

    def kill(self, reason: str) -> None:
        """SIGKILL the client now: its sockets close with it, no ur_rtde code runs any more."""
        self._fail(reason)
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()

    def close(self, timeout: float) -> None:
        """Orderly shutdown on a live stream (stop the script, disconnect); SIGKILL if it does not finish."""
        if self.proc is None:
            return
        if self.error is None:
            try:
                with self._send_lock:
                    self._conn.send(("close",))
                with self._cv:
                    self._cv.wait_for(lambda: self._closed or self.error is not None, timeout)
            except OSError:
                pass
        try:
            self.proc.wait(timeout if self.error is None else 0.5)
        except subprocess.TimeoutExpired:
            pass
        self.kill("closed")
        self.proc.wait()
        # The reader sees the dead client's EOF and ends; closing the pipe under its recv() instead
        # makes multiprocessing raise a TypeError in that thread.
        if self._reader is not None:
            self._reader.join(timeout)
        if self._reader is None or not self._reader.is_alive():
            self._conn.close()


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
