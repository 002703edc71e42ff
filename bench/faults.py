"""Fault campaign for the robot side: repeat each controller/simulator fault many times, count the outcomes.

Run ``python -m bench.faults [--quick | --full] [--freeze N] [--faults N] [--app-freezes N]
[--parent-deaths N] [--kills N] [--targets N] [--seed S]`` or ``python -m bench --faults``. Prints a
markdown table:
fault, runs, clean errors, crashes (native signals), hangs, samples lost, and the slowest
detection. Everything runs on this process's own loopback /24 (``127.a.b.x``).

- **Frozen stream, short / long** (``--freeze`` runs each): the simulator stops sending RTDE data
  0.05-0.4 s into a 25 cm moveL, for 2 s (short) or 10 s (long: past ur_rtde's own 2.5 s read
  deadline). Clean = `ConnectionLostError` naming
  the frozen stream, raised during the move; then reconnect and move home.
- **Drop, protective stop, e-stop** (``--faults`` runs each): same move, the fault instead.
  Clean = `ConnectionLostError` / `RobotStoppedError`; then recover (unlock, release) and move.
- Each of these runs in a worker process through the real ur_rtde client (`URRobot`) against
  `handeye.mocks.ur_sim`. A worker killed by a signal counts a crash (the worker is restarted), a run
  with no answer within 60 s a hang.
- **calibrate with a frozen stream** (``--app-freezes``): ``handeye calibrate`` on the simulated
  cell, the stream frozen for 60 s after 1-4 samples. Clean = exit 1 with one line naming the frozen stream; the detection column
  is the time until the process has exited; lost = samples recorded before the freeze that are
  not in the session afterwards.
- **Parent death** (``--parent-deaths``): a 32-thread parent (the simulator launched from a
  worker thread that exits first) is SIGKILLed; orphan = the simulator still runs 3 s later or
  its ports are still bound.
- **kill -9 + resume** (``--kills``): ``handeye calibrate`` on the simulated cell is SIGKILLed
  (the process only, not its children) at a random moment after its first sample, then
  ``handeye calibrate --resume`` completes the session; a resume that ends with a clean
  one-line error is run again (up to 3 times, as a user would; the summary says how many
  completed at the first). Lost = a sample readable right after the kill that is missing
  (or has missing frames) after the resume.
- **Targets vs the simulator's execution** (``--targets``): random moveL/moveJ targets from
  random start joints, 30 % aimed at the wrist/elbow singularities, checked by
  `URRobot.check_target` offline; every accepted one is executed by the simulator's own motion
  model (`handeye.mocks.ur_sim.motion`) at the CB3 control rate and must neither protective-stop nor
  leave the workspace box, the tilt cone or the joint limits at any tick.

The robot only supplies ``T_base_flange`` (A_i): the figures hold for eye-to-hand and eye-in-hand.
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import os
import queue
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from handeye.app import exit_status
from handeye.calib.errors import HandeyeError
from handeye.drivers.errors import ConnectionLostError, LimitViolationError, RobotStoppedError

START_Q = (0.0, -1.2, 1.6, -1.97, -1.5708, 0.0)
SIM_TCP = (0.01, -0.02, 0.15, 0.1, -0.2, 0.3)
ROBOT_FAULTS = {  # name: (expected error, what its message must say)
    "freeze_short": (ConnectionLostError, "frozen"),
    "freeze_long": (ConnectionLostError, "frozen"),
    "drop": (ConnectionLostError, "lost"),
    "protective_stop": (RobotStoppedError, "protective stop"),
    "emergency_stop": (RobotStoppedError, "emergency"),
}
RUN_TIMEOUT = 60.0
DEFAULTS = dict(freeze=10, faults=5, app_freezes=5, parent_deaths=20, kills=6, targets=1000)
QUICK = dict(freeze=2, faults=1, app_freezes=1, parent_deaths=3, kills=1, targets=100)
FULL = dict(freeze=25, faults=10, app_freezes=10, parent_deaths=50, kills=100, targets=10000)
#: --resume runs per killed session while each ends with a clean one-line error.
RESUME_ATTEMPTS = 3
#: The exit statuses of a calibration that ran to its verdict (`handeye.app.exit_status`): whatever the verdict, the
#: resume completed (8 samples often judge WARN, exit 5).
COMPLETED = (exit_status.PASS, exit_status.WARN, exit_status.FAIL)


def _net() -> str:
    """This process's loopback /24, derived from the pid like the test suite's."""
    pid = os.getpid()
    return f"127.{(pid >> 8) % 250 + 1}.{pid % 256}"


def _robot_config(host: str):
    from handeye.drivers.robot.ur import URRobotConfig

    return URRobotConfig(host=host, model="ur10", speed=0.25, acceleration=1.2, workspace_min=(-1.3, -1.0, 0.0),
                         workspace_max=(1.3, 1.0, 1.2), max_tilt_deg=45.0)


# ------------------------------------------------------------ robot faults
def _inject(sim, fault: str) -> None:
    if fault == "freeze_short":
        sim.freeze(2.0)
    elif fault == "freeze_long":
        sim.freeze(10.0)
    elif fault == "drop":
        sim.drop(0.5)
    elif fault == "protective_stop":
        sim.protective_stop()
    else:
        sim.command("sim emergency_stop")


def _recover(robot, sim, fault: str, t_inject: float) -> None:
    if fault == "freeze_short":
        time.sleep(max(0.0, t_inject + 2.05 - time.monotonic()))
    elif fault == "freeze_long":
        robot.disconnect()
        time.sleep(max(0.0, t_inject + 3.0 - time.monotonic()))  # past ur_rtde's 2.5 s read deadline
        sim.freeze(0.0)
    elif fault == "drop":
        time.sleep(max(0.0, t_inject + 0.55 - time.monotonic()))
    elif fault == "protective_stop":
        sim.unlock_protective_stop()
    else:
        sim.command("sim release")
    robot.reconnect()


def worker(fault: str, host: str, runs: int, seed: int) -> int:
    """One worker process: ``runs`` runs of ``fault``, one JSON line each on stdout."""
    from handeye.drivers.robot.ur import URRobot
    from handeye.mocks.ur_sim import launch

    expected, words = ROBOT_FAULTS[fault]
    rng = random.Random(seed)
    with launch(host, model="ur10", controller="5.11", initial_q=START_Q, tcp_offset=SIM_TCP) as sim:
        robot = URRobot(_robot_config(host))
        robot.connect()
        home = robot.read().T_base_flange.copy()
        for _ in range(runs):
            target = home.copy()
            target[0, 3] += 0.25
            t_inject = []
            timer = threading.Timer(rng.uniform(0.05, 0.4), lambda: (t_inject.append(time.monotonic()),
                                                                     _inject(sim, fault)))
            result = {"clean": False, "detect_s": None, "error": None}
            timer.start()
            try:
                robot.move_to(target)
                result["error"] = "no error: the fault went unnoticed"
            except HandeyeError as exc:
                t = time.monotonic()
                timer.join()
                result["error"] = f"{type(exc).__name__}: {exc}"
                result["clean"] = isinstance(exc, expected) and words in str(exc) and "\n" not in str(exc)
                result["detect_s"] = t - t_inject[0] if t_inject else None
            timer.join()
            try:
                _recover(robot, sim, fault, t_inject[0] if t_inject else time.monotonic())
                robot.move_to(home)
            except HandeyeError as exc:
                result["clean"] = False
                result["error"] = f"recovery failed: {type(exc).__name__}: {exc}"
            print(json.dumps(result), flush=True)
        robot.disconnect()
    return 0


def run_robot_fault(fault: str, runs: int, slots, seed: int) -> dict:
    """Run ``fault`` ``runs`` times in worker processes; restart a worker after a crash or hang."""
    row = {"fault": fault, "runs": 0, "clean": 0, "crashes": 0, "hangs": 0, "lost": None, "detect": [],
           "errors": []}
    while row["runs"] < runs:
        host = f"{_net()}.{next(slots)}"
        # Own session: a hung worker is killed with its simulator and RTDE client.
        proc = subprocess.Popen([sys.executable, "-m", "bench.faults", "--worker", fault, host,
                                 str(runs - row["runs"]), str(seed + row["runs"])],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
        lines: queue.Queue = queue.Queue()
        err_tail: collections.deque = collections.deque(maxlen=5)
        threading.Thread(target=lambda: ([lines.put(x) for x in proc.stdout], lines.put(None)), daemon=True).start()
        threading.Thread(target=lambda: err_tail.extend(proc.stderr), daemon=True).start()
        while row["runs"] < runs:
            try:
                line = lines.get(timeout=RUN_TIMEOUT)
            except queue.Empty:
                row["runs"] += 1
                row["hangs"] += 1
                row["errors"].append(f"hang: no result within {RUN_TIMEOUT:.0f} s")
                os.killpg(proc.pid, signal.SIGKILL)
                break
            if line is None:  # the worker ended without a result for this run
                code = proc.wait()
                row["runs"] += 1
                if code < 0:
                    row["crashes"] += 1
                    row["errors"].append(f"worker killed by {signal.Signals(-code).name}")
                else:
                    row["errors"].append(f"worker exited {code}: {''.join(err_tail).strip()[-300:]}")
                break
            r = json.loads(line)
            row["runs"] += 1
            row["clean"] += int(r["clean"])
            if r["detect_s"] is not None:
                row["detect"].append(r["detect_s"])
            if not r["clean"]:
                row["errors"].append(r["error"])
        try:
            proc.wait(15.0)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return row


# ------------------------------------------------------------- parent death
# A parent like a calibrate run: the simulator is launched from a worker thread that then
# exits (PR_SET_PDEATHSIG would fire here), and 31 more threads are alive when it dies.
PARENT = """
import sys, threading, time
from handeye.mocks.ur_sim import launch
box = []
t = threading.Thread(target=lambda: box.append(launch(sys.argv[1])))
t.start(); t.join()
for _ in range(31):
    threading.Thread(target=time.sleep, args=(3600,), daemon=True).start()
