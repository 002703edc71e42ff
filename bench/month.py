"""A month left alone (issue 42): the monitoring engine over 30 days of a realistic cell, against the truth.

Run ``python -m bench --month [--seeds 5] [--first-seed 0] [--days 30] [--stops 4] [--distance 0.8] [--programs 1]
[--jobs 2] [--sessions DIR]``; ``--programs N`` composes the production of N programs, one per 8 h shift drawn at
random. Prints the tables (also ``<out>/month.md``) and plots the live error and its stated 1-sigma day by day
(``<out>/month.png``). ``--sessions DIR`` also writes each cell as two handeye sessions, its arming calibration
and its month (`write_sessions`), for ``handeye replay DIR/<cell>/month --monitor --reference
DIR/<cell>/calibration``.

Each seed gives four cells: eye-to-hand and eye-in-hand, each with the robot's joints (the engine holds its
kinematic error) and without (a pose-only source: ROS 2 ``PoseStamped``, another tool's recording). A cell is
`handeye.calib.simulate.realistic_profile` (UR10 DH error, 1.5 % depth scale, 3 mm depth offset, 1 % focal, 2 px
misregistration) calibrated with ``auto`` from 30 poses, then `handeye.calib.simulate_month.month_stream`: a sample every
30 s at the program's stops; each stop with its own fixed error beyond the DH error (0.1-0.5 mm, drawn per cell);
the mount breathing a daily cycle of 0.5-2 mm (and 0.01 deg) beside a 0.05 mm/sqrt(h) walk; four 5 mm / 0.3 deg
bumps at random hours, one in each week.

Per cell-day: the live workspace error against the truth (RMS over 200 held-out marker poses, where the camera is
used; eye-in-hand in the flange frame), the stated 1-sigma over the workspace, and the mean of (error / sigma)^2
(1 when honest). The bound is ``max(1 mm, 1.5 x the arming calibration's realised or stated error)``; after a
re-learn a day is also within when its p95 is within 1.5x an oracle's, the camera registered from every sample since
the bump with its time known (`oracle_errors`): a bump can leave the camera where the program's stops determine it
less well than the arming did. The 40 samples after each bump (the re-learn) are left out of the accuracy figures.
The camera correction's wander is its largest distance from the arming's value in the arming's 1-sigma. Beside
the bumps flagged within 20 samples, the number the best test would flag (`bench.detection.bump_limits`: the
bump's time and the noise known, each stop's 20 samples after it against its visits since the previous re-learn),
and for each bump flagged later or never, that test's probability of flagging it within 20.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import functools  # noqa: E402
import multiprocessing  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402
from types import SimpleNamespace  # noqa: E402

import numpy as np  # noqa: E402

from bench.detection import bump_limits  # noqa: E402
from bench.shift import RECOVER_WITHIN, classify_alarms, workspace_error  # noqa: E402
from bench.tables import markdown_table  # noqa: E402
from handeye.calib import simulate, solve  # noqa: E402
from handeye.calib import transforms as tf  # noqa: E402
from handeye.calib.monitor import MonitorEngine, MonitorSettings  # noqa: E402
from handeye.calib.problem import CalibrationProblem  # noqa: E402
from handeye.calib.setup import Setup  # noqa: E402
from handeye.calib.simulate_month import DAY_S, Month, month_stream  # noqa: E402

#: Where a cell's month starts in the sessions `write_sessions` writes (2026-01-05 06:00 UTC), s since the epoch.
SESSION_EPOCH = 1_767_592_800.0
#: Held-out workspace poses per cell.
WORKSPACE_POINTS = 200
#: The live estimate is scored at every this many samples (the month's figures are per day).
SCORE_EVERY = 10
#: Calibration poses of the arming.
CALIBRATION_POSES = 30


@dataclass(frozen=True)
class CellSpec:
    """One cell of the benchmark: seed, setup and whether its samples carry joints."""

    seed: int
    setup: Setup
    joints: bool
    days: float
    stops: int
    distance: float
    programs: int = 1

    @property
    def name(self) -> str:
        side = "eye-to-hand" if self.setup == Setup.EYE_TO_HAND else "eye-in-hand"
        return f"{side}, {'joints' if self.joints else 'poses only'}, seed {self.seed}"

    @property
    def directory(self) -> str:
        """The name as a directory (`write_sessions`): ``eye-to-hand_poses-only_seed-0``."""
        return self.name.replace(", ", "_").replace(" ", "-")


@dataclass
class CellRun:
    """One cell's month: per scored sample the day, error, stated sigma and whether it is settled (outside the
    re-learn windows); the alarms; the arming figures; the camera correction's wander."""

    spec: CellSpec
    stop_error_mm: float
    thermal_mm: float
    day: np.ndarray
    error_mm: np.ndarray
    sigma_mm: np.ndarray
    settled: np.ndarray
    moved: list
    drifting: int
    bumped: list
    arming_mm: float
    stated_mm: float
    wander_sigma: np.ndarray      # (3,) the camera correction's largest distance from the arming's, in its 1-sigma
    seconds: float
    oracle_mm: np.ndarray         # per scored sample the oracle's error (`oracle_errors`); nan before a bump
    limits: list                  # per bump the probability that the best test flags it within 20 samples

    @property
    def bound_mm(self) -> float:
        return max(1.0, 1.5 * max(self.arming_mm, self.stated_mm))

    def day_p95(self, d: int) -> float:
        """The live error's p95 on day ``d``, mm (its settled samples)."""
        return float(np.percentile(self.error_mm[(self.day == d) & self.settled], 95))

    def within(self, d: int) -> bool:
        """Day ``d``'s p95 is within the bound or, on a day after a re-learn, within 1.5x the oracle's p95 over the
        same samples (the issue's two criteria)."""
        p95 = self.day_p95(d)
        oracle = self.oracle_mm[(self.day == d) & self.settled]
        after = not np.isnan(oracle).any()
        return p95 <= self.bound_mm or (after and p95 <= 1.5 * float(np.percentile(oracle, 95)))


