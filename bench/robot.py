"""Benchmark of the UR driver against the simulated controller, through the real ur_rtde client.

Run ``python -m bench.robot [--seconds S] [--repeats N] [--out DIR]``. Prints
markdown tables and writes ``robot_stream.png`` and ``robot_moves.png`` to
``out/bench/``:

- streaming rate the client sees (`URRobot` buffer: distinct controller
  timestamps per second of wall clock), missed packages and the largest gap,
  for a CB3 (PolyScope 3.15, 125 Hz) and an e-Series (5.11, 500 Hz) UR10;
- move round trip: `URRobot.move_to` from the call to the settled return
  (limit and path check, ur_rtde command, motion, settling), against the
  ideal trapezoidal duration of the motion itself; and the time of the limit
  check alone (`URRobot.check_target`).

The robot only provides ``T_base_flange`` (the paper's A_i), so the figures
hold for eye-to-hand and eye-in-hand alike.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from handeye.drivers.robot import ur_kinematics as kin
from handeye.drivers.robot.ur import URRobot, URRobotConfig
from handeye.mocks.ur_sim import launch
from handeye.mocks.ur_sim.motion import trapezoid_duration

START_Q = (0.0, -1.2, 1.6, -1.97, -1.5708, 0.0)
CONTROLLERS = [("CB3 3.15", "3.15", "127.0.77.1", 125.0), ("e-Series 5.11", "5.11", "127.0.77.2", 500.0)]
SPEED, ACC, JSPEED, JACC = 0.25, 1.2, 1.0, 2.0


def _config(host: str) -> URRobotConfig:
    return URRobotConfig(host=host, model="ur10", speed=SPEED, acceleration=ACC, joint_speed=JSPEED,
                         joint_acceleration=JACC, workspace_min=(-1.3, -1.0, 0.0), workspace_max=(1.3, 1.0, 1.2),
                         max_tilt_deg=45.0)


def measure_stream(robot: URRobot, seconds: float, nominal_hz: float) -> tuple[dict, np.ndarray]:
    """Collect every state the client saw for ``seconds``; returns stats and the controller stamps."""
    t_end = time.time() + seconds
    stamps = []
    while time.time() < t_end:
        stamps.append(robot.read().t_controller)
        time.sleep(0.0005)
    stamps = np.unique(stamps)
    dt = 1.0 / nominal_hz
    gaps = np.diff(stamps)
    expected = round((stamps[-1] - stamps[0]) / dt)
    return {
        "rate_hz": (len(stamps) - 1) / (stamps[-1] - stamps[0]) if expected else 0.0,
        "seen_hz": len(stamps) / seconds,
        "missed_pct": 100.0 * (1 - (len(stamps) - 1) / expected) if expected else 100.0,
        "max_gap_ms": 1e3 * gaps.max(),
    }, stamps


def measure_moves(robot: URRobot, repeats: int) -> list[dict]:
    """Round trips of moveL / moveJ of several sizes, back and forth from the start pose."""
    rows = []
    T0 = kin.forward(np.array(START_Q), "ur10")
    cases = [("moveL", "linear", d) for d in (0.05, 0.10, 0.20)] + [("moveJ", "joint", a) for a in (0.2, 0.5)]
    for name, motion, size in cases:
        if motion == "linear":
            target = T0.copy()
            target[0, 3] += size
            ideal = trapezoid_duration(size, SPEED, ACC)
            label = f"{name} {size * 100:.0f} cm"
        else:
            q = np.array(START_Q)
            q[0] += size
            target = kin.forward(q, "ur10")
            ideal = trapezoid_duration(size, JSPEED, JACC)
            label = f"{name} {size:.1f} rad"
        rt, chk = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            robot.check_target(target, motion)
            chk.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            robot.move_to(target, motion)
            rt.append(time.perf_counter() - t0)
            robot.move_joints(START_Q)
        rows.append({"move": label, "ideal_s": ideal, "round_trip_s": float(np.median(rt)),
                     "overhead_ms": 1e3 * (float(np.median(rt)) - ideal), "check_ms": 1e3 * float(np.median(chk))})
    return rows


def run(seconds: float, repeats: int) -> tuple[list[dict], dict, dict]:
    stream_rows, move_rows, stamps = [], {}, {}
    for label, version, host, hz in CONTROLLERS:
        with launch(host, "ur10", version, initial_q=START_Q) as sim, URRobot(_config(host)) as robot:
            stats, stamps[label] = measure_stream(robot, seconds, hz)
            stream_rows.append({"controller": label, "nominal_hz": hz, **stats})
            move_rows[label] = measure_moves(robot, repeats)
            assert sim.state()["safety_mode"] == 1
    return stream_rows, move_rows, stamps


def plot(stamps: dict, move_rows: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for label, s in stamps.items():
        ax.hist(np.diff(s) * 1e3, bins=np.arange(0.25, 20.3, 0.5), alpha=0.6, label=label)
    ax.set_xlabel("interval between states seen by the client (controller clock, ms)")
    ax.set_ylabel("count")
    ax.set_yscale("log")
    ax.legend()
    ax.set_title("UR RTDE stream via ur_rtde (simulated controller)")
    fig.tight_layout()
    fig.savefig(out / "robot_stream.png", dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7, 3.5))
    labels = [r["move"] for r in next(iter(move_rows.values()))]
    x = np.arange(len(labels))
    w = 0.8 / (len(move_rows) + 1)
    ax.bar(x - w * len(move_rows) / 2, [r["ideal_s"] for r in next(iter(move_rows.values()))], w, label="ideal trapezoid")
    for k, (label, rows) in enumerate(move_rows.items()):
        ax.bar(x - w * len(move_rows) / 2 + w * (k + 1), [r["round_trip_s"] for r in rows], w, label=f"move_to, {label}")
    ax.set_xticks(x, labels)
    ax.set_ylabel("s")
    ax.set_title("move_to: call to settled (UR10, simulated controller)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "robot_moves.png", dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.robot", description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="stream measurement per controller, s")
    ap.add_argument("--repeats", type=int, default=3, help="round trips per move size")
    ap.add_argument("--out", type=Path, default=Path("out/bench"))
    args = ap.parse_args(argv)
    stream_rows, move_rows, stamps = run(args.seconds, args.repeats)
    print("## UR RTDE stream seen by the client (URRobot over ur_rtde 1.6.5, simulated UR10)\n")
    print("| controller | nominal Hz | received Hz | missed % | max gap ms |")
    print("|---|---|---|---|---|")
    for r in stream_rows:
        print(f"| {r['controller']} | {r['nominal_hz']:.0f} | {r['rate_hz']:.1f} | {r['missed_pct']:.1f} | {r['max_gap_ms']:.1f} |")
    print(f"\n## move_to round trip (call to settled; moveL {SPEED} m/s, {ACC} m/s^2; moveJ {JSPEED} rad/s, "
          f"{JACC} rad/s^2; settle_time 0.1 s; median of {args.repeats})\n")
    print("| controller | move | ideal motion s | round trip s | overhead ms | limit check ms |")
    print("|---|---|---|---|---|---|")
    for label, rows in move_rows.items():
        for r in rows:
            print(f"| {label} | {r['move']} | {r['ideal_s']:.3f} | {r['round_trip_s']:.3f} | "
                  f"{r['overhead_ms']:.0f} | {r['check_ms']:.1f} |")
    plot(stamps, move_rows, args.out)
    print(f"\nplots: {args.out / 'robot_stream.png'}, {args.out / 'robot_moves.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
