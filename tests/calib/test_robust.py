"""Outlier-robust calibration (handeye.calib.robust) through solve(..., robust=True)."""

import numpy as np
import pytest

from handeye.calib import simulate
from handeye.calib import transforms as tf
from handeye.calib.api import closed_form, solve
from handeye.calib.errors import CalibrationError, InsufficientDataError
from handeye.calib.robust import robust_solve
from handeye.calib.problem import CalibrationProblem


@pytest.mark.parametrize("setup,fraction", [("eye_to_hand", 0.3), ("eye_in_hand", 0.3), ("eye_to_hand", 0.1)])
def test_outliers_leave_error_within_ten_percent(setup, fraction):
    """Reference: the same solver on the samples that were not corrupted."""
    rng = np.random.default_rng(31)
    err, ref, found, wrong = [], [], 0, 0
    n_bad_total = 0
    for _ in range(20):
        d = simulate.realistic_cell(60, rng, setup=setup)
        pts, bad = simulate.with_gross_outliers(d.points, fraction, rng)
        res = solve("YKronT'", d.A, pts, setup=setup, robust=True, point_cov=d.point_cov, rng=rng)
        good = np.setdiff1d(np.arange(60), bad)
        clean = solve("YKronT'", d.A[good], pts[good], setup=setup, point_cov=d.point_cov[good])
        truth = d.Y if setup == "eye_to_hand" else d.X
        err.append(tf.pose_error(res.camera_transform, truth))
        ref.append(tf.pose_error(clean.camera_transform, truth))
        found += len(np.intersect1d(res.rejected, bad))
        wrong += len(np.setdiff1d(res.rejected, bad))
        n_bad_total += len(bad)
        assert res.method == "YKronT'+LMedS" and res.n_samples == 60 and res.inliers.shape == (60,)
    err, ref = np.array(err), np.array(ref)
    rms = np.sqrt((err**2).mean(axis=0) / (ref**2).mean(axis=0))
    assert np.all(rms < 1.10), rms
    assert found == n_bad_total
    assert wrong <= 0.03 * 20 * 60


def test_no_outliers_rejects_almost_nothing():
    rng = np.random.default_rng(32)
    d = simulate.realistic_cell(80, rng)
    res = solve("YKronT'", d.A, d.points, robust=True, point_cov=d.point_cov, rng=rng)
    assert len(res.rejected) <= 3


def test_pose_data_with_wrong_marker_outliers():
    rng = np.random.default_rng(33)
    d = simulate.realistic_cell(50, rng)
    B = d.B.copy()
    bad = np.arange(0, 50, 5)
    B[bad] = B[bad] @ tf.from_rotvec_translation(np.tile([0.0, 0.6, 0.0], (10, 1)), np.tile([0.1, 0.0, 0.0], (10, 1)))
    res = solve("YQuatT'", d.A, B, robust=True, rng=rng)
    assert set(bad) <= set(res.rejected)
    assert tf.pose_error(res.Y, d.Y)[1] < 0.01


def test_refine_on_inliers_composes():
    rng = np.random.default_rng(34)
    d = simulate.realistic_cell(60, rng)
    pts, bad = simulate.with_gross_outliers(d.points, 0.2, rng)
    res = solve("YKronT'", d.A, pts, robust=True, refine=True, point_cov=d.point_cov, rng=rng)
    assert res.method == "YKronT'+LMedS+ML"
    assert set(bad) <= set(res.rejected)
    assert tf.pose_error(res.Y, d.Y)[1] < 0.005


def test_bad_arguments():
    rng = np.random.default_rng(35)
    d = simulate.realistic_cell(8, rng)
    fn = lambda sub: closed_form("YKronT'", sub)  # noqa: E731
    with pytest.raises(InsufficientDataError):
        robust_solve(fn, CalibrationProblem.from_arrays(d.A[:6], d.points[:6]), rng=rng)
    with pytest.raises(CalibrationError, match="rng"):
        robust_solve(fn, CalibrationProblem.from_arrays(d.A, d.points), rng=0)
    with pytest.raises(CalibrationError, match="max_outlier_fraction"):
        robust_solve(fn, CalibrationProblem.from_arrays(d.A, d.points), rng=rng, max_outlier_fraction=0.6)