def month_of(spec: CellSpec, rng: np.random.Generator) -> Month:
    """The cell's month: its stops' error (0.1-0.5 mm), its mount's daily cycle (0.5-2 mm), a bump in each week."""
    week = spec.days / 4.0
    bumps = tuple(((k + rng.uniform(0.1, 0.9)) * week, 5.0, 0.3) for k in range(4))
    return Month(days=spec.days, stops=spec.stops, programs=spec.programs, stop_error_m=rng.uniform(0.1e-3, 0.5e-3),
                 thermal_mm=rng.uniform(0.5, 2.0), bumps=bumps)


def oracle_errors(real, result, stream, P, scored: np.ndarray) -> np.ndarray:
    """The oracle's live workspace error (mm) at the ``scored`` samples: the camera transform registered from every
    sample since the last bump (its time known; `handeye.calib.transforms.register_points` on running sums), the
    arming's marker mount and camera correction held; nan before the first bump (there is nothing to re-learn).

    Eye-to-hand it registers the corrected camera points to the marker's points in the base frame
    (``T_base_flange @ X``), giving ``T_base_cam``; eye-in-hand to the marker's points in the flange frame
    (``inv(T_base_flange) @ Y``), giving ``T_flange_cam``.
    """
    eye_to_hand = real.data.setup == Setup.EYE_TO_HAND
    mount = (result.X if eye_to_hand else result.Y)[:3, 3]
    A = stream.A_stops[stream.stop]
    parent = tf.transform_points(A if eye_to_hand else tf.invert(A), mount)
    seen = result.camera_correction.correct(stream.points)
    out = np.full(len(scored), np.nan)
    ends = list(stream.bumped[1:]) + [len(stream.t)]
    for b, end in zip(stream.bumped, ends):
        at = np.flatnonzero((scored >= b + 2) & (scored < end))      # three samples or more since the bump
        i = scored[at]
        n = (i - b + 1)[:, None]
        sp, sq = np.cumsum(seen[b:end], axis=0)[i - b], np.cumsum(parent[b:end], axis=0)[i - b]
        sqp = np.cumsum(parent[b:end, :, None] * seen[b:end, None, :], axis=0)[i - b]
        R = tf.project_to_so3(sqp - sq[:, :, None] * sp[:, None, :] / n[:, :, None])
        t = (sq - np.einsum("kij,kj->ki", R, sp)) / n
        for k, j in enumerate(at):
            C = tf.make_transform(R[k], t[k])
            out[j] = workspace_error(C, result.camera_correction, real.camera, stream.C[i[k]], P) * 1e3
    return out


