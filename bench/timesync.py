"""Benchmark of the clock-offset estimate (handeye.calib.timesync) and the pose-stream importer.

Eye-in-hand streams throughout (X = T_flange_cam, Y = T_base_marker).

1. Synthetic: a 50 Hz robot stream and a 30 Hz camera stream stamped ``offset``
   s early, camera rotation noise sigma in deg; error of the angular-speed
   cross-correlation estimate and its run time, over seeds.
2. The pose-stream importer's pipeline at library level on the same kind of
   streams: cross-correlation, then refinement on the YKronT' residual; the
   errors of both, the residual at the refined offset and at zero, and a plot
   of the residual against the offset (out/bench/timesync_residual_vs_offset.png).
   (The real ETH recordings are measured through the importer by
   tests/regression, which may read tests/data; a benchmark does not.)

Run: ``python -m bench.timesync [--seeds N]``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from handeye.calib import timesync
from handeye.calib import transforms as tf
from handeye.calib.api import closed_form
from handeye.calib.setup import Setup

OUT = Path("out/bench")


def synthetic_streams(rng: np.random.Generator, offset: float, noise_deg: float, duration: float = 30.0):
    """Robot (true clock) and camera (clock late by ``offset``) streams of a smooth random motion."""
    X = tf.make_transform(tf.random_rotations(1, 1.0, rng)[0], [0.05, -0.02, 0.1])
    Y = tf.make_transform(tf.random_rotations(1, 1.0, rng)[0], [0.8, 0.1, 0.0])
    freq = rng.uniform(0.1, 0.5, size=(3, 2))
    phase = rng.uniform(0, 2 * np.pi, size=(3, 2))

    def A_at(t):
        rv = 0.4 * np.sin(2 * np.pi * np.outer(t, freq[:, 0]) + phase[:, 0])
        p = [0.5, 0.0, 0.6] + 0.1 * np.sin(2 * np.pi * np.outer(t, freq[:, 1]) + phase[:, 1])
        return tf.from_rotvec_translation(rv, p)

    t_a = np.arange(0.0, duration, 0.02)
    t_b = np.arange(0.013, duration, 1 / 30)
    B = tf.invert(A_at(t_b) @ X) @ Y
    noise = tf.from_rotvec_translation(rng.normal(scale=np.deg2rad(noise_deg), size=(len(B), 3)),
                                       rng.normal(scale=0.001, size=(len(B), 3)))
    return t_a, A_at(t_a), t_b - offset, B @ noise


def bench_synthetic(seeds: int) -> str:
    lines = ["| camera noise [deg] | true offset [ms] | mean abs error [ms] | max abs error [ms] | time [ms] |",
             "|---|---|---|---|---|"]
    for noise in (0.1, 0.5, 1.0):
        for offset in (0.0, 0.1, -0.35):
            errs, times = [], []
            for seed in range(seeds):
                t_a, A, t_b, B = synthetic_streams(np.random.default_rng(seed), offset, noise)
                t0 = time.perf_counter()
                est = timesync.estimate_clock_offset(t_a, A, t_b, B, max_offset=0.5)
                times.append(time.perf_counter() - t0)
                errs.append(abs(est.offset - offset))
            lines.append(f"| {noise} | {offset * 1e3:+.0f} | {np.mean(errs) * 1e3:.2f} | {np.max(errs) * 1e3:.2f} "
                         f"| {np.median(times) * 1e3:.0f} |")
    return "\n".join(lines)


def bench_refined(seeds: int) -> str:
    """The importer's whole offset pipeline at library level on simulated streams: cross-correlation,
    then refinement on the YKronT' residual (`handeye.calib.timesync.calibration_cost`, `refine_clock_offset`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lines = ["| true offset [ms] | xcorr error [ms] | corr. | refined error [ms] | YKronT' RMS at refined [mm] "
             "| at 0 [mm] | time [s] |", "|---|---|---|---|---|---|---|"]
    fig, ax = plt.subplots(figsize=(7, 4))

    def rms(A_p, B_p):
        return closed_form("YKronT'", A_p, B_p, setup=Setup.EYE_IN_HAND).residuals.rms_translation

    for offset in (0.0, 0.04, -0.12):
        rows = []
        for seed in range(seeds):
            t_a, A, t_b, B = synthetic_streams(np.random.default_rng(100 + seed), offset, 0.5)
            t0 = time.perf_counter()
            est = timesync.estimate_clock_offset(t_a, A, t_b, B, max_offset=0.5)
            cost = timesync.calibration_cost(t_a, A, t_b, B, rms)
            ref = timesync.refine_clock_offset(cost, est.offset, half_width=0.05)
            rows.append((abs(est.offset - offset), est.score, abs(ref.offset - offset), ref.score, cost(0.0),
                         time.perf_counter() - t0))
            if seed == 0:
                offsets = offset + np.linspace(-0.15, 0.15, 61)
                ax.plot(offsets * 1e3, [cost(o) * 1e3 for o in offsets], label=f"true offset {offset * 1e3:+.0f} ms")
        r = np.array(rows)
        lines.append(f"| {offset * 1e3:+.0f} | {r[:, 0].mean() * 1e3:.2f} | {r[:, 1].mean():.3f} "
                     f"| {r[:, 2].mean() * 1e3:.2f} | {r[:, 3].mean() * 1e3:.2f} | {r[:, 4].mean() * 1e3:.2f} "
                     f"| {np.median(r[:, 5]):.2f} |")
    ax.set_xlabel("clock offset t_robot - t_camera [ms]")
    ax.set_ylabel("YKronT' residual RMS [mm]")
    ax.set_yscale("log")
    ax.legend()
    ax.set_title("simulated pose streams (eye-in-hand): residual vs clock offset")
    OUT.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(OUT / "timesync_residual_vs_offset.png", dpi=100)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=5, help="random streams per synthetic cell")
    args = p.parse_args(argv)
    print("## Clock offset from angular-speed correlation (synthetic, eye-in-hand)\n")
    print(bench_synthetic(args.seeds))
    print("\n## Cross-correlation + refinement on the residual (simulated, eye-in-hand)\n")
    print(bench_refined(args.seeds))
    print(f"\nplot: {OUT / 'timesync_residual_vs_offset.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