print(box[0].proc.pid, flush=True)
time.sleep(3600)
"""


def process_alive(pid: int) -> bool:
    """Running; a zombie waiting for init to reap it holds no ports and counts as gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def ports_free(host: str) -> bool:
    """The simulator's three ports can be bound on ``host`` (nothing holds them)."""
    for port in (29999, 30003, 30004):
        with socket.socket() as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind((host, port))
            except OSError:
                return False
    return True


def run_parent_deaths(runs: int, slots) -> dict:
    row = {"fault": "parent death (32 threads, SIGKILL)", "runs": 0, "clean": 0, "crashes": 0, "hangs": 0,
           "lost": None, "detect": [], "errors": [], "orphans": 0}
    for _ in range(runs):
        host = f"{_net()}.{next(slots)}"
        parent = subprocess.Popen([sys.executable, "-c", PARENT, host], stdout=subprocess.PIPE, text=True)
        row["runs"] += 1
        try:
            line = parent.stdout.readline()
            if not line:
                row["errors"].append(f"parent could not start the simulator (exit {parent.wait()})")
                continue
            sim_pid = int(line)
            parent.kill()
            parent.wait()
            t0 = time.monotonic()
            while process_alive(sim_pid) and time.monotonic() - t0 < 3.0:
                time.sleep(0.02)
            gone = not process_alive(sim_pid)
            if gone and ports_free(host):
                row["clean"] += 1
                row["detect"].append(time.monotonic() - t0)
            else:
                row["orphans"] += 1
                row["errors"].append(f"orphaned simulator on {host}")
                if process_alive(sim_pid):
                    os.kill(sim_pid, signal.SIGKILL)
        finally:
            if parent.poll() is None:
                parent.kill()
                parent.wait()
    return row


