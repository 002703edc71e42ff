"""Solver benchmark: the paper's sec. V in simulation, next to OpenCV, plus refinement, robustness, timings.

Run ``python -m bench [--quick | --tiny] [--out out/bench] [--seed S]``
(or ``python -m bench.solvers`` with the same options). Writes ``<out>/solvers.md`` and PNG plots, prints the
markdown. All data are eye-to-hand (static camera, marker on the flange:
``X = T_flange_marker``, ``Y = T_base_cam``) unless a table says eye-in-hand
(``X = T_flange_cam``, ``Y = T_base_marker``).

Experiments
-----------
1. Error vs number of samples (5..70), `handeye.calib.simulate.paper_setup` with the
   paper's experiment-1 noise (|N_A| < 15 deg / 0.02 m, |N_B| < 10 deg / 0.01 m),
   30 rounds; every method of Table I plus OpenCV's ``calibrateHandEye``
   (TSAI, PARK, HORAUD, ANDREFF, DANIILIDIS; eye-to-hand gets the inverted
   robot poses, as OpenCV documents) and ``calibrateRobotWorldHandEye``
   (SHAH, LI) on the same data.
2. Error vs noise level at N = 30: rotation noise 0..30 / 20 deg and
   translation noise 0..0.06 / 0.03 m (A / B) rising linearly, 40 rounds.
3. The realistic cell (`handeye.calib.simulate.realistic_cell`, 80 samples, 30 rounds),
   with YKronT' + ML refinement and the Cramér-Rao bound.
4. Efficiency and honesty of the refinement: RMS error / CRLB and NEES.
4b. Honesty of ``cov`` per method of Table I, closed form and refined: NEES
   on the realistic cell (``cov_kind`` says how each was computed).
5. Robustness to 0-30% gross outliers; 6. timings (with the monitoring engine's update; its shift
benchmark is ``python -m bench --shift``).

Errors are those of ``Y = T_base_cam``: rotation angle (deg) and translation
(mm). The reprojection error follows the paper: the marker point (origin of
the marker frame) mapped through both sides of ``A_i X = Y B_i``,
``e_i = |t(A_i X) - t(Y B_i)|``, reported as the mean of ``e_i^2`` (mm^2). We
use the noise-free poses ``A_i, B_i`` of the same samples, so it measures the
calibration, not the measurement noise.

Timings run single-threaded: this module sets OMP/OpenBLAS/MKL threads to 1
before numpy is imported (when it is imported first, as with ``python -m``).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from handeye.calib import simulate, solvers  # noqa: E402
from handeye.calib import transforms as tf  # noqa: E402
from handeye.calib.api import METHODS, closed_form, solve  # noqa: E402
from handeye.calib.errors import CalibrationError  # noqa: E402
from handeye.calib.problem import CalibrationProblem  # noqa: E402
from handeye.calib.monitor import MonitorEngine  # noqa: E402
from handeye.calib.setup import Setup  # noqa: E402
from handeye.calib.refine import cramer_rao_bound, error_vector, kron_t_prime_covariance, nees, refine  # noqa: E402
from bench.tables import markdown_table  # noqa: E402

cv2.setNumThreads(1)

OPENCV_HAND_EYE = {
    "cv2.TSAI": cv2.CALIB_HAND_EYE_TSAI,
    "cv2.PARK": cv2.CALIB_HAND_EYE_PARK,
    "cv2.HORAUD": cv2.CALIB_HAND_EYE_HORAUD,
    "cv2.ANDREFF": cv2.CALIB_HAND_EYE_ANDREFF,
    "cv2.DANIILIDIS": cv2.CALIB_HAND_EYE_DANIILIDIS,
}
OPENCV_ROBOT_WORLD = {
    "cv2.SHAH": cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH,
    "cv2.LI": cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI,
}
SOLVERS = list(METHODS) + list(OPENCV_HAND_EYE) + list(OPENCV_ROBOT_WORLD)
FOUR_BEST = ["YQuatT'", "YKronT'", "YQuatR*", "YKronRT"]


# --------------------------------------------------------------------------- solvers


def _complete_x(Y, A, B):
    """Eye-to-hand ``X = T_flange_marker`` given ``Y``: chordal mean of ``A_i^-1 Y B_i``."""
    Xs = tf.invert(A) @ Y @ B
    return tf.make_transform(tf.project_to_so3(Xs[:, :3, :3].sum(axis=0)), Xs[:, :3, 3].mean(axis=0))


def _opencv(name, A, B):
    """OpenCV on eye-to-hand data; returns (X, Y)."""
    if name in OPENCV_HAND_EYE:
        # Eye-to-hand: pass base->gripper (inverted robot poses); the result is cam->base = Y.
        Ai = tf.invert(A)
        R, t = cv2.calibrateHandEye(
            list(Ai[:, :3, :3]), list(Ai[:, :3, 3]), list(B[:, :3, :3]), list(B[:, :3, 3]),
            method=OPENCV_HAND_EYE[name],
        )
        Y = tf.make_transform(tf.project_to_so3(R), t.ravel())
        return _complete_x(Y, A, B), Y
    # AX = ZB with the marker as OpenCV's "camera" and our camera as its "world":
    # world2cam = T_marker_cam = B^-1, base2gripper = T_flange_base = A^-1;
    # base2world = T_cam_base = Y^-1, gripper2cam = T_marker_flange = X^-1.
    Bi, Ai = tf.invert(B), tf.invert(A)
    R_bw, t_bw, R_gc, t_gc = cv2.calibrateRobotWorldHandEye(
        list(Bi[:, :3, :3]), list(Bi[:, :3, 3]), list(Ai[:, :3, :3]), list(Ai[:, :3, 3]),
        method=OPENCV_ROBOT_WORLD[name],
    )
    Y = tf.invert(tf.make_transform(tf.project_to_so3(R_bw), t_bw.ravel()))
    X = tf.invert(tf.make_transform(tf.project_to_so3(R_gc), t_gc.ravel()))
    return X, Y


def run_solver(name, A, B):
    """(X, Y) of solver ``name`` on eye-to-hand poses ``B`` (YKronT' uses only their translations)."""
    if name in METHODS:
        res = closed_form(name, A, B)
        return res.X, res.Y
    return _opencv(name, A, B)


def errors(X, Y, d, n):
    """Rotation error (deg), translation error (mm) of Y and reprojection error (mm^2) on the first n samples."""
    rot, t = tf.pose_error(Y, d.Y)
    a = (d.A_true[:n] @ X)[:, :3, 3]
    b = (Y @ d.B_true[:n])[:, :3, 3]
    return np.rad2deg(rot), 1e3 * t, 1e6 * float(np.mean(np.sum((a - b) ** 2, axis=1)))


# --------------------------------------------------------------------------- experiments


def _steps(iterable, desc: str, total: int | None = None):
    """The loop with a progress bar on stderr (tqdm; off when stderr is not a terminal)."""
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, total=total, file=sys.stderr, leave=False, mininterval=0.5, disable=None)


