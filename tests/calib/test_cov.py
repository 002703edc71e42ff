"""Honest covariance: NEES of the camera transform averages 6 on simulation."""

import numpy as np
import pytest

from calib import simulate
from calib.api import solve
from calib.refine import covariance, nees


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_nees_of_refined_points_averages_six(setup):
    rng = np.random.default_rng(21)
    values = []
    for _ in range(150):
        d = simulate.realistic_cell(40, rng, setup=setup)
        res = solve("YKronT'", d.A, d.points, setup=setup, refine=True, point_cov=d.point_cov)
        truth = d.Y if setup == "eye_to_hand" else d.X
        values.append(nees(res.camera_transform, truth, res.cov))
    # Mean of 150 chi-square(6) draws: sd 0.28; +-10% is about +-2 sd.
    assert 5.4 < np.mean(values) < 6.6


def test_nees_of_refined_poses():
    """Pose data, rotation noise level estimated from the residuals: still consistent (looser band)."""
    rng = np.random.default_rng(22)
    values = []
    for _ in range(80):
        d = simulate.realistic_cell(40, rng)
        res = solve("YQuatT'", d.A, d.B, refine=True, point_cov=d.point_cov)
        values.append(nees(res.Y, d.Y, res.cov))
    assert 4.8 < np.mean(values) < 7.5


def test_covariance_shrinks_with_more_samples_and_is_symmetric():
    rng = np.random.default_rng(23)
    d = simulate.realistic_cell(200, rng)
    small = covariance(d.X, d.Y, d.A[:20], d.points[:20], setup="eye_to_hand", point_cov=d.point_cov[:20])
    large = covariance(d.X, d.Y, d.A, d.points, setup="eye_to_hand", point_cov=d.point_cov)
    np.testing.assert_allclose(large, large.T)
    assert np.trace(large) < np.trace(small) / 5


def test_inconsistent_point_cov_is_inflated():
    """A covariance ten times too small is rejected by the chi-square test and scaled up."""
    rng = np.random.default_rng(24)
    d = simulate.realistic_cell(60, rng)
    honest = covariance(d.X, d.Y, d.A, d.points, setup="eye_to_hand", point_cov=d.point_cov)
    tiny = covariance(d.X, d.Y, d.A, d.points, setup="eye_to_hand", point_cov=d.point_cov / 100)
    assert 0.3 < np.trace(tiny) / np.trace(honest) < 3


def test_pose_covariance_ignores_a_placeholder_marker_rotation():
    """A point-only estimate (identity R_X) on pose data: the nuisance rotation is re-estimated."""
    rng = np.random.default_rng(25)
    d = simulate.realistic_cell(60, rng)
    X_placeholder = d.X.copy()
    X_placeholder[:3, :3] = np.eye(3)
    a = covariance(d.X, d.Y, d.A, d.B, setup="eye_to_hand")
    b = covariance(X_placeholder, d.Y, d.A, d.B, setup="eye_to_hand")
    np.testing.assert_allclose(b, a, rtol=0.05, atol=1e-12)
