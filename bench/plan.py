"""Pose-planning benchmark: how many motions to a trusted result, and are the planned motions valid.

Run ``python -m bench.plan [--seeds N] [--validity-poses N] [--out DIR]`` (also
``python -m bench --plan``). Prints markdown and writes ``<out>/plan.md`` and
``<out>/plan.png``.

1. **Motions to target** on the simulated cells of ``config/sim.toml``
   (eye-to-hand) and ``config/eye_in_hand.toml`` (eye-in-hand), through the
   real driver (ur_rtde client against `handeye.mocks.ur_sim`) and the rendered
   camera, one full ``calibrate`` run per strategy and seed (the seed drives
   the pose candidates and the camera noise): robot motions until the
   predicted 1-sigma of the camera transform (``T_base_cam`` eye-to-hand,
   ``T_flange_cam`` eye-in-hand; the cell's configured solver, ``auto``, as
   ``calibrate`` runs it) is below 1 mm and 0.1 deg (first check after 5
   samples; at most 80 samples, so that `random` gets there too). Strategies: ``optimal`` (`handeye.calib.planner`),
   ``random`` (uniform in the same box and tilt), ``fixed17``: a 17-pose
   pattern of the kind ROS tools ship (start, +-tilt about the flange x, y, z,
   +-offset along base x, y, z, four combined), at 2/3 of the same ranges,
   replayed as a plan file, and ``plan``: ``handeye plan`` (prior: the
   simulator's truth, noise measured at the start) replayed, its expected
   1-sigma compared with what the run reached. Robot time is the time spent
   in ``move_to`` (until settled).
2. **Validity**: the planning loop without rendering: cells with random true
   mountings (marker within 10 cm of the flange, turned up to 30 deg; eye-in-
   hand camera within 10 cm, marker anywhere in view), synthetic measurements
   from the truth with the `handeye.calib.noise` depth model, the estimate re-solved
   (the cell's solver, ``auto``) after every sample. Every planned pose (bootstrap
   and optimal) is checked independently: `URRobot.check_target` of the
   simulated cell's driver from the previous joints (joint limits, workspace
   box, tilt cone, path) and, under the TRUE mounting, all four marker
   corners inside the image, depth within range and the marker facing the
   camera within the view-angle limit. Planning time per pose is wall and
   process CPU time of `PosePlanner.next_pose` with numpy single-threaded.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from handeye.app import devices, planning  # noqa: E402
from handeye.app.config import load_config  # noqa: E402
from handeye.calib import planner as pl  # noqa: E402
from handeye.calib import transforms as tf  # noqa: E402
from handeye.calib.api import solve_observations  # noqa: E402
from handeye.calib.errors import CalibrationError, HandeyeError  # noqa: E402
from handeye.calib.noise import default_point_cov  # noqa: E402
from handeye.calib.setup import Setup  # noqa: E402
from handeye.drivers.camera.base import CameraIntrinsics  # noqa: E402

CELLS = {Setup.EYE_TO_HAND: "config/sim.toml", Setup.EYE_IN_HAND: "config/eye_in_hand.toml"}
TARGET_MM, TARGET_DEG = 1.0, 0.1
MAX_SAMPLES = 80
#: Samples of one synthetic run of the validity part.
VALIDITY_SAMPLES = 40
STRATEGIES = ("optimal", "random", "fixed17", "plan")
INTR = CameraIntrinsics(640, 480, 570.0, 570.0, 319.5, 239.5)
HOST_NET = "127.0.79"


def fixed_pattern(T_start: np.ndarray, translation_m: float, tilt_deg: float) -> np.ndarray:
    """17 flange poses (17, 4, 4): start, +-tilt about the flange x/y/z axes, +-offsets along base x/y/z,
    and four tilts about x+-y with diagonal offsets (the kind of fixed pattern ROS calibration tools ship)."""
    a, d = math.radians(tilt_deg), translation_m
    s = 1 / math.sqrt(2)
    steps = [([0, 0, 0], [0, 0, 0])]
    steps += [(list(sg * a * np.eye(3)[i]), [0, 0, 0]) for i in range(3) for sg in (1, -1)]
    steps += [([0, 0, 0], list(sg * d * np.eye(3)[i])) for i in range(3) for sg in (1, -1)]
    steps += [([sx * a * s, sy * a * s, 0], [sx * d * s, sy * d * s, 0]) for sx in (1, -1) for sy in (1, -1)]
    out = []
    for rv, dt in steps:
        R = T_start[:3, :3] @ tf.so3_exp(np.array(rv, float))
        out.append(tf.make_transform(R, T_start[:3, 3] + np.array(dt, float)))
    return np.stack(out)


# --------------------------------------------------------------------------- 1. motions to target


def _cell_config(setup: str, seed: int, host: str, root: Path, poses: str):
    cfg = load_config(CELLS[setup])
    data = cfg.model_dump()
    # The cell's own solver (`auto` in the shipped configs), as `calibrate` runs it.
    data["calibrate"].update(poses=poses, seed=seed, target_sigma_mm=TARGET_MM, target_sigma_deg=TARGET_DEG,
                             min_samples=5, samples=MAX_SAMPLES)
    data["robot"]["host"] = host
    data["camera"]["seed"] = seed
    data["session"].update(root=str(root), save_frames=False, exports=["json"])
    data["viz"]["enabled"] = False
    return type(cfg).model_validate(data)


def run_strategy(setup: str, strategy: str, seed: int, host: str, root: Path) -> dict:
    """One full calibrate run on the simulated cell; motions, robot time and the outcome."""
    from handeye.app.runs.calibrate import calibrate
    from handeye.drivers.robot import ur_kinematics as kin

    poses = strategy
    planned = None
    if strategy == "plan":
        from handeye.app.runs.plan import plan

        planned = plan(_cell_config(setup, seed, host, root, "optimal"), root / f"plan_{setup}_{seed}.json").document
        poses = str(root / f"plan_{setup}_{seed}.json")
    if strategy == "fixed17":
        cfg = _cell_config(setup, seed, host, root, "random")
        T0 = kin.forward(np.array(cfg.robot.initial_q), cfg.robot.model)
        pattern = fixed_pattern(T0, 2 / 3 * cfg.calibrate.translation_range_m, 2 / 3 * cfg.calibrate.tilt_deg)
        doc = {"format": planning.PLAN_FORMAT, "version": planning.PLAN_VERSION, "setup": setup,
               "poses": [{"T_base_flange": T.tolist()} for T in pattern]}
        poses = str(planning.write_plan(doc, root / f"fixed17_{setup}.json"))
    cfg = _cell_config(setup, seed, host, root, poses)
    out = calibrate(cfg, progress=False)
    r = out.report
    s_rot, s_t = r.result.sigma if r.result is not None and r.result.sigma is not None else (math.nan, math.nan)
    s_deg, s_mm = math.degrees(s_rot), s_t * 1e3
    err = tf.pose_error(r.result.camera_transform, out.truth) if r.result is not None else (math.nan, math.nan)
    lost = sum(n for why, n in r.skip_reasons.items() if not why.startswith(("limit:", "marker predicted")))
    return {"setup": setup, "strategy": strategy, "seed": seed, "reached": r.stopped_by == "target_sigma",
            "stopped_by": r.stopped_by, "motions": r.n_motions, "samples": r.n_samples, "robot_s": r.robot_time_s,
            "sigma_mm": s_mm, "sigma_deg": s_deg, "err_mm": float(err[1]) * 1e3, "err_deg": math.degrees(err[0]),
            "lost_marker": lost, "limit_refused": sum(n for why, n in r.skip_reasons.items() if why.startswith("limit:")),
            **(_expected(planned, r.n_samples) if planned is not None else {})}


def _expected(doc: dict, n_samples: int) -> dict:
    """What ``plan.json`` expected: its motions and the 1-sigma after the pose where the replay stopped."""
    row = doc["poses"][max(min(n_samples, len(doc["poses"])) - 1, 0)]
    return {"planned_motions": len(doc["poses"]) - 1, "expected_mm": row["expected_sigma_mm"],
            "expected_deg": row["expected_sigma_deg"], "noise_model": doc["noise_model"]}


# --------------------------------------------------------------------------- 2. validity


def _random_cell(setup: str, cfg, T0: np.ndarray, rng: np.random.Generator):
    """True (X, Y) of a cell like the configured one, with a random mounting that sees the marker at T0."""
    base = cfg.camera
    view = planning.camera_view(cfg.calibrate, INTR, cfg.marker)
    for _ in range(1000):
        t = rng.normal(size=3)
        t *= rng.uniform(0.0, 0.1) / np.linalg.norm(t)
        if setup == Setup.EYE_TO_HAND:
            X = tf.make_transform(tf.random_rotations(1, math.radians(30), rng)[0] @ base.X[:3, :3], t)
            Y = base.Y
        else:
            X = tf.make_transform(tf.random_rotations(1, math.radians(10), rng)[0] @ base.X[:3, :3], t)
            # The marker somewhere in the start view, turned up to 20 deg.
            T_cm = tf.invert(T0 @ base.X) @ base.Y
            T_cm = tf.make_transform(tf.random_rotations(1, math.radians(20), rng)[0] @ T_cm[:3, :3],
                                     T_cm[:3, 3] + rng.uniform(-0.08, 0.08, 3) * [1, 1, 0.5])
            Y = T0 @ X @ T_cm
        if pl.PosePlanner(setup, X, Y, view, pl.PlannerConfig(uncertainty_k=0)).screen(T0[None])[0][0]:
            return X, Y
    raise RuntimeError("no visible random cell found")


#: Orientation noise of the synthetic marker poses, rad per axis.
MARKER_ROT_SIGMA = math.radians(1.0)


def _measure(setup, X, Y, A, rng):
    """Synthetic marker point (depth-model noise) and a marker pose with `MARKER_ROT_SIGMA` orientation noise,
    with their covariances."""
    T_cm = (tf.invert(Y) @ A @ X) if setup == Setup.EYE_TO_HAND else (tf.invert(A @ X) @ Y)
    p = T_cm[:3, 3]
    cov = default_point_cov(p[None])[0]
    p_meas = p + np.linalg.cholesky(cov) @ rng.normal(size=3)
    B = tf.make_transform(tf.so3_exp(rng.normal(0, MARKER_ROT_SIGMA, 3)) @ T_cm[:3, :3], p_meas)
    pose_cov = np.zeros((6, 6))
    pose_cov[:3, :3] = MARKER_ROT_SIGMA**2 * np.eye(3)
    pose_cov[3:, 3:] = cov
    return p_meas, cov, B, pose_cov


class CheckedRobot:
    """The driver as the planner's reachability callback sees it, with every `check_target` call timed
    (process CPU) and its passes recorded, so a planned pose is known to have passed the driver's own check
    from exactly the joints it will start from."""

    def __init__(self, robot):
        self.robot = robot
        self.passed: dict = {}
        self.cpu_s = 0.0
        self.calls = 0

    def check_target(self, T_base_flange, q_start=None):
        c0 = time.process_time()
        try:
            q = self.robot.check_target(T_base_flange, q_start=q_start)
        finally:
            self.cpu_s += time.process_time() - c0
            self.calls += 1
        self.passed[_key(T_base_flange, q_start)] = q
        return q


def _key(T, q) -> tuple:
    return np.asarray(T, float).tobytes(), None if q is None else np.asarray(q, float).tobytes()


def validity_run(setup: str, cfg, robot, state, rng: np.random.Generator, max_poses: int, stats: dict) -> int:
    """One simulated calibration driven by the app's own pose source (`handeye.app.planning.OptimalPoses`) on
    synthetic measurements; every pose it plans is checked. Returns the samples taken.

    The robot check of a pose is the driver's `check_target` from the joints the motion starts from: taken
    from the record of the planner's own callback when it made exactly that call, else run here."""
    from handeye.calib.observation import Observation
    from handeye.drivers.robot.base import RobotState

    X, Y = _random_cell(setup, cfg, state.T_base_flange, rng)
    truth_view = planning.camera_view(cfg.calibrate, INTR, cfg.marker).model_copy(update={"margin_px": 0.0})
    truth = pl.PosePlanner(setup, X, Y, truth_view, pl.PlannerConfig(uncertainty_k=0))
    checked = CheckedRobot(robot)
    source = planning.OptimalPoses(cfg, state.T_base_flange, planning.camera_view(cfg.calibrate, INTR, cfg.marker),
                                   checked, rng)
    obs: list = []
    cur = state
    estimate = None
    while len(obs) < max_poses:
        w0, c0, chk0 = time.perf_counter(), time.process_time(), checked.cpu_s
        target = source.next(cur, estimate, obs)
        cpu_check = checked.cpu_s - chk0
        if target is not None and target.kind == "optimal":
            stats["wall_ms"].append(1e3 * (time.perf_counter() - w0))
            stats["cpu_ms"].append(1e3 * (time.process_time() - c0))
            stats["cpu_planner_ms"].append(1e3 * (time.process_time() - c0 - cpu_check))
        if target is None:
            stats[source.done_reason] = stats.get(source.done_reason, 0) + 1
            break
        T = target.T_base_flange
        if target.kind != "start":
            stats["poses"] += 1
            q = checked.passed.get(_key(T, cur.q))
            if q is None:
                try:
                    q = robot.check_target(T, q_start=cur.q)
                except HandeyeError:
                    stats["invalid_robot"] += 1
                    break
            if not truth.screen(T[None])[0][0]:
                stats["invalid_view"] += 1
                why = [k for k, n in truth.stats.reasons.items() if n]
                print(f"invalid view: {setup} {target.kind} pose after {len(obs)} samples "
                      f"(estimate {'yes' if estimate is not None else 'no'}): {why}", flush=True)
                truth.stats.reasons.clear()
        else:
            q = cur.q
        cur = RobotState(0.0, 0.0, T, q, np.zeros(6), 7, 1)
        p, c, B, pose_cov = _measure(setup, X, Y, T, rng)
        obs.append(Observation(len(obs), 0.0, T, p, c, B, pose_cov))
        if len(obs) >= 3:
            try:
                estimate = solve_observations(cfg.calibrate.method, obs, setup, refine=cfg.calibrate.refine)
            except CalibrationError:
                estimate = None
            if estimate is not None and len(obs) >= 5:
                s_rot, s_t = estimate.sigma
                if s_t * 1e3 <= TARGET_MM and math.degrees(s_rot) <= TARGET_DEG:
                    stats["reached"].append(len(obs) - 1)
                    break
    stats["check_calls"] += checked.calls
    stats["check_cpu_s"] += checked.cpu_s
    return len(obs)