def experiment_sample_count(rng, counts, rounds):
    """errs[solver] -> array (len(counts), rounds, 3) of (rot deg, trans mm, reproj mm^2); NaN on failure."""
    errs = {s: np.full((len(counts), rounds, 3), np.nan) for s in SOLVERS}
    for r in _steps(range(rounds), "rounds"):
        d = simulate.paper_setup(max(counts), rng)
        for k, n in enumerate(counts):
            for s in SOLVERS:
                try:
                    X, Y = run_solver(s, d.A[:n], d.B[:n])
                except (CalibrationError, cv2.error):
                    continue
                errs[s][k, r] = errors(X, Y, d, n)
    return errs


def experiment_noise(rng, levels, rounds, n):
    errs = {s: np.full((len(levels), rounds, 3), np.nan) for s in SOLVERS}
    for k, s_level in _steps(enumerate(levels), "noise levels", len(levels)):
        for r in range(rounds):
            d = simulate.paper_setup(
                n, rng,
                noise_A=(np.deg2rad(30.0) * s_level, 0.06 * s_level),
                noise_B=(np.deg2rad(20.0) * s_level, 0.03 * s_level),
            )
            for s in SOLVERS:
                try:
                    X, Y = run_solver(s, d.A, d.B)
                except (CalibrationError, cv2.error):
                    continue
                errs[s][k, r] = errors(X, Y, d, n)
    return errs