def write_sessions(root: Path, spec: CellSpec, real, stream, joints) -> Path:
    """The cell as two handeye sessions under ``root/<cell>/``: ``calibration`` (the arming's 30 samples, an hour
    before the month) and ``month`` (a sample at each stop of the month, with its joints when the cell has them;
    ``joints`` (S, 6) or None per stop). Eye-to-hand ``T_base_flange`` and the marker centre in the camera frame,
    eye-in-hand the same pair; the camera transform they determine is ``T_base_cam`` / ``T_flange_cam``. Returns
    the cell's directory."""
    from handeye.app.session import SessionWriter
    from handeye.calib.observation import Observation

    cell = root / spec.directory
    d = real.data
    q = real.q if spec.joints else [None] * len(d.A)
    start = SESSION_EPOCH - 3600.0 - 10.0 * len(d.A)
    with SessionWriter.create(cell, spec.setup, name="calibration", source="bench.month") as w:
        for i in range(len(d.A)):
            w.add_sample(Observation(i, start + 10.0 * i, d.A[i], d.points[i], d.point_cov[i], joints=q[i]))
    with SessionWriter.create(cell, spec.setup, name="month", source="bench.month") as w:
        for i, s in enumerate(stream.stop):
            w.add_sample(Observation(i, SESSION_EPOCH + float(stream.t[i]), stream.A_stops[s], stream.points[i],
                                     stream.point_cov[i], joints=None if joints is None else joints[s]))
    return cell


def run_cell(spec: CellSpec, settings: MonitorSettings | None = None, sessions: Path | None = None) -> CellRun:
    """Calibrate the cell, arm the engine, run its month and score it (module docstring); with ``sessions``, write
    the cell's sessions there first (`write_sessions`)."""
    rng = np.random.default_rng([spec.seed, 42, spec.setup == Setup.EYE_TO_HAND, spec.joints])
    month = month_of(spec, rng)
    prof = simulate.RealisticProfile(pose_error_m=month.stop_error_m)
    real = simulate.realistic_profile(CALIBRATION_POSES, rng, prof, distance=spec.distance, setup=spec.setup)
    d = real.data
    factor = prof.dh_error_factor(real.q) if spec.joints else None
    problem = CalibrationProblem.from_arrays(d.A, d.points, setup=spec.setup, point_cov=d.point_cov,
                                             robot_shared_error=factor)
    result = solve("auto", problem, rng=rng)
    engine = MonitorEngine(settings)
    reference = engine.arm(result, problem)
    arming_C = result.Y if spec.setup == Setup.EYE_TO_HAND else result.X
    theta0, theta_sigma = engine.filter.u[3:6].copy(), np.sqrt(np.diag(engine.filter.P)[9:12])
    stream = month_stream(real, month, rng, prof)
    P = simulate.workspace_points(real, WORKSPACE_POINTS, rng)
    arming = workspace_error(arming_C, result.camera_correction, real.camera, stream.C[0], P) * 1e3
    factors = prof.dh_error_factor(stream.q_stops) if spec.joints else [None] * len(stream.q_stops)
    if sessions is not None:
        write_sessions(sessions, spec, real, stream, stream.q_stops if spec.joints else None)
    # The detection limit (`bench.detection.bump_limits`): the marker side is T_flange_marker eye-to-hand,
    # T_base_marker eye-in-hand; the robot's repeatability at every visit.
    seen = SimpleNamespace(bumped=stream.bumped, t=stream.t, Y=stream.C, stop=stream.stop,
                           A=stream.A_true_stops[stream.stop], point_cov=stream.point_cov)
    robot_cov = prof.repeatability_cov()
    limits = bump_limits(seen, d.X if spec.setup == Setup.EYE_TO_HAND else d.Y, spec.setup, robot_cov,
                         engine.detector.threshold)
    settled = np.ones(len(stream.t), dtype=bool)
    for b in stream.bumped:
        settled[b:b + RECOVER_WITHIN] = False
    scored = np.arange(0, len(stream.t), SCORE_EVERY)
    err, sig = np.empty(len(scored)), np.empty(len(scored))
    moved, drifting = [], 0
    wander = np.zeros(3)
    t0 = time.perf_counter()
    k = 0
    for i in range(len(stream.t)):
        s = stream.stop[i]
        upd = engine.update(stream.t[i], stream.A_stops[s], stream.points[i], stream.point_cov[i], factors[s])
        if upd.alarm == "moved":
            moved.append(i)
        elif upd.alarm == "drifting":
            drifting += 1
        if k < len(scored) and scored[k] == i:
            err[k] = workspace_error(upd.camera_transform, engine.camera_correction, real.camera, stream.C[i], P) * 1e3
            sig[k] = upd.sigma_mm
            if settled[i]:
                wander = np.maximum(wander, np.abs(engine.filter.u[3:6] - theta0) / theta_sigma)
            k += 1
    seconds = time.perf_counter() - t0
    print(f"  {spec.name}: {seconds:.0f} s", file=sys.stderr, flush=True)
    return CellRun(spec, month.stop_error_m * 1e3, month.thermal_mm, np.floor(stream.t[scored] / DAY_S).astype(int),
                   err, sig, settled[scored], moved, drifting, [int(b) for b in stream.bumped], arming,
                   reference.sigma_mm, wander, seconds, oracle_errors(real, result, stream, P, scored), limits)