# --------------------------------------------------------------------------- report


def _median(values):
    v = [x for x in values if x is not None and not (isinstance(x, float) and math.isnan(x))]
    return float(np.median(v)) if v else math.nan


def format_report(runs: list[dict], val: dict, elapsed: float) -> str:
    lines = ["# Pose planning benchmark (`python -m bench --plan`)", "",
             f"Target: predicted 1-sigma of the camera transform <= {TARGET_MM} mm and {TARGET_DEG} deg "
             f"(the cells' solver, `auto`, as `calibrate` runs it; first check after 5 samples, at most "
             f"{MAX_SAMPLES}). Simulated cells through the "
             "real driver and the rendered camera; eye-to-hand: `T_base_cam`, eye-in-hand: `T_flange_cam`.", "",
             "| cell | poses | runs | reached | motions (median) | motions (per seed) | robot time [s] (median) "
             "| final 1-sigma [mm / deg] (median) | error vs truth [mm / deg] (median) | marker lost after a motion |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for setup in CELLS:
        for strategy in STRATEGIES:
            rs = [r for r in runs if r["setup"] == setup and r["strategy"] == strategy]
            if not rs:
                continue
            reached = [r for r in rs if r["reached"]]
            per_seed = ", ".join(str(r["motions"]) + ("" if r["reached"] else "*") for r in rs)
            med = _median([r["motions"] for r in reached]) if len(reached) == len(rs) else math.nan
            med_txt = f"{med:.0f}" if not math.isnan(med) else f"> {max(r['motions'] for r in rs)} (not all reached)"
            robot_txt = f"{_median([r['robot_s'] for r in reached]):.1f}" if reached else "-"
            lines.append(
                f"| {setup} | {strategy} | {len(rs)} | {len(reached)} | {med_txt} | {per_seed} | "
                f"{robot_txt} | "
                f"{_median([r['sigma_mm'] for r in rs]):.2f} / {_median([r['sigma_deg'] for r in rs]):.3f} | "
                f"{_median([r['err_mm'] for r in rs]):.2f} / {_median([r['err_deg'] for r in rs]):.3f} | "
                f"{sum(r['lost_marker'] for r in rs)} |")
    lines += ["", "`*` = the run ended (max samples, or the fixed pattern / plan was used up) before the target.", ""]
    plans = [r for r in runs if r["strategy"] == "plan"]
    if plans:
        lines += ["`handeye plan` (plan.json) against its replay: motions planned to reach the target and made; "
                  "expected 1-sigma after the pose where the replay stopped and the 1-sigma it reached there "
                  "(medians; expected / reached per seed in mm).", "",
                  "| cell | runs | motions planned / made | expected 1-sigma [mm / deg] | reached [mm / deg] "
                  "| expected / reached, mm, per seed |", "|---|---|---|---|---|---|"]
        for setup in CELLS:
            rs = [r for r in plans if r["setup"] == setup]
            if rs:
                lines.append(
                    f"| {setup} | {len(rs)} | {_median([r['planned_motions'] for r in rs]):.0f} / "
                    f"{_median([r['motions'] for r in rs]):.0f} | {_median([r['expected_mm'] for r in rs]):.2f} / "
                    f"{_median([r['expected_deg'] for r in rs]):.3f} | {_median([r['sigma_mm'] for r in rs]):.2f} / "
                    f"{_median([r['sigma_deg'] for r in rs]):.3f} | "
                    + ", ".join(f"{r['expected_mm']:.2f} / {r['sigma_mm']:.2f}" for r in rs) + " |")
        lines += ["", f"Noise model of the plans: {plans[0]['noise_model']}.", ""]
    for setup in CELLS:
        o = [r["motions"] for r in runs if r["setup"] == setup and r["strategy"] == "optimal" and r["reached"]]
        rnd = [r["motions"] for r in runs if r["setup"] == setup and r["strategy"] == "random" and r["reached"]]
        if o and rnd:
            lines.append(f"- {setup}: optimal / random median motions = {np.median(o):.0f} / {np.median(rnd):.0f} "
                         f"= {np.median(o) / np.median(rnd):.2f} (target <= 0.5)")
    if val["poses"]:
        wall, cpu, own = (np.array(val[k]) for k in ("wall_ms", "cpu_ms", "cpu_planner_ms"))
        invalid = val["invalid_robot"] + val["invalid_view"]

        def stat(v):
            return f"{np.median(v):.0f} / {np.percentile(v, 95):.0f} / {v.max():.0f}"

        lines += ["", "## Validity of planned poses (no rendering)", "",
                  "| cells (random mountings) | planned poses | invalid: robot check | invalid: marker not in view "
                  "(truth) | runs ended: no valid pose / no estimate after bootstrap |", "|---|---|---|---|---|",
                  f"| {val['cells']} | {val['poses']} | {val['invalid_robot']} | {val['invalid_view']} | "
                  f"{val.get('no_valid_pose', 0)} / {val.get('no_estimate_after_bootstrap', 0)} |", "",
                  f"{invalid} invalid of {val['poses']} planned poses. Samples to target in these synthetic runs: "
                  + (f"median {_median(val['reached']):.0f} over the {len(val['reached'])} that reached it."
                     if val["reached"] else f"none reached it within {VALIDITY_SAMPLES} samples (the default depth "
                     "model's noise is ~10x the rendered camera's)."), "",
                  "Time to plan one optimal pose, ms, median / p95 / max (numpy single-threaded):", "",
                  "| wall, all | CPU, all | CPU, planner alone (candidates, screening, scoring, early estimate) "
                  "| CPU per call of the driver's `check_target` |", "|---|---|---|---|",
                  f"| {stat(wall)} | {stat(cpu)} | {stat(own)} | "
                  f"{1e3 * val['check_cpu_s'] / max(val['check_calls'], 1):.0f} (mean of {val['check_calls']}) |", "",
                  f"Over 100 ms: {int(np.sum(wall > 100))} of {len(wall)} wall, {int(np.sum(cpu > 100))} CPU."]
    lines += ["", f"Total benchmark time {elapsed:.0f} s."]
    return "\n".join(lines) + "\n"


def plot(path: Path, runs: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, setup in zip(axes, CELLS):
        data = [[r["motions"] for r in runs if r["setup"] == setup and r["strategy"] == s] for s in STRATEGIES]
        ax.boxplot(data)
        ax.set_xticks(range(1, len(STRATEGIES) + 1), ["optimal", "random", "fixed 17", "plan.json"])
        ax.set_title(f"{setup}: motions to 1 mm / 0.1 deg")
        ax.set_ylabel("robot motions")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None) -> int:
    """Run the benchmark; returns 0. See the module docstring."""
    ap = argparse.ArgumentParser(prog="python -m bench.plan", description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeds per cell and strategy (full calibrate runs)")
    ap.add_argument("--validity-poses", type=int, default=10000, help="planned poses to check at least")
    ap.add_argument("--out", default="out/bench", help="output folder for plan.md and plan.png")
    ap.add_argument("--seed", type=int, default=0, help="first seed (runs of several bounded parts add up)")
    ap.add_argument("--part", choices=["all", "motions", "validity"], default="all",
                    help="run one half only (each takes several minutes)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        k = 0
        for setup in (CELLS if args.part != "validity" else ()):
            for seed in range(args.seed, args.seed + args.seeds):
                for strategy in STRATEGIES:
                    for attempt in range(3):  # a simulator starved of CPU by other work may freeze its stream
                        k += 1
                        try:
                            r = run_strategy(setup, strategy, seed, f"{HOST_NET}.{k % 200 + 1}", Path(tmp))
                            break
                        except HandeyeError as e:
                            print(f"{setup} {strategy} seed {seed}: {e}; again", flush=True)
                    else:
                        raise RuntimeError(f"{setup} {strategy} seed {seed} failed three times")
                    print(f"[{time.perf_counter() - t0:6.0f} s] {setup} {strategy} seed {seed}: {r['motions']} motions, "
                          f"{r['stopped_by']}, {r['sigma_mm']:.2f} mm / {r['sigma_deg']:.3f} deg", flush=True)
                    runs.append(r)
    val = {"poses": 0, "invalid_robot": 0, "invalid_view": 0, "no_valid_pose": 0, "cells": 0, "check_calls": 0,
           "check_cpu_s": 0.0, "wall_ms": [], "cpu_ms": [], "cpu_planner_ms": [], "reached": []}
    per_setup = math.ceil(args.validity_poses / len(CELLS))
    for i, setup in enumerate(CELLS if args.part != "motions" else ()):
        cfg = load_config(CELLS[setup])
        cfg = cfg.model_copy(update={"robot": cfg.robot.model_copy(update={"host": f"{HOST_NET}.{210 + i}"})})
        rng = np.random.default_rng([args.seed, i])
        with devices.open_robot(cfg, read_only=True) as robot:
            state = robot.read()
            start = val["poses"]
            while val["poses"] - start < per_setup:
                val["cells"] += 1
                validity_run(setup, cfg, robot, state, rng, VALIDITY_SAMPLES, val)
        print(f"[{time.perf_counter() - t0:6.0f} s] validity {setup}: {val['poses']} poses so far", flush=True)
    report = format_report(runs, val, time.perf_counter() - t0)
    if runs:
        report += "\nPlot: `plan.png`.\n"
    (out / f"plan{'' if args.part == 'all' else '_' + args.part}.md").write_text(report)
    if runs:
        plot(out / "plan.png", runs)
    print(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