def experiment_realistic(rng, rounds, n):
    names = SOLVERS + ["YKronT'+ML"]
    errs = {s: np.full((rounds, 3), np.nan) for s in names}
    crlb = np.zeros((rounds, 2))
    for r in _steps(range(rounds), "rounds"):
        d = simulate.realistic_cell(n, rng)
        for s in SOLVERS:
            try:
                X, Y = run_solver(s, d.A, d.B)
            except (CalibrationError, cv2.error):
                continue
            errs[s][r] = errors(X, Y, d, n)
        res = solve("YKronT'", d.A, d.points, refine=True, point_cov=d.point_cov)
        errs["YKronT'+ML"][r] = errors(res.X, res.Y, d, n)
        c_rot, c_t, _ = cramer_rao_bound(d.X, d.Y, d.A_true, d.point_cov, setup=Setup.EYE_TO_HAND)
        crlb[r] = np.rad2deg(c_rot), 1e3 * c_t
    return errs, crlb


def experiment_efficiency(rng, trials, counts):
    """RMS error / CRLB and NEES of refined YKronT' per setup and N; NEES of other variants."""
    rows = []
    for setup in Setup:
        for n in counts:
            se = np.zeros((trials, 2))
            bound = np.zeros((trials, 2))
            ne = {"ML, given cov": [], "ML, default model": [], "closed form (delta)": [], "poses YQuatT'+ML": []}
            for k in _steps(range(trials), f"{setup} N={n}"):
                d = simulate.realistic_cell(n, rng, setup=setup)
                truth = d.Y if setup == Setup.EYE_TO_HAND else d.X
                res = solve("YKronT'", d.A, d.points, setup=setup, refine=True, point_cov=d.point_cov)
                e = error_vector(res.camera_transform, truth)
                se[k] = e[:3] @ e[:3], e[3:] @ e[3:]
                c_rot, c_t, _ = cramer_rao_bound(d.X, d.Y, d.A_true, d.point_cov, setup=setup)
                bound[k] = c_rot**2, c_t**2
                ne["ML, given cov"].append(nees(res.camera_transform, truth, res.cov))
                res = solve("YKronT'", d.A, d.points, setup=setup, refine=True)
                ne["ML, default model"].append(nees(res.camera_transform, truth, res.cov))
                res = solve("YKronT'", d.A, d.points, setup=setup, point_cov=d.point_cov)
                ne["closed form (delta)"].append(nees(res.camera_transform, truth, res.cov))
                res = solve("YQuatT'", d.A, d.B, setup=setup, refine=True, point_cov=d.point_cov)
                ne["poses YQuatT'+ML"].append(nees(res.camera_transform, truth, res.cov))
            rms = np.sqrt(se.mean(axis=0))
            crlb = np.sqrt(bound.mean(axis=0))
            rows.append((setup, n, rms, crlb, {k: float(np.mean(v)) for k, v in ne.items()}))
    return rows


def experiment_nees_methods(rng, trials, n):
    """Mean NEES of ``solve(...).cov`` per method, closed form and refined (eye-to-hand realistic cell).

    Returns {method: (cov_kind closed form, NEES closed form, NEES refined, ms per closed-form solve with cov)}.
    """
    rows = {m: ([], [], [], []) for m in METHODS}
    for _ in _steps(range(trials), "trials"):
        d = simulate.realistic_cell(n, rng)
        for m, info in METHODS.items():
            B = d.points if info.needs == "points" else d.B
            try:
                t0 = time.perf_counter()
                res = solve(m, d.A, B, point_cov=d.point_cov)
                rows[m][3].append(1e3 * (time.perf_counter() - t0))
                rows[m][0].append(res.cov_kind)
                rows[m][1].append(nees(res.Y, d.Y, res.cov))
                ref = solve(m, d.A, B, refine=True, point_cov=d.point_cov)
                rows[m][2].append(nees(ref.Y, d.Y, ref.cov))
            except CalibrationError:
                continue
    return {m: (v[0][0] if v[0] else "—", float(np.mean(v[1])), float(np.mean(v[2])), float(np.median(v[3])))
            for m, v in rows.items()}