def cell_row(run: CellRun) -> list:
    """One row of the cells table."""
    days = np.unique(run.day)
    p95 = np.array([run.day_p95(d) for d in days])
    within = sum(run.within(d) for d in days)
    ratio = (run.error_mm[run.settled] / run.sigma_mm[run.settled]) ** 2
    delays, late, false = classify_alarms(run.moved, run.bumped)
    flagged = sum(d is not None for d in delays)
    return [run.spec.name, f"{run.stop_error_mm:.2f}", f"{run.thermal_mm:.2f}",
            f"{run.arming_mm:.2f} / {run.stated_mm:.2f}", f"{run.bound_mm:.2f}", f"{p95.max():.2f}",
            f"{within}/{len(days)} ({int((p95 <= run.bound_mm).sum())})",
            f"{np.median(run.sigma_mm[run.settled]):.2f}", f"{ratio.mean():.2f}",
            " / ".join(f"{w:.1f}" for w in run.wander_sigma), false,
            f"{flagged}/{len(run.bumped)} ({sum(run.limits):.1f})", late_text(delays, late, run.limits), run.drifting,
            f"{run.seconds:.0f}"]


CELL_HEADERS = ["cell", "stop error [mm]", "daily cycle [mm]", "arming realised / stated [mm]", "bound [mm]",
                "worst day p95 [mm]", "days within bound or 1.5x the oracle after a re-learn (the bound alone)",
                "stated 1-sigma median [mm]", "mean (error/sigma)^2",
                "camera correction wander [sigma] (scale / offset / focal)", "false moved",
                "bumps flagged within 20 (the limit expects)", "the others: flagged after [samples] (the limit's power)",
                "drifting alarms", "time [s]"]


def late_text(delays, late, limits) -> str:
    """The bumps not flagged within 20 samples: when they were (or never, before the next bump), and how likely
    the limit was to flag each within 20."""
    out = [f"{'never' if lt is None else lt} ({p:.0%})" for d, lt, p in zip(delays, late, limits) if d is None]
    return ", ".join(out) or "-"


def day_rows(runs: list[CellRun]) -> list:
    """Per day over the cells: median live error, median stated 1-sigma, mean (error / sigma)^2, cells within
    their bound."""
    rows = []
    for d in np.unique(np.concatenate([r.day for r in runs])):
        err, sig, within = [], [], 0
        for r in runs:
            keep = (r.day == d) & r.settled
            err.append(r.error_mm[keep])
            sig.append(r.sigma_mm[keep])
            within += r.within(d)
        e, s = np.concatenate(err), np.concatenate(sig)
        rows.append([int(d), f"{np.median(e):.2f}", f"{np.percentile(e, 95):.2f}", f"{np.median(s):.2f}",
                     f"{np.mean((e / s) ** 2):.2f}", f"{within}/{len(runs)}"])
    return rows


DAY_HEADERS = ["day", "live error median [mm]", "live error p95 [mm]", "stated 1-sigma median [mm]",
               "mean (error/sigma)^2", "cells within bound"]


