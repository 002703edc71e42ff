"""Closed-form overhead benchmark: solver core vs `closed_form` vs `solve` (input checks, residuals, covariance).

Run ``python -m bench.overhead [--repeats R] [--out out/bench]``. Prints the
markdown tables, writes ``<out>/overhead.md`` and ``<out>/overhead.png``.
Data: `handeye.calib.simulate.realistic_cell`, eye-to-hand (``X = T_flange_marker``,
``Y = T_base_cam``), marker poses for the pose methods and marker points for
YKronT'. Median wall time in ms, single-threaded: this module sets
OMP/OpenBLAS/MKL threads to 1 before numpy is imported.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from bench.solvers import median_time_ms  # noqa: E402
from handeye.calib import simulate, solvers  # noqa: E402
from handeye.calib import transforms as tf  # noqa: E402
from handeye.calib.api import METHODS, closed_form, solve  # noqa: E402
from handeye.calib.setup import Setup  # noqa: E402

COUNTS = (10, 100, 1000)


def median_ms(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` in ms over ``repeats`` calls, after one warm-up call."""
    fn()
    return median_time_ms(fn, repeats)


def measure(repeats: int, rng: np.random.Generator) -> tuple[dict, dict]:
    """Closed-form time per method and N, and the YKronT' pipeline broken into its steps."""
    methods, steps = {m: [] for m in METHODS}, {}
    for n in COUNTS:
        d = simulate.realistic_cell(n, rng)
        for m, info in METHODS.items():
            B = d.points if info.needs == "points" else d.B
            methods[m].append(median_ms(lambda: closed_form(m, d.A, B), repeats))
        est = closed_form("YKronT'", d.A, d.points)
        rows = {
            "check_transforms(A)": lambda: tf.check_transforms(d.A, "A"),
            "YKronT' solver core": lambda: solvers.y_kron_t_prime_unchecked(d.A, d.points, Setup.EYE_TO_HAND),
            "residuals (validated)": lambda: solvers.residuals(est.X, est.Y, d.A, d.points, Setup.EYE_TO_HAND),
            "closed_form(\"YKronT'\")": lambda: closed_form("YKronT'", d.A, d.points),
            "solve(\"YKronT'\") (with cov)": lambda: solve("YKronT'", d.A, d.points),
        }
        for name, fn in rows.items():
            steps.setdefault(name, []).append(median_ms(fn, repeats))
    return methods, steps


def md_table(first: str, rows: dict) -> str:
    lines = [f"| {first} | " + " | ".join(f"N={n}" for n in COUNTS) + " |", "|---" * (len(COUNTS) + 1) + "|"]
    lines += [f"| {k} | " + " | ".join(f"{v:.3f}" for v in vals) + " |" for k, vals in rows.items()]
    return "\n".join(lines)


def plot(path: Path, methods: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for m, vals in methods.items():
        ax.loglog(COUNTS, vals, marker="o", label=m)
    ax.set_xlabel("samples N")
    ax.set_ylabel("closed_form time (ms, median, 1 thread)")
    ax.set_title("closed_form: solver + input checks + residuals (eye-to-hand)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.overhead", description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=50, help="timed calls per cell (median reported)")
    ap.add_argument("--out", default="out/bench", help="folder for overhead.md and overhead.png")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    methods, steps = measure(args.repeats, np.random.default_rng(args.seed))
    report = ("## closed_form per method (ms)\n\n" + md_table("method", methods)
              + "\n\n## YKronT' pipeline steps (ms)\n\n" + md_table("step", steps) + "\n")
    print(report)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "overhead.md").write_text(report)
    plot(out / "overhead.png", methods)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
