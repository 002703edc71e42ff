"""``handeye replay``: re-solve a recorded session (or an imported file) with one, several or all solvers.

Works for both setups; the session header says which (eye-to-hand:
``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand: ``X = T_flange_cam``,
``Y = T_base_marker``).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app import devices
from app.errors import SessionError
from app.session import read_session
from calib import transforms as tf
from calib.api import METHODS, solve_observations
from calib.errors import HandeyeError, InsufficientDataError
from calib.observation import Observation
from calib.result import CalibrationResult
from calib.setup import Setup


NAME = "replay"
HELP = "re-solve a recorded session or an imported file, compare solvers"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", type=Path, help="session directory, or a file/dir to import (easy_handeye, "
                   "industrial_calibration, pose-stream CSV)")
    p.add_argument("-m", "--method", action="append", dest="methods",
                   help="solver (repeatable); default YKronT' and YQuatT'; 'all' for every solver")
    p.add_argument("--refine", action="store_true", help="refine each solution (nonlinear least squares)")
    p.add_argument("--robust", action="store_true", help="reject outliers")
    p.add_argument("--setup", choices=[s.value for s in Setup], help="setup of an imported file")
    p.add_argument("--seed", type=int, default=0, help="seed for randomised (robust) solvers")


def run(args) -> int:
    methods = args.methods or ["YKronT'", "YQuatT'"]
    print(replay_source(args.source, methods, refine=args.refine, robust=args.robust, setup=args.setup,
                        rng=np.random.default_rng(args.seed)))
    return 0


def replay_source(source: Path, methods: list[str], *, refine: bool = False, robust: bool = False,
                  setup: Setup | None = None, rng: np.random.Generator | None = None) -> str:
    """Re-solve a session directory or an imported file with each method; returns the markdown table."""
    if not Path(source).exists():
        raise SessionError(f"{source}: no such file or directory")
    if (Path(source) / "session.json").exists():
        session = read_session(source)
        if setup is not None and setup != session.setup:
            raise SessionError(f"{source} is an {session.setup} session; --setup {setup} contradicts it")
        observations, file_setup, truth = session.observations, session.setup, session.truth
        header = ""
    else:
        observations, file_setup, meta = devices.import_observations(Path(source), setup)
        truth, header = {}, _import_summary(meta)
    setup = setup or file_setup
    if not observations:
        raise InsufficientDataError(f"{source}: no samples to replay")
    if methods == ["all"]:
        methods = list(METHODS)
    rows = replay(observations, setup, methods, refine=refine, robust=robust,
                  truth=devices.camera_truth(setup, truth), rng=rng)
    if all(r.result is None for r in rows):
        raise HandeyeError(f"no solver succeeded on {source}: " + "; ".join(f"{r.method}: {r.error}" for r in rows))
    return f"{source} ({setup}, {len(observations)} samples)\n{header}\n" + format_table(rows, setup)


def _import_summary(meta: dict) -> str:
    """What an importer measured that the table does not show (the streams' clock offset)."""
    if "clock_offset_s" not in meta:
        return ""
    line = f"clock offset (t_robot = t_camera + offset): {meta['clock_offset_s'] * 1e3:+.1f} ms"
    if "xcorr_score" in meta:
        line += f" (angular-speed correlation {meta['xcorr_score']:.2f}"
        if "refine_rms_mm" in meta:
            line += f", refined on the residual: RMS {meta['refine_rms_mm']:.2f} mm"
        line += ")"
    return line + "\n"


@dataclass
class ReplayRow:
    """One solver's outcome on the replayed samples.

    ``error`` holds the one-line reason when the solver refused the data (e.g.
    a pose-based method on a point-only session); ``truth_error`` is
    ``(deg, mm)`` of the camera transform against the recorded truth, if any.
    """

    method: str
    result: CalibrationResult | None
    seconds: float
    error: str | None = None
    truth_error: tuple[float, float] | None = None


def replay(
    observations: list[Observation],
    setup: Setup,
    methods: list[str],
    *,
    refine: bool = False,
    robust: bool = False,
    truth: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
) -> list[ReplayRow]:
    """Solve the same samples with each method and time it.

    Parameters
    ----------
    observations : list[Observation]
    setup : {"eye_to_hand", "eye_in_hand"}
    methods : list of str
        Paper names (``"YKronT'"``, ``"YQuatT'"``, ``"XKronRT"``, ...).
    truth : ndarray (4, 4), optional
        True camera transform (``T_base_cam`` eye-to-hand, ``T_flange_cam``
        eye-in-hand) to report errors against.

    Returns
    -------
    list[ReplayRow]
        One per method, in the given order; a method that raises a
        ``HandeyeError`` gets a row with ``error`` set instead of stopping the rest.
    """
    rows = []
    for method in methods:
        t0 = time.perf_counter()
        try:
            res = solve_observations(method, observations, setup, refine=refine, robust=robust, rng=rng)
        except HandeyeError as e:
            rows.append(ReplayRow(method, None, time.perf_counter() - t0, error=str(e)))
            continue
        dt = time.perf_counter() - t0
        err = None
        if truth is not None:
            rot, trans = tf.pose_error(res.camera_transform, truth)
            err = (float(np.rad2deg(rot)), float(trans * 1e3))
        rows.append(ReplayRow(method, res, dt, truth_error=err))
    return rows


def format_table(rows: list[ReplayRow], setup: Setup) -> str:
    """Markdown table: method, samples, residual RMS (mm), camera xyz (mm), 1-sigma, time, error vs. truth."""
    cam = Setup(setup).camera_name
    has_truth = any(r.truth_error is not None for r in rows)
    head = ["solver", "n", "inliers", "resid RMS [mm]", f"{cam} xyz [mm]", "1σ [mm]", "1σ [deg]", "time [ms]"]
    if has_truth:
        head += ["err [mm]", "err [deg]"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        if r.result is None:
            cells = [r.method, "-", "-", f"failed: {r.error}"] + [""] * (len(head) - 4)
        else:
            res = r.result
            xyz = " ".join(f"{v:.1f}" for v in res.camera_transform[:3, 3] * 1e3)
            s_rot, s_t = res.sigma if res.sigma is not None else (float("nan"), float("nan"))
            n_in = res.n_samples if res.inliers is None else int(np.count_nonzero(res.inliers))
            cells = [r.method, str(res.n_samples), str(n_in), f"{res.residuals.rms_translation * 1e3:.2f}",
                     xyz, f"{s_t * 1e3:.2f}", f"{np.rad2deg(s_rot):.3f}", f"{r.seconds * 1e3:.1f}"]
            if has_truth:
                cells += ["-", "-"] if r.truth_error is None else [f"{r.truth_error[1]:.2f}", f"{r.truth_error[0]:.3f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