def summary(runs: list[CellRun]) -> str:
    """The issue's targets in one paragraph."""
    ratios = np.array([np.mean((r.error_mm[r.settled] / r.sigma_mm[r.settled]) ** 2) for r in runs])
    within = sum(all(r.within(d) for d in np.unique(r.day)) for r in runs)
    classified = [classify_alarms(r.moved, r.bumped) for r in runs]
    false = sum(c[2] for c in classified)
    flagged = sum(sum(d is not None for d in c[0]) for c in classified)
    bumps = sum(len(r.bumped) for r in runs)
    limit = sum(sum(r.limits) for r in runs)
    wander = max(float(r.wander_sigma.max()) for r in runs)
    return (f"{len(runs)} cells: {within} within their bound (after a re-learn, or 1.5x the oracle) every day; "
            f"mean (error/sigma)^2 {ratios.mean():.2f} over the cells (largest {ratios.max():.2f}, target 0.5-2, at "
            f"most 4); camera correction within {wander:.1f} sigma of the arming's; {false} false moved alarms; "
            f"{flagged}/{bumps} bumps flagged within 20 samples, where the best test (the bump's time and the noise "
            f"known) would flag {limit:.1f}.")


def plot(runs: list[CellRun], path: Path) -> None:
    """Live error and stated 1-sigma per cell over the month."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    for r in runs:
        t = r.day + 0.0
        line, = axes[0].plot(t[r.settled], r.error_mm[r.settled], ".", ms=1, alpha=0.4)
        axes[0].plot(t[r.settled], r.sigma_mm[r.settled], "-", lw=0.8, color=line.get_color())
        axes[1].plot(t[r.settled], (r.error_mm[r.settled] / r.sigma_mm[r.settled]) ** 2, ".", ms=1, alpha=0.3,
                     color=line.get_color())
    axes[0].set_ylabel("live error (dots), stated 1-sigma (lines) [mm]")
    axes[1].set_ylabel("(error / sigma)^2")
    axes[1].set_yscale("log")
    axes[1].set_xlabel("day")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def specs(seeds: list[int], days: float, stops: int, distance: float, programs: int = 1) -> list[CellSpec]:
    return [CellSpec(seed, setup, joints, days, stops, distance, programs)
            for seed in seeds for setup in (Setup.EYE_TO_HAND, Setup.EYE_IN_HAND) for joints in (True, False)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench --month", description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="four cells per seed (both setups, with and without joints)")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--days", type=float, default=30.0)
    ap.add_argument("--stops", type=int, default=4)
    ap.add_argument("--distance", type=float, default=0.8, help="camera to marker at the calibration, m")
    ap.add_argument("--programs", type=int, default=1,
                    help="programs of --stops stops each, one per 8 h shift drawn at random (composed production)")
    ap.add_argument("--jobs", type=int, default=1, help="cells run at once")
    ap.add_argument("--out", type=Path, default=Path("out/bench"))
    ap.add_argument("--sessions", type=Path, default=None,
                    help="also write each cell as handeye sessions here (<cell>/calibration, <cell>/month: about "
                         "60 MB a cell-month), for handeye replay --monitor")
    args = ap.parse_args(argv)
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    cells = specs(seeds, args.days, args.stops, args.distance, args.programs)
    t0 = time.monotonic()
    if args.jobs > 1:
        # The workers leave Ctrl-C to this process, which ends them (leaving the pool terminates it).
        with multiprocessing.get_context("spawn").Pool(args.jobs, signal.signal, (signal.SIGINT, signal.SIG_IGN)) \
                as pool:
            runs = pool.map(functools.partial(run_cell, sessions=args.sessions), cells)
    else:
        runs = [run_cell(c, sessions=args.sessions) for c in cells]
    programs = f", {args.programs} programs of them" if args.programs > 1 else ""
    text = (f"### A month left alone: {args.days:g} days, {args.stops} stops{programs}, seeds {seeds[0]}-{seeds[-1]} "
            f"(`python -m bench --month --seeds {args.seeds} --first-seed {args.first_seed} --days {args.days:g} "
            f"--stops {args.stops} --distance {args.distance:g} --programs {args.programs}`)\n\n"
            + summary(runs) + "\n\n"
            + markdown_table(CELL_HEADERS, [cell_row(r) for r in runs])
            + "\n\nPer day, over the cells:\n\n" + markdown_table(DAY_HEADERS, day_rows(runs))
            + f"\n\n({time.monotonic() - t0:.0f} s)")
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "month.md").write_text(text + "\n")
    plot(runs, args.out / "month.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
