"""Replay that advises: grouped and sorted tables, the recommendation, the note on agreeing
refined rows, a verdict per result (few samples, inconsistent residuals)."""

import numpy as np
import pytest

from handeye.app.runs.replay import advice, format_table, recommended, replay
from handeye.calib import simulate
from handeye.calib.observation import Observation

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
    notes = advice(rows, refine=True)
    assert any(n.startswith("note: the 3 refined rows using marker poses agree within") for n in notes), notes
    assert any(n.startswith("no recommendation") for n in notes) or recommended(rows) is not None
    assert not any("warning" in n for n in notes), notes   # 40 good samples: precise and consistent
    assert not any("agree" in n for n in advice(replay(obs, "eye_to_hand", POSE_METHODS, crossval=False),
                                                 refine=False))


def test_each_row_is_judged_few_samples_and_outliers_are_reasons():
    """The problems the advice used to list per solver are each result's verdict reasons now."""
    rng = np.random.default_rng(32)
    d = simulate.realistic_cell(8, rng)
    few = _observations(d)
    (row,) = replay(few, "eye_to_hand", POINT_METHODS, crossval=False)
    v = row.result.verdict
    assert v.level in ("warn", "fail") and any("only 8 samples" in r for r in v.reasons), v
    (row,) = replay(few, "eye_to_hand", POINT_METHODS, crossval=False, tolerance=(500, 50))
    assert not any("tolerance" in r for r in row.result.verdict.reasons)
    assert "| warn |" in format_table([row], "eye_to_hand")
    d = simulate.realistic_cell(30, rng)
    bad, _ = simulate.with_gross_outliers(d.points, 0.3, rng)
    obs = _observations(d, bad)
    (row,) = replay(obs, "eye_to_hand", POINT_METHODS, crossval=False)
    (msg,) = [r for r in row.result.verdict.reasons if "what the camera's noise explains" in r]
    assert "--robust" in msg and row.result.verdict.level != "pass"
    clean = _observations(d)
    (row,) = replay(clean, "eye_to_hand", POINT_METHODS, crossval=False, tolerance=(5.0, 1.0))
    assert row.result.verdict.level == "pass", row.result.verdict     # (30 samples, 1 / 3 mm noise: ~2 mm)


def test_recommendation_by_held_out_error():
    pytest.importorskip("handeye.calib.crossval")
    d = simulate.realistic_cell(15, np.random.default_rng(33))
    obs = _observations(d)
    rows = replay(obs, "eye_to_hand", ["YQuatT'", "YKronRT"] + POINT_METHODS, rng=np.random.default_rng(0))
    best = recommended(rows)
    assert best is not None and all(r.heldout is not None for r in rows)
    assert best.heldout.observed_rms == min(r.heldout.observed_rms for r in rows)
    assert "**recommended**" in format_table(rows, "eye_to_hand")
    assert advice(rows, refine=False)[0].startswith(f"recommended: {best.method}")


def test_auto_gets_its_own_group_and_a_held_out_error():
    d = simulate.realistic_cell(15, np.random.default_rng(34))
    obs = _observations(d)
    rows = replay(obs, "eye_to_hand", ["auto", "YKronT'"], rng=np.random.default_rng(0))
    auto = next(r for r in rows if r.method == "auto")
    assert auto.uses == "auto" and auto.result is not None and auto.heldout is not None, auto.heldout_error
    assert "the solver 'auto'" in format_table(rows, "eye_to_hand")
