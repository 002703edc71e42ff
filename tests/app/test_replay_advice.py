"""Replay that advises: grouped and sorted tables, the recommendation, the note on agreeing
refined rows, warnings for a large 1-sigma and for inconsistent residuals."""

import numpy as np
import pytest

from app.runs.replay import advice, format_table, recommended, replay
from calib import simulate
from calib.observation import Observation

POINT_METHODS = ["YKronT'"]
POSE_METHODS = ["YQuatT'", "YKronRT", "YQuatR*"]


def _observations(d, points=None):
    pts = d.points if points is None else points
    return [Observation(i, float(i), d.A[i], pts[i], d.point_cov[i], d.B[i]) for i in range(len(d.A))]


def test_groups_sorted_and_agreeing_refined_rows_explained():
    d = simulate.realistic_cell(40, np.random.default_rng(31))
    obs = _observations(d)
    rows = replay(obs, "eye_to_hand", POSE_METHODS + POINT_METHODS + ["nonsense"], refine=True, truth=d.Y,
                  crossval=False)
    table = format_table(rows, "eye_to_hand")
    lines = table.splitlines()
    i_points = lines.index("solvers using marker points, by held-out prediction error:")
    i_poses = lines.index("solvers using marker poses, by held-out prediction error:")
    assert i_points < i_poses and "unknown solvers" in table and "failed:" in table
    pose_rows = [ln for ln in lines[i_poses:] if ln.startswith("| Y")]
    rms = [float(ln.split("|")[4]) for ln in pose_rows]
    assert len(rms) == 3 and rms == sorted(rms)     # without held-out errors: by residual RMS
    notes = advice(rows, obs, refine=True)
    assert any(n.startswith("note: the 3 refined rows using marker poses agree within") for n in notes), notes
    assert any(n.startswith("no recommendation") for n in notes) or recommended(rows) is not None
    assert not any("warning" in n for n in notes), notes   # 40 good samples: precise and consistent
    assert not any("agree" in n for n in advice(replay(obs, "eye_to_hand", POSE_METHODS, crossval=False), obs,
                                                 refine=False))


def test_warnings_for_large_sigma_and_inconsistent_residuals():
    rng = np.random.default_rng(32)
    d = simulate.realistic_cell(8, rng)
    few = _observations(d)
    rows = replay(few, "eye_to_hand", POINT_METHODS, crossval=False)
    warn = [n for n in advice(rows, few, refine=False) if n.startswith("warning: 1-sigma above the default target")]
    assert len(warn) == 1 and "YKronT'" in warn[0]
    assert not any(n.startswith("warning: 1-sigma") for n in advice(rows, few, refine=False, target_mm=500,
                                                                   target_deg=50))
    d = simulate.realistic_cell(30, rng)
    bad, _ = simulate.with_gross_outliers(d.points, 0.3, rng)
    obs = _observations(d, bad)
    rows = replay(obs, "eye_to_hand", POINT_METHODS, crossval=False)
    (msg,) = [n for n in advice(rows, obs, refine=False) if "inconsistent residuals" in n]
    assert "try --robust" in msg
    clean = _observations(d)
    rows = replay(clean, "eye_to_hand", POINT_METHODS, crossval=False)
    assert not any("inconsistent" in n for n in advice(rows, clean, refine=False))


def test_recommendation_by_held_out_error():
    pytest.importorskip("calib.crossval")
    d = simulate.realistic_cell(15, np.random.default_rng(33))
    obs = _observations(d)
    rows = replay(obs, "eye_to_hand", ["YQuatT'", "YKronRT"] + POINT_METHODS, rng=np.random.default_rng(0))
    best = recommended(rows)
    assert best is not None and all(r.heldout is not None for r in rows)
    assert best.heldout.observed_rms == min(r.heldout.observed_rms for r in rows)
    assert "**recommended**" in format_table(rows, "eye_to_hand")
    assert advice(rows, obs, refine=False)[0].startswith(f"recommended: {best.method}")


def test_auto_gets_its_own_group_and_a_held_out_error():
    d = simulate.realistic_cell(15, np.random.default_rng(34))
    obs = _observations(d)
    rows = replay(obs, "eye_to_hand", ["auto", "YKronT'"], rng=np.random.default_rng(0))
    auto = next(r for r in rows if r.method == "auto")
    assert auto.uses == "auto" and auto.result is not None and auto.heldout is not None, auto.heldout_error
    assert "the solver 'auto'" in format_table(rows, "eye_to_hand")