def experiment_robust(rng, trials, n=60):
    rows = []
    for fraction in _steps((0.0, 0.1, 0.2, 0.3), "outlier fractions"):
        err, ref, found, n_bad, false_rej, times = [], [], 0, 0, 0, []
        for _ in range(trials):
            d = simulate.realistic_cell(n, rng)
            pts, bad = simulate.with_gross_outliers(d.points, fraction, rng)
            t0 = time.perf_counter()
            res = solve("YKronT'", d.A, pts, robust=True, point_cov=d.point_cov, rng=rng)
            times.append(time.perf_counter() - t0)
            good = np.setdiff1d(np.arange(n), bad)
            clean = solve("YKronT'", d.A[good], pts[good], point_cov=d.point_cov[good])
            err.append(tf.pose_error(res.Y, d.Y))
            ref.append(tf.pose_error(clean.Y, d.Y))
            found += len(np.intersect1d(res.rejected, bad))
            n_bad += len(bad)
            false_rej += len(np.setdiff1d(res.rejected, bad))
        err, ref = np.array(err), np.array(ref)
        ratio = np.sqrt((err**2).mean(axis=0) / (ref**2).mean(axis=0))
        rows.append((fraction, ratio, found / max(n_bad, 1), false_rej / (trials * n), 1e3 * float(np.median(times)),
                     np.rad2deg(np.sqrt((err[:, 0] ** 2).mean())), 1e3 * np.sqrt((err[:, 1] ** 2).mean())))
    return rows


