"""Replay: re-solve a recorded session (or an imported file) with one, several or all solvers.

Works for both setups; the session header says which (eye-to-hand:
``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand: ``X = T_flange_cam``,
``Y = T_base_marker``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from app.pipeline import sigma, solve_observations
from calib import transforms as tf
from calib.errors import HandeyeError
from calib.observation import Observation
from calib.result import CalibrationResult
from calib.setup import Setup


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
            s_deg, s_mm = sigma(res.cov) if res.cov is not None else (float("nan"), float("nan"))
            n_in = res.n_samples if res.inliers is None else int(np.count_nonzero(res.inliers))
            cells = [r.method, str(res.n_samples), str(n_in), f"{res.residuals.rms_translation * 1e3:.2f}",
                     xyz, f"{s_mm:.2f}", f"{s_deg:.3f}", f"{r.seconds * 1e3:.1f}"]
            if has_truth:
                cells += ["-", "-"] if r.truth_error is None else [f"{r.truth_error[1]:.2f}", f"{r.truth_error[0]:.3f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
