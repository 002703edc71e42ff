"""YAxisR (Zhuang 1994) before/after the pre-rotation: accuracy on the paper's data and exactness near half-turns.

Run ``python -m bench.yaxisr [--rounds R] [--out out/bench]``. Prints markdown,
writes ``<out>/yaxisr.md`` and ``<out>/yaxisr.png`` (rotation error of Y per
round against ``|y_0|``, the scalar part of the true ``R_Y`` quaternion that
Zhuang's reduction divides by). "unrotated" is Zhuang's reduction solved
directly in the given frames (the previous YAxisR):
`handeye.calib.solvers.zhuang_rotations` with ``pre_rotate=False``. Eye-to-hand
(``X = T_flange_marker``, ``Y = T_base_cam``) unless the column says
eye-in-hand (``X = T_flange_cam``, ``Y = T_base_marker``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from handeye.calib import simulate, solvers
from handeye.calib import transforms as tf
from handeye.calib.api import closed_form
from handeye.calib.errors import DegenerateMotionError
from handeye.calib.setup import Setup


def unrotated_y_axis_r(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``R_Y`` from Zhuang's reduced eq. 9 without pre-rotation (singular when ``y_0 = 0``)."""
    return solvers.zhuang_rotations(A, B, pre_rotate=False)[1]


def rotation_error_deg(R_est: np.ndarray, R_true: np.ndarray) -> float:
    return float(np.rad2deg(tf.rotation_angle(R_true.T @ R_est)))


def accuracy(rounds: int, seed: int) -> tuple[dict, dict]:
    """Y rotation error (deg) per round for each dataset and variant, and |y_0| of the true Y per round."""
    sets = {"paper exp. 1, N=70": lambda rng: (simulate.paper_setup(70, rng), Setup.EYE_TO_HAND),
            "realistic, N=80": lambda rng: (simulate.realistic_cell(80, rng), Setup.EYE_TO_HAND),
            "realistic eye-in-hand, N=80": lambda rng: (simulate.realistic_cell(80, rng, setup=Setup.EYE_IN_HAND),
                                                        Setup.EYE_IN_HAND)}
    err = {(s, v): [] for s in sets for v in ("unrotated", "pre-rotated", "YQuatR*")}
    y0 = {s: [] for s in sets}
    for s, make in sets.items():
        for r in range(rounds):
            d, setup = make(np.random.default_rng(seed + r))
            B = d.B if setup == Setup.EYE_TO_HAND else tf.invert(d.B)  # eye-in-hand as A X = Y B^-1
            y0[s].append(abs(Rotation.from_matrix(d.Y[:3, :3]).as_quat()[3]))
            err[(s, "unrotated")].append(rotation_error_deg(unrotated_y_axis_r(d.A, B), d.Y[:3, :3]))
            for name, method in (("pre-rotated", "YAxisR"), ("YQuatR*", "YQuatR*")):
                est = closed_form(method, d.A, d.B, setup=setup)
                err[(s, name)].append(rotation_error_deg(est.Y[:3, :3], d.Y[:3, :3]))
    return err, y0


def exactness(seed: int) -> dict:
    """Largest element error of X and Y on noise-free paper data for R_Y at several angles (3 axes each)."""
    d = simulate.paper_setup(20, np.random.default_rng(seed))
    out = {}
    for angle in (0.0, 90.0, 179.0, 179.9, 180.0):
        worst = {"unrotated": 0.0, "pre-rotated": 0.0}
        for axis in ([1.0, 0.1, 0.2], [0.0, 1.0, 0.0], [0.3, -0.5, 0.8]):
            R_Y = Rotation.from_rotvec(np.array(axis) / np.linalg.norm(axis) * np.deg2rad(angle)).as_matrix()
            Y = tf.make_transform(R_Y, [0.3, -0.4, 1.2])
            B = tf.invert(Y) @ d.A_true @ d.X
            try:
                worst["unrotated"] = max(worst["unrotated"], float(np.abs(unrotated_y_axis_r(d.A_true, B) - R_Y).max()))
            except DegenerateMotionError:
                worst["unrotated"] = np.inf
            X_est, Y_est = solvers.y_axis_r(d.A_true, B)
            worst["pre-rotated"] = max(worst["pre-rotated"], float(np.abs(X_est - d.X).max()),
                                       float(np.abs(Y_est - Y).max()))
        out[angle] = worst
    return out


def report(err: dict, y0: dict, exact: dict, rounds: int) -> str:
    sets = list(y0)
    lines = [f"## YAxisR: rotation error of Y, deg, mean (max) over {rounds} rounds", "",
             "| variant | " + " | ".join(sets) + " |", "|---" * (len(sets) + 1) + "|"]
    for v in ("unrotated", "pre-rotated", "YQuatR*"):
        label = {"unrotated": "YAxisR unrotated (before)", "pre-rotated": "YAxisR pre-rotated (now)",
                 "YQuatR*": "YQuatR* (reference)"}[v]
        lines.append(f"| {label} | " + " | ".join(
            f"{np.mean(err[(s, v)]):.2f} ({np.max(err[(s, v)]):.1f})" for s in sets) + " |")
    lines += ["", "## Noise-free exactness: largest element error (inf = DegenerateMotionError)", "",
              "| R_Y angle, deg | unrotated (R_Y) | pre-rotated (X, Y) |", "|---|---|---|"]
    lines += [f"| {a:g} | {w['unrotated']:.1e} | {w['pre-rotated']:.1e} |" for a, w in exact.items()]
    return "\n".join(lines) + "\n"


def plot(path: Path, err: dict, y0: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = "paper exp. 1, N=70"
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.scatter(y0[s], err[(s, "unrotated")], label="unrotated (before)", marker="x")
    ax.scatter(y0[s], err[(s, "pre-rotated")], label="pre-rotated (now)", marker="o")
    ax.set_xlabel("|y_0| of the true R_Y (0 = half-turn)")
    ax.set_ylabel("rotation error of Y, deg")
    ax.set_title(f"YAxisR on {s} (eye-to-hand)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.yaxisr", description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=30)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--out", default="out/bench", help="folder for yaxisr.md and yaxisr.png")
    args = ap.parse_args(argv)
    err, y0 = accuracy(args.rounds, args.seed)
    text = report(err, y0, exactness(args.seed), args.rounds)
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "yaxisr.md").write_text(text)
    plot(out / "yaxisr.png", err, y0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
