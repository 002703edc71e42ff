"""Recordings that leave part of the answer open: a grid at one tool orientation, rotations about one axis.

Run ``python -m bench.grids [--cells 100] [--n 100] [--seed 0] [--out out/bench]``
(also ``python -m bench --grids``). Prints markdown, writes ``<out>/grids.md``.

Per setup (eye-to-hand ``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand
``X = T_flange_cam``, ``Y = T_base_marker``) and per motion, on ``--cells``
simulated cells (`handeye.calib.simulate.realistic_cell`: camera 0.7 m away, 1 mm
lateral / 3 mm depth point noise, a camera with a 1.5 % depth scale and a
3 mm depth offset), ``--n`` samples each:

- **open part held**: ``solve("auto")`` without the marker offset. It answers
  (no refusal) with ``undetermined`` set, the verdict's ``warn``; the camera's
  rotation against its stated covariance (NEES, 3 dof: mean 3 when honest),
  and the whole camera transform against the truth moved along the open
  directions to the value held (NEES, 6 dof: mean 6);
- **offset given**: ``solve("auto", marker_offset=<true offset>)``: the camera's
  error (RMS over the cells, mm and deg) beside the full calibration's;
- **full calibration**: the same cell with the tool turned +-40 deg about random
  axes (the normal recording), ``solve("auto")`` at the same N.

Motions: "grid" (``angle_range=0``: every sample at one orientation, positions
within +-0.15 m per axis as the full calibration's), "grid +-0.25 m" (the same
over a wider box) and "one axis" (+-40 deg about the flange's z axis only).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from bench.tables import markdown_table
from handeye.calib import model, simulate
from handeye.calib.api import solve
from handeye.calib.auto.determined import MotionPrior, held_equivalent, motion_prior
from handeye.calib.problem import CalibrationProblem
from handeye.calib.refine import error_vector
from handeye.calib.setup import Setup

#: The camera's systematic error in every cell: 1.5 % depth scale, 3 mm depth offset (a structured-light camera
#: before an infield correction); ``auto`` estimates both.
CAMERA = model.CameraCorrection(depth_scale=0.015, depth_offset=0.003)

#: (name, keywords of `handeye.calib.simulate.realistic_cell`) of the motions that leave part of the answer open: a grid
#: over the full calibration's +-0.15 m, one over +-0.25 m, and +-40 deg about the flange's z axis only.
MOTIONS = (("grid", {"angle_range": 0.0}), ("grid +-0.25 m", {"angle_range": 0.0, "translation_range": 0.25}),
           ("one axis", {"rotation_axis": (0.0, 0.0, 1.0)}))


def cell(n: int, seed: int, setup: Setup, **motion) -> tuple[simulate.SimulatedData, np.ndarray]:
    """A simulated cell (`handeye.calib.simulate.realistic_cell`) seen through `CAMERA`, and its measured points
    (n, 3)."""
    d = simulate.realistic_cell(n, np.random.default_rng(seed), setup=setup, **motion)
    return d, CAMERA.measure(d.points)


def camera_truth(d: simulate.SimulatedData) -> np.ndarray:
    """The true camera transform: ``T_base_cam`` eye-to-hand, ``T_flange_cam`` eye-in-hand."""
    return d.Y if d.setup == Setup.EYE_TO_HAND else d.X


def marker_offset(d: simulate.SimulatedData) -> np.ndarray:
    """The true marker-side translation (`handeye.calib.problem.CalibrationProblem.marker_offset`), m."""
    return (d.X if d.setup == Setup.EYE_TO_HAND else d.Y)[:3, 3]


def held_truth(d: simulate.SimulatedData, motion: MotionPrior) -> np.ndarray:
    """The true camera transform moved along the open directions to the value ``auto`` holds (`held_equivalent`)."""
    X, Y = held_equivalent(d.X, d.Y, d.A, d.setup, motion)
    return model.split(X, Y, d.A, d.setup)[0]


def run_cells(cells: int, n: int, seed: int, setup: Setup, motion: dict) -> dict:
    """Every figure of one (setup, motion) row over ``cells`` cells (see the module docstring)."""
    out = {k: [] for k in ("warn", "nees_rot", "nees_held", "err_given", "err_full", "nees_given", "seconds",
                           "dof_held", "nees_full")}
    for c in range(seed, seed + cells):
        d, points = cell(n, c, setup, **motion)
        problem = CalibrationProblem.from_arrays(d.A, points, setup=setup)
        t0 = time.perf_counter()
        res = solve("auto", problem)
        out["seconds"].append(time.perf_counter() - t0)
        out["warn"].append(bool(res.undetermined))
        motion_ = motion_prior(problem)
        e = error_vector(res.camera_transform, held_truth(d, motion_))
        out["nees_rot"].append(float(e[:3] @ np.linalg.solve(res.cov[:3, :3], e[:3])))
        out["nees_held"].append(float(e @ np.linalg.solve(res.cov, e)))
        # Camera translation held exactly (eye-in-hand: the camera is the flange side) is no error: fewer dof.
        out["dof_held"].append(6 - (0 if setup == Setup.EYE_TO_HAND else motion_.open.shape[1]))
        given = solve("auto", d.A, points, setup=setup, marker_offset=marker_offset(d))
        e = error_vector(given.camera_transform, camera_truth(d))
        out["err_given"].append(e)
        out["nees_given"].append(float(e @ np.linalg.solve(given.cov, e)))
        full, full_points = cell(n, c, setup)
        full_res = solve("auto", full.A, full_points, setup=setup)
        e = error_vector(full_res.camera_transform, camera_truth(full))
        out["err_full"].append(e)
        out["nees_full"].append(float(e @ np.linalg.solve(full_res.cov, e)))
    return out


def _rms(errors, part) -> float:
    e = np.array(errors)[:, part]
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def report(rows: dict, cells: int, n: int) -> str:
    """The markdown table of `run_cells`' figures per (setup, motion)."""
    head = ["setup", "motion", "warn", "rotation NEES (3)", "NEES given held (dof)", "offset given: err mm / deg",
            "full calibration: err mm / deg", "ratio mm / deg", "NEES offset given (6)", "NEES full (6)",
            "auto [ms]"]
    table = []
    for (setup, motion), f in rows.items():
        given = (_rms(f["err_given"], slice(3, 6)) * 1e3, np.rad2deg(_rms(f["err_given"], slice(0, 3))))
        full = (_rms(f["err_full"], slice(3, 6)) * 1e3, np.rad2deg(_rms(f["err_full"], slice(0, 3))))
        table.append([setup, motion, f"{sum(f['warn'])}/{len(f['warn'])}", f"{np.mean(f['nees_rot']):.2f}",
                      f"{np.mean(f['nees_held']):.2f} ({f['dof_held'][0]})", f"{given[0]:.2f} / {given[1]:.3f}",
                      f"{full[0]:.2f} / {full[1]:.3f}", f"{given[0] / full[0]:.2f} / {given[1] / full[1]:.2f}",
                      f"{np.mean(f['nees_given']):.2f}", f"{np.mean(f['nees_full']):.2f}",
                      f"{np.median(f['seconds']) * 1e3:.0f}"])
    return (f"## Recordings that leave part of the answer open ({cells} cells, N = {n})\n\n"
            "warn: results that name what is open (`undetermined`); NEES: mean over the cells (honest: the dof in "
            "brackets; \"given held\": the camera transform against the truth moved to the value held, whose "
            "held components are no error); err: RMS over the cells of the camera transform's error; ratio: offset "
            "given / full calibration (+-40 deg, +-0.15 m); auto: median time of one solve without the offset.\n\n"
            + markdown_table(head, table))


def main(argv=None) -> int:
    """Run the benchmark; returns 0. See the module docstring."""
    ap = argparse.ArgumentParser(prog="python -m bench.grids", description=__doc__.split("\n")[0])
    ap.add_argument("--cells", type=int, default=100, help="simulated cells per setup and motion")
    ap.add_argument("--n", type=int, default=100, help="samples per recording")
    ap.add_argument("--seed", type=int, default=0, help="seed of the first cell")
    ap.add_argument("--out", default="out/bench", help="folder for grids.md")
    args = ap.parse_args(argv)
    rows = {}
    for setup in (Setup.EYE_TO_HAND, Setup.EYE_IN_HAND):
        for name, motion in MOTIONS:
            print(f"bench.grids: {setup}, {name}", file=sys.stderr, flush=True)
            rows[(str(setup), name)] = run_cells(args.cells, args.n, args.seed, setup, motion)
    text = report(rows, args.cells, args.n)
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "grids.md").write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