# ------------------------------------------------------------ kill -9 + resume
def _sample_indices(session: Path) -> tuple[set[int], int]:
    """Indices of the samples readable in ``session`` and how many of them miss a frame file."""
    from handeye.app.session import read_session

    s = read_session(session)
    missing = sum(1 for o in s.observations for k in ("color", "depth")
                  if o.meta.get(k) and not (session / o.meta[k]).exists())
    return {o.index for o in s.observations}, missing


def _sim_config(path: Path, host: str) -> Path:
    """The shipped simulated-cell config with its controller on ``host``, written to ``path``."""
    base = Path(__file__).resolve().parents[1] / "config" / "sim.toml"
    path.write_text(base.read_text().replace('host = "127.0.0.2"', f'host = "{host}"'))
    return path


def run_kills(runs: int, slots, seed: int, samples: int = 8) -> dict:
    row = {"fault": "kill -9 of calibrate + --resume", "runs": 0, "clean": 0, "crashes": 0, "hangs": 0, "lost": 0,
           "detect": [], "errors": [], "resumable": 0, "resumed_first": 0}
    rng = random.Random(seed)
    tmp = Path(tempfile.mkdtemp(prefix="handeye-faults-"))
    try:
        for i in range(runs):
            cfg = _sim_config(tmp / f"sim{i}.toml", f"{_net()}.{next(slots)}")
            root = tmp / f"sessions{i}"
            cmd = [sys.executable, "-m", "handeye.app.cli", "calibrate", "--yes-move", "-c", str(cfg), "--session-root",
                   str(root), "--no-viz", "--samples", str(samples), "--seed", str(i)]
            row["runs"] += 1
            proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            deadline = time.monotonic() + 120
            while not list(root.glob("*/samples.jsonl")) or b'"kind": "sample"' not in \
                    next(root.glob("*/samples.jsonl")).read_bytes():
                if proc.poll() is not None or time.monotonic() > deadline:
                    break
                time.sleep(0.05)
            time.sleep(rng.uniform(0.0, 3.0))
            if proc.poll() is not None:
                row["errors"].append(f"run ended before the kill (exit {proc.returncode}): "
                                     f"{proc.stderr.read().strip()[-200:]}")
                continue
            proc.kill()  # SIGKILL, the process only: its simulator and RTDE client must go by themselves
            proc.wait()
            sessions = list(root.iterdir())
            if not sessions:
                row["errors"].append("no session directory after the kill")
                continue
            session = sessions[0]
            try:
                before, _ = _sample_indices(session)
            except HandeyeError as exc:
                row["errors"].append(f"killed session unreadable: {exc}")
                continue
            # A resume that ends with a clean one-line error (exit 1, e.g. a stream starved by host load) leaves
            # the session as it was: the user runs --resume again. Up to RESUME_ATTEMPTS, each counted.
            for attempt in range(1, RESUME_ATTEMPTS + 1):
                try:
                    res = subprocess.run([*cmd[:cmd.index("--seed")], "--resume", str(session)],
                                         capture_output=True, text=True, timeout=180)
                except subprocess.TimeoutExpired:
                    res = None
                    break
                if res.returncode != 1:
                    break
                row["errors"].append(f"resume attempt {attempt} exit 1: {res.stderr.strip()[-200:]}")
            if res is None:
                row["hangs"] += 1
                row["errors"].append("resume hung")
                continue
            if res.returncode < 0:
                row["crashes"] += 1
            try:
                after, missing = _sample_indices(session)
            except HandeyeError as exc:
                row["errors"].append(f"resumed session unreadable: {exc}")
                row["lost"] += len(before)
                continue
            lost = len(before - after) + missing
            row["lost"] += lost
            ok = res.returncode in COMPLETED and len(after) >= samples and (session / "result.yaml").exists()
            row["resumable"] += int(ok)
            row["resumed_first"] += int(ok and attempt == 1)
            row["clean"] += int(ok and lost == 0)
            if not ok:
                row["errors"].append(f"resume exit {res.returncode}: {res.stderr.strip()[-300:]}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return row


def run_app_freezes(runs: int, slots, seed: int, seconds: float = 60.0) -> dict:
    """``handeye calibrate`` with the stream frozen ``seconds`` after a random number of samples."""
    row = {"fault": f"calibrate, stream frozen {seconds:.0f} s mid-run", "runs": 0, "clean": 0, "crashes": 0,
           "hangs": 0, "lost": 0, "detect": [], "errors": []}
    rng = random.Random(seed)
    tmp = Path(tempfile.mkdtemp(prefix="handeye-faults-"))
    try:
        for i in range(runs):
            host = f"{_net()}.{next(slots)}"
            cfg = _sim_config(tmp / f"sim{i}.toml", host)
            root = tmp / f"sessions{i}"
            row["runs"] += 1
            proc = subprocess.Popen([sys.executable, "-m", "handeye.app.cli", "calibrate", "--yes-move", "-c", str(cfg),
                                     "--session-root", str(root), "--no-viz", "--samples", "30", "--seed", str(i)],
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            want = rng.randint(1, 4)
            deadline = time.monotonic() + 120
            before: set[int] = set()
            while len(before) < want and proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.05)
                try:
                    before, _ = _sample_indices(next(root.iterdir()))
                except (StopIteration, HandeyeError, OSError):
                    pass
            if proc.poll() is not None or len(before) < want:
                proc.kill()
                row["errors"].append(f"no {want} samples before the freeze: {proc.communicate()[1].strip()[-200:]}")
                continue
            t0 = time.monotonic()
            with socket.create_connection((host, 29999), timeout=5) as s:
                f = s.makefile("rb")
                f.readline()
                s.sendall(f"sim freeze {seconds}\n".encode())
                f.readline()
            try:
                _, err = proc.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()
                row["hangs"] += 1
                row["errors"].append("calibrate did not exit within 30 s of the freeze")
                continue
            row["detect"].append(time.monotonic() - t0)  # until the process has exited, not just detected
            if proc.returncode < 0:
                row["crashes"] += 1
                row["errors"].append(f"calibrate killed by {signal.Signals(-proc.returncode).name}")
                continue
            after, missing = _sample_indices(next(root.iterdir()))
            row["lost"] += len(before - after) + missing
            last = err.strip().splitlines()[-1] if err.strip() else ""
            if proc.returncode == 1 and "frozen" in last and "Traceback" not in err:
                row["clean"] += 1
            else:
                row["errors"].append(f"exit {proc.returncode}: {last[-200:]}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return row


# ---------------------------------------------------- targets vs simulator
def random_valid_start(rng: np.random.Generator, robot) -> np.ndarray:
    """Random start joints in a state the driver allows (`URRobot.check_pose`: box and tilt cone).

    Starts outside the cone made the oracle flag motions that only brought the arm back in.
    """
    from handeye.drivers.robot import ur_kinematics as kin

    while True:
        q = np.array(START_Q) + rng.uniform(-1.0, 1.0, 6) * [1.5, 0.8, 1.0, 1.5, 1.5, 2.0]
        try:
            robot.check_pose(kin.forward(q, "ur10"), "start")
        except LimitViolationError:
            continue
        return q


def sim_path_violation(motion, robot, limits, tick: float) -> str | None:
    """Execute ``motion`` as the simulator does (one ``q_at`` per control tick); first problem or None."""
    from handeye.drivers.robot import ur_kinematics as kin

    cfg = robot.config
    lo, hi = np.asarray(cfg.workspace_min), np.asarray(cfg.workspace_max)
    ref = np.asarray(cfg.tilt_reference) / np.linalg.norm(cfg.tilt_reference)
    T_flange_tcp = robot.T_flange_tcp
    for t in np.arange(tick, motion.duration + tick, tick):
        q = motion.q_at(t)
        if q is None:
            return f"simulator protective stop: {motion.failure}"
        if np.any(q < limits[:, 0]) or np.any(q > limits[:, 1]):
            return "joint limit"
        T = kin.forward_one(q, "ur10")
        for p in (T[:3, 3], (T @ T_flange_tcp)[:3, 3]):
            if np.any(p < lo - 1e-6) or np.any(p > hi + 1e-6):
                return f"outside the workspace box at {np.round(p, 3).tolist()}"
        if math.degrees(math.acos(float(np.clip(T[:3, 2] @ ref, -1, 1)))) > cfg.max_tilt_deg + 1e-6:
            return "outside the tilt cone"
    return None


def run_targets(n: int, seed: int) -> dict:
    from handeye.drivers.robot import ur_kinematics as kin
    from handeye.drivers.robot.ur import URRobot
    from handeye.mocks.ur_sim.motion import JointMotion, LinearMotion

    # Offline (check_target with explicit start joints); a wide box and tilt cone, so that the
    # joint limits and singularities, not the box, decide most targets.
    cfg = _robot_config("127.0.0.1").model_copy(update={"workspace_min": (-1.4, -1.4, -0.2),
                                                        "workspace_max": (1.4, 1.4, 1.4), "max_tilt_deg": 120.0})
    robot = URRobot(cfg)
    limits = cfg.joint_limits
    rng = np.random.default_rng(seed)
    row = {"fault": "targets vs simulator execution", "runs": n, "clean": 0, "crashes": 0, "hangs": 0, "lost": None,
           "detect": [], "errors": [], "accepted": 0, "refused": 0, "bad": 0, "singular_refused": 0}
    for _ in range(n):
        q0 = random_valid_start(rng, robot)
        q1 = q0 + rng.normal(0.0, 0.3, 6)
        if rng.random() < 0.3:  # aim at a singularity: the wrist (q5) or the elbow (q3) crosses zero
            j = 4 if rng.random() < 0.6 else 2
            q1[j] = -q0[j] * rng.uniform(0.2, 1.0) if abs(q0[j]) > 0.05 else q0[j] + rng.choice([-0.3, 0.3])
        motion = "linear" if rng.random() < 0.8 else "joint"
        T = kin.forward(q1, "ur10")
        try:
            q_target = robot.check_target(T, motion, q_start=q0)
        except LimitViolationError as exc:
            row["refused"] += 1
            row["clean"] += 1
            row["singular_refused"] += int("singular" in str(exc))
            continue
        row["accepted"] += 1
        if motion == "linear":
            m = LinearMotion(q0, T @ robot.T_flange_tcp, cfg.speed, cfg.acceleration, "ur10", robot.T_flange_tcp,
                             kin.UR_JOINT_LIMITS)
        else:
            m = JointMotion(q0, q_target, cfg.joint_speed, cfg.joint_acceleration)
        problem = sim_path_violation(m, robot, limits, tick=1.0 / 125.0)
        if problem is None:
            row["clean"] += 1
        else:
            row["bad"] += 1
            row["errors"].append(f"{motion} accepted, then {problem}")
    return row


# --------------------------------------------------------------------- main
def format_row(row: dict) -> str:
    det = f"{max(row['detect']):.2f}" if row["detect"] else "-"
    lost = "-" if row["lost"] is None else str(row["lost"])
    return (f"| {row['fault']} | {row['runs']} | {row['clean']} | {row['crashes']} | {row['hangs']} | {lost} | "
            f"{det} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.faults", description=__doc__.splitlines()[0])
    ap.add_argument("--worker", nargs=4, metavar=("FAULT", "HOST", "RUNS", "SEED"), help=argparse.SUPPRESS)
    size = ap.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help=f"smoke-test counts {QUICK}")
    size.add_argument("--full", action="store_true", help=f"the issue's target counts {FULL} (long)")
    for name in DEFAULTS:
        ap.add_argument(f"--{name.replace('_', '-')}", type=int, help=f"runs (default {DEFAULTS[name]})")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.worker:
        fault, host, runs, seed = args.worker
        return worker(fault, host, int(runs), int(seed))
    counts = dict(QUICK if args.quick else FULL if args.full else DEFAULTS)
    for name in counts:
        if getattr(args, name) is not None:
            counts[name] = getattr(args, name)
    slots = iter(range(10, 250))
    t0 = time.monotonic()
    rows = []
    for fault in ROBOT_FAULTS:
        rows.append(run_robot_fault(fault, counts["freeze" if fault.startswith("freeze") else "faults"], slots,
                                    args.seed))
    rows.append(run_app_freezes(counts["app_freezes"], slots, args.seed))
    rows.append(run_parent_deaths(counts["parent_deaths"], slots))
    rows.append(run_kills(counts["kills"], slots, args.seed))
    rows.append(run_targets(counts["targets"], args.seed))
    print(f"## Robot fault campaign ({time.monotonic() - t0:.0f} s; simulated UR10, ur_rtde 1.6.5 in its client "
          "process)\n")
    print("| fault | runs | clean errors | crashes | hangs | samples lost | slowest detection s |")
    print("|---|---|---|---|---|---|---|")
    for row in rows:
        print(format_row(row))
    freeze = [r for r in rows if r["fault"].startswith("freeze")]
    app_freeze = rows[len(ROBOT_FAULTS)]
    pd, kills, tg = rows[-3], rows[-2], rows[-1]
    print("\n## Targets\n")
    print(f"- frozen-stream runs: {sum(r['runs'] for r in freeze)}, native crashes "
          f"{sum(r['crashes'] for r in freeze)}, hangs {sum(r['hangs'] for r in freeze)}, stale stream detected "
          f"within 1 s in {sum(sum(d <= 1.0 for d in r['detect']) for r in freeze)}")
    print(f"- calibrate with the stream frozen 60 s: {app_freeze['runs']}, native crashes {app_freeze['crashes']}, "
          f"hangs {app_freeze['hangs']}, clean one-line errors {app_freeze['clean']}")
    print(f"- parent deaths: {pd['runs']}, orphaned simulators {pd['orphans']}")
    print(f"- kill -9 + resume: {kills['runs']}, samples lost {kills['lost']}, resumed to completion "
          f"{kills['resumable']} ({kills['resumed_first']} at the first --resume, the others within "
          f"{RESUME_ATTEMPTS})")
    print(f"- targets: {tg['runs']} ({tg['accepted']} accepted, {tg['refused']} refused of which "
          f"{tg['singular_refused']} near a singularity); accepted but outside the limits or through a singular "
          f"path in the simulator's execution: {tg['bad']}")
    problems = [(r["fault"], e) for r in rows for e in r["errors"]]
    if problems:
        print("\n## Not clean\n")
        for fault, e in problems[:30]:
            print(f"- {fault}: {e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