def median_time_ms(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` in ms over ``repeats`` calls."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def experiment_timing(rng, counts, repeats, skip_slow):
    """Median wall time (ms) per solver and N on realistic-cell data.

    OpenCV's calibrateHandEye uses all sample pairs (O(N^2)): seconds at
    N = 1000, so it runs once there, or not at all when ``skip_slow``.
    """
    names = (SOLVERS[:len(METHODS)] + ["YKronT' (solver core, no input checks)"] + SOLVERS[len(METHODS):]
             + ["YKronT' closed-form covariance (analytic delta)", "YKronT'+ML (refine only)",
                "YKronT' robust (LMedS)", "monitoring engine update (per sample, median)"])
    table = {s: [] for s in names}
    for n, rep in zip(counts, repeats):
        d = simulate.realistic_cell(n, rng)
        for s in SOLVERS:
            if s in OPENCV_HAND_EYE and n >= 1000:
                table[s].append(np.nan if skip_slow else median_time_ms(lambda: run_solver(s, d.A, d.B), 1))
                continue
            table[s].append(median_time_ms(lambda: run_solver(s, d.A, d.B), rep))
        table["YKronT' (solver core, no input checks)"].append(
            median_time_ms(lambda: solvers.y_kron_t_prime_unchecked(d.A, d.points, Setup.EYE_TO_HAND), rep))
        start = closed_form("YKronT'", d.A, d.points)
        table["YKronT' closed-form covariance (analytic delta)"].append(median_time_ms(
            lambda: kron_t_prime_covariance(start.X, start.Y, CalibrationProblem.from_arrays(
                d.A, d.points, point_cov=d.point_cov)), rep))
        table["YKronT'+ML (refine only)"].append(median_time_ms(lambda: refine(start, CalibrationProblem.from_arrays(
            d.A, d.points, point_cov=d.point_cov)), rep))
        table["YKronT' robust (LMedS)"].append(
            median_time_ms(lambda: solve("YKronT'", d.A, d.points, robust=True, point_cov=d.point_cov, rng=rng),
                            max(1, rep // 5)))
    # The monitoring engine's update does not depend on N: one figure, measured on a stream.
    table["monitoring engine update (per sample, median)"] = [1e-3 * monitor_update_median_us(rng)] * len(counts)
    return table


def monitor_update_median_us(rng, n=480) -> float:
    """Median wall time (µs) of one `handeye.calib.monitor.MonitorEngine.update` over a simulated shift (realistic
    profile, armed from a 30-pose ``auto`` calibration with the robot's kinematic error, 4 stops)."""
    prof = simulate.RealisticProfile()
    real = simulate.realistic_profile(30, rng, prof)
    d = real.data
    F = prof.dh_error_factor(real.q)
    engine = MonitorEngine()
    problem = CalibrationProblem.from_arrays(d.A, d.points, point_cov=d.point_cov, robot_shared_error=F)
    engine.arm(solve("auto", problem, rng=rng), problem)
    shift = dataclasses.replace(simulate.Shift(), hours=n * simulate.Shift().sample_s / 3600.0)
    s = simulate.shift_stream(real, shift, rng, prof)
    F_s = prof.dh_error_factor(s.q)
    times = []
    for i in range(len(s.t)):
        t0 = time.perf_counter()
        engine.update(s.t[i], s.A[i], s.points[i], s.point_cov[i], F_s[i])
        times.append(time.perf_counter() - t0)
    return 1e6 * float(np.median(times))


# --------------------------------------------------------------------------- output


def _ms(values):
    """'mean ± sd' of finite values, 3 significant digits."""
    v = values[np.isfinite(values)]
    if len(v) == 0:
        return "failed"
    return f"{np.mean(v):.3g} ± {np.std(v):.2g}"


def _plot_curves(path, x, errs, xlabel, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = [
        ("AX=XB (Table I)", [s for s in METHODS if METHODS[s].equation == "AX=XB"]),
        ("AX=YB (Table I)", [s for s in METHODS if METHODS[s].equation == "AX=YB"]),
        ("OpenCV", list(OPENCV_HAND_EYE) + list(OPENCV_ROBOT_WORLD)),
    ]
    cols = ["rotation error (deg)", "translation error (mm)", "reprojection error (mm²)"]
    # A noise-free point (x = 0) has errors at rounding level: it would stretch the log axes over 20 decades.
    keep = np.asarray(x) > 0
    xs = np.asarray(x)[keep]
    fig, axes = plt.subplots(3, 3, figsize=(15, 12), sharex=True)
    for i, (gname, names) in enumerate(groups):
        for j, cname in enumerate(cols):
            ax = axes[i, j]
            for s in names:
                e = errs[s][keep, :, j]
                ok = np.isfinite(e)
                m = np.where(ok, e, 0).sum(axis=1) / np.maximum(ok.sum(axis=1), 1)
                sd = np.sqrt(np.where(ok, (e - m[:, None]) ** 2, 0).sum(axis=1) / np.maximum(ok.sum(axis=1), 1))
                m[ok.sum(axis=1) == 0] = np.nan
                (line,) = ax.plot(xs, m, label=s)
                # The paper shades a fraction of a standard deviation to keep curves readable.
                ax.fill_between(xs, m - 0.2 * sd, m + 0.2 * sd, color=line.get_color(), alpha=0.15)
            ax.set_yscale("log")
            ax.set_title(f"{gname}: {cname}", fontsize=9)
            if i == 2:
                ax.set_xlabel(xlabel)
            if j == 0:
                ax.legend(fontsize=7)
    fig.suptitle(f"{title} (mean, band = ±0.2 sd)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _plot_realistic(path, errs, crlb):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(errs)
    fig, axes = plt.subplots(1, 2, figsize=(14, 5))
    for j, (label, c) in enumerate((("rotation error (deg)", 0), ("translation error (mm)", 1))):
        m = [np.nanmean(errs[s][:, c]) for s in names]
        sd = [np.nanstd(errs[s][:, c]) for s in names]
        axes[j].bar(range(len(names)), m, yerr=sd, color="tab:blue", alpha=0.7)
        axes[j].axhline(np.sqrt(np.mean(crlb[:, c] ** 2)), color="tab:red", ls="--", label="Cramér-Rao bound (RMS)")
        axes[j].set_xticks(range(len(names)), names, rotation=70, fontsize=8)
        axes[j].set_yscale("log")
        axes[j].set_title(label)
        axes[j].legend()
    fig.suptitle("Realistic cell (eye-to-hand, camera 0.7 m, 1 mm / 3 mm point noise): error of T_base_cam")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _format_report(cfg, exp1=None, exp2=None, real=None, eff=None, nees_m=None, rob=None, timing=None,
                   elapsed=None):
    """The markdown report of the experiments run so far (None = not run: its section is left out)."""
    counts, levels = cfg["counts"], cfg["levels"]
    out = [
        "# Solver benchmark (simulation, eye-to-hand unless noted)",
        "",
        f"`{_command(cfg)}` — seed {cfg['seed']}, "
        "single-threaded BLAS (run time at the end). Errors of `Y = T_base_cam`: "
        "rotation (deg), translation (mm), mean ± sd over rounds; reprojection = mean squared distance (mm²) "
        "between the marker point mapped through `A_i X` and through `Y B_i` (noise-free poses). "
        "YKronT' uses only the marker center (translation of B).",
        "",
    ]
    if exp1 is not None:
        out += [f"## Experiment 1: error vs sample count (paper sec. V-A, {cfg['rounds1']} rounds, "
                "|N_A| < 15° / 20 mm, |N_B| < 10° / 10 mm)", ""]
        show = [k for k, n in enumerate(counts) if n in cfg["show_counts"]]
        headers = ["method"] + [f"{h} N={counts[k]}" for k in show for h in ("rot", "trans", "reproj")]
        rows = []
        for s in SOLVERS:
            row = [s]
            for k in show:
                row += [_ms(exp1[s][k, :, j]) for j in range(3)]
            rows.append(row)
        out += [markdown_table(headers, rows), ""]

    if exp2 is not None:
        out += [f"## Experiment 2: error vs noise (N = {cfg['n_noise']}, {cfg['rounds2']} rounds; level 1 = "
                "|N_A| < 30° / 60 mm, |N_B| < 20° / 30 mm)", ""]
        show = cfg["show_levels"]
        headers = ["method"] + [f"{h} @{levels[k]:.2f}" for k in show for h in ("rot", "trans")]
        rows = [[s] + [_ms(exp2[s][k, :, j]) for k in show for j in range(2)] for s in SOLVERS]
        out += [markdown_table(headers, rows), ""]

    if real is not None:
        errs, crlb = real
        out += [f"## Realistic cell (N = {cfg['n_real']}, {cfg['rounds_real']} rounds; camera 0.7 m away, flange "
                "±0.15 m / ±40°, point noise 1 mm lateral / 3 mm along the ray, marker pose noise 1°)", ""]
        rows = [[s, _ms(errs[s][:, 0]), _ms(errs[s][:, 1]), _ms(errs[s][:, 2])] for s in errs]
        rows.append(["Cramér-Rao bound (RMS)", f"{np.sqrt(np.mean(crlb[:, 0] ** 2)):.3g}",
                     f"{np.sqrt(np.mean(crlb[:, 1] ** 2)):.3g}", "—"])
        out += [markdown_table(["method", "rot (deg)", "trans (mm)", "reproj (mm²)"], rows), ""]

    if eff is not None:
        out += [f"## ML refinement vs the Cramér-Rao bound, covariance honesty ({cfg['trials_eff']} trials each)", "",
                "RMS error of the camera transform (`T_base_cam` eye-to-hand, `T_flange_cam` eye-in-hand) of "
                "YKronT'+ML with the true point covariance, against the CRLB (sqrt of the trace of the rotation / "
                "translation block of the inverse Fisher information at the truth). NEES should average 6.", ""]
        rows = []
        for setup, n, rms, bound, ne in eff:
            rows.append([setup, n, f"{np.rad2deg(rms[0]):.4f} / {np.rad2deg(bound[0]):.4f} = {rms[0] / bound[0]:.3f}",
                         f"{1e3 * rms[1]:.3f} / {1e3 * bound[1]:.3f} = {rms[1] / bound[1]:.3f}"]
                        + [f"{v:.2f}" for v in ne.values()])
        out += [markdown_table(["setup", "N", "rot RMS / CRLB (deg)", "trans RMS / CRLB (mm)"]
                          + [f"NEES {k}" for k in eff[0][4]], rows), ""]

    if nees_m is not None:
        out += [f"## Covariance honesty per method ({cfg['trials_nees']} trials, realistic cell N = {cfg['n_nees']}, "
                "eye-to-hand, true point covariance given)", "",
                "Mean NEES of `solve(...).cov` for `Y = T_base_cam` (6 if honest). Closed form: the first-order "
                "covariance of the closed-form estimator itself (`cov_kind`: delta-analytic for YKronT', "
                "delta-numerical for the pose methods up to 100 samples); refined: the inverse Fisher information "
                "of the ML estimate (method+ML). Time: median ms of one closed-form `solve` including its covariance.", ""]
        rows = [[m, kind, f"{a:.2f}", f"{b:.2f}", f"{t:.3g}"] for m, (kind, a, b, t) in nees_m.items()]
        out += [markdown_table(["method", "cov_kind (closed form)", "NEES closed form", "NEES refined (+ML)",
                           "closed form + cov (ms)"], rows), ""]

    if rob is not None:
        out += [f"## Robustness: gross outliers (N = 60, {cfg['trials_rob']} trials; half wrong depth +5..30%, "
                "half wrong marker 5..20 cm off)", "",
                "Ratio = RMS error of YKronT' + LMedS over that of YKronT' on the uncorrupted samples alone.", ""]
        rows = [[f"{100 * f:.0f}%", f"{r[0]:.3f}", f"{r[1]:.3f}", f"{rr:.3f}", f"{100 * found:.1f}%",
                 f"{100 * fr:.2f}%", f"{t:.0f}"]
                for f, r, found, fr, t, rr, rt in [(x[0], x[1], x[2], x[3], x[4], x[5], x[6]) for x in rob]]
        out += [markdown_table(["outliers", "rot ratio", "trans ratio", "rot RMS (deg)", "outliers found",
                           "inliers rejected", "time (ms)"], rows), ""]

    if timing is not None:
        out += ["## Timing (median ms, realistic-cell data, one thread; — = skipped in --quick)", ""]
        rows = [[s] + [f"{v:.3g}" if np.isfinite(v) else "—" for v in vals] for s, vals in timing.items()]
        out += [markdown_table(["solver"] + [f"N={n}" for n in cfg["time_counts"]], rows), ""]
    if elapsed is not None:
        out += [f"Run time: {elapsed:.0f} s on this machine."]
    return "\n".join(out)


def _command(cfg) -> str:
    """The command line that prints this report, as a user types it."""
    size = " --tiny" if cfg["tiny"] else " --quick" if cfg["quick"] else ""
    seed = f" --seed {cfg['seed']}" if cfg["seed"] else ""
    return f"python -m bench{size}{seed}"


def _config(quick: bool, tiny: bool, seed: int) -> dict:
    if quick:
        cfg = dict(counts=[5, 10, 30, 70], rounds1=5, levels=list(np.linspace(0, 1, 4)), rounds2=5, n_noise=30,
                   n_real=80, rounds_real=5, trials_eff=30, eff_counts=(30,), trials_nees=5, n_nees=30,
                   trials_rob=3, time_counts=(10, 100, 1000), time_repeats=(5, 3, 2))
    else:
        cfg = dict(counts=list(range(5, 71, 5)), rounds1=30, levels=list(np.linspace(0, 1, 11)), rounds2=40,
                   n_noise=30, n_real=80, rounds_real=30, trials_eff=300, eff_counts=(30, 80), trials_nees=150,
                   n_nees=30, trials_rob=20,
                   time_counts=(10, 100, 1000), time_repeats=(30, 10, 5))
    if tiny:
        for k in ("rounds1", "rounds2", "rounds_real", "trials_eff", "trials_nees", "trials_rob"):
            cfg[k] = 1
        cfg.update(counts=[5, 10], levels=[0.0, 0.5, 1.0], n_real=30, n_nees=10, time_counts=(10, 50),
                   time_repeats=(1, 1))
    n_lev = len(cfg["levels"])
    cfg.update(quick=quick, tiny=tiny, seed=seed, show_counts=(10, 30, 70),
               show_levels=sorted({n_lev // 3, (2 * n_lev) // 3, n_lev - 1}))
    return cfg


def main(argv=None) -> int:
    """Run the benchmark; returns 0. See the module docstring."""
    ap = argparse.ArgumentParser(prog="python -m bench", description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="small smoke run (< 1 min)")
    ap.add_argument("--out", default="out/bench", help="output folder for solvers.md and the PNG plots")
    ap.add_argument("--tiny", action="store_true", help="one round of everything at tiny sizes (smoke test)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    cfg = _config(args.quick or args.tiny, args.tiny, args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    # In report order: each section is printed (and flushed) as soon as its experiment is done.
    stages = [
        ("exp1", "experiment 1: error vs sample count",
         lambda: experiment_sample_count(rng, cfg["counts"], cfg["rounds1"])),
        ("exp2", "experiment 2: error vs noise", lambda: experiment_noise(rng, cfg["levels"], cfg["rounds2"], cfg["n_noise"])),
        ("real", "realistic cell", lambda: experiment_realistic(rng, cfg["rounds_real"], cfg["n_real"])),
        ("eff", "ML refinement vs the Cramér-Rao bound", lambda: experiment_efficiency(rng, cfg["trials_eff"],
                                                                                       cfg["eff_counts"])),
        ("nees_m", "covariance honesty per method", lambda: experiment_nees_methods(rng, cfg["trials_nees"],
                                                                                   cfg["n_nees"])),
        ("rob", "robustness to gross outliers", lambda: experiment_robust(rng, cfg["trials_rob"])),
        ("timing", "timing", lambda: experiment_timing(rng, cfg["time_counts"], cfg["time_repeats"],
                                                       skip_slow=cfg["quick"])),
    ]
    results: dict = {}
    printed = ""
    interrupted, current = False, ""
    try:
        for i, (key, title, run) in enumerate(stages, start=1):
            current = title
            print(f"bench.solvers [{i}/{len(stages)}] {title} ({time.perf_counter() - t0:.0f} s so far)",
                  file=sys.stderr, flush=True)
            results[key] = run()
            text = _format_report(cfg, **results)
            print(text[len(printed):], end="", flush=True)
            printed = text
    except KeyboardInterrupt:
        interrupted = True

    if "exp1" in results:
        _plot_curves(out / "solvers_samples.png", cfg["counts"], results["exp1"], "number of samples",
                     "Experiment 1: error vs sample count")
    if "exp2" in results:
        _plot_curves(out / "solvers_noise.png", cfg["levels"], results["exp2"],
                     "noise level (1 = 30°/60 mm on A, 20°/30 mm on B)", "Experiment 2: error vs noise")
    if "real" in results:
        _plot_realistic(out / "solvers_realistic.png", *results["real"])
    report = _format_report(cfg, **results, elapsed=time.perf_counter() - t0)
    if interrupted:
        report += (f"\n**Interrupted** during {current}: the sections above are complete, the rest did not "
                   "run.\n")
    else:
        report += "\nPlots: `solvers_samples.png`, `solvers_noise.png`, `solvers_realistic.png`.\n"
    (out / "solvers.md").write_text(report)
    print(report[len(printed):], flush=True)
    if interrupted:
        print(f"bench.solvers: interrupted; partial results in {out / 'solvers.md'}", file=sys.stderr, flush=True)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
