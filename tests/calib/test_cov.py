"""Honest covariance: NEES of the camera transform averages 6 on simulation."""

import numpy as np
import pytest

from handeye.calib import api, simulate, solvers
from handeye.calib.api import solve
from handeye.calib.refine import covariance, error_vector, kron_t_prime_covariance, nees
from handeye.calib.problem import CalibrationProblem


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
    small = covariance(d.X, d.Y, CalibrationProblem.from_arrays(d.A[:20], d.points[:20], setup="eye_to_hand", point_cov=d.point_cov[:20]))
    large = covariance(d.X, d.Y, CalibrationProblem.from_arrays(d.A, d.points, setup="eye_to_hand", point_cov=d.point_cov))
    np.testing.assert_allclose(large, large.T)
    assert np.trace(large) < np.trace(small) / 5


def test_inconsistent_point_cov_is_inflated():
    """A covariance ten times too small is rejected by the chi-square test and scaled up."""
    rng = np.random.default_rng(24)
    d = simulate.realistic_cell(60, rng)
    honest = covariance(d.X, d.Y, CalibrationProblem.from_arrays(d.A, d.points, setup="eye_to_hand", point_cov=d.point_cov))
    tiny = covariance(d.X, d.Y, CalibrationProblem.from_arrays(d.A, d.points, setup="eye_to_hand", point_cov=d.point_cov / 100))
    assert 0.3 < np.trace(tiny) / np.trace(honest) < 3


def test_pose_covariance_ignores_a_placeholder_marker_rotation():
    """A point-only estimate (identity R_X) on pose data: the nuisance rotation is re-estimated."""
    rng = np.random.default_rng(25)
    d = simulate.realistic_cell(60, rng)
    X_placeholder = d.X.copy()
    X_placeholder[:3, :3] = np.eye(3)
    a = covariance(d.X, d.Y, CalibrationProblem.from_arrays(d.A, d.B, setup="eye_to_hand"))
    b = covariance(X_placeholder, d.Y, CalibrationProblem.from_arrays(d.A, d.B, setup="eye_to_hand"))
    np.testing.assert_allclose(b, a, rtol=0.05, atol=1e-12)


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_nees_of_closed_form_ykront_averages_six(setup):
    """Closed-form YKronT' gets the covariance of its own estimator, not the (smaller) ML one."""
    rng = np.random.default_rng(26)
    values = []
    for _ in range(150):
        d = simulate.realistic_cell(40, rng, setup=setup)
        res = solve("YKronT'", d.A, d.points, setup=setup, point_cov=d.point_cov)
        assert res.cov_kind == "delta-analytic"
        truth = d.Y if setup == "eye_to_hand" else d.X
        values.append(nees(res.camera_transform, truth, res.cov))
    # The ML covariance gave 10-14 here; the estimator's own covariance must give 6 +- 10%.
    assert 5.4 < np.mean(values) < 6.6


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_analytic_ykront_covariance_matches_finite_differences(setup):
    """The three-step analytic propagation equals a numerical Jacobian of the solver."""
    rng = np.random.default_rng(27)
    d = simulate.realistic_cell(25, rng, setup=setup)
    X, Y = solvers.y_kron_t_prime(d.A, d.points, setup)
    cam = Y if setup == "eye_to_hand" else X
    analytic = kron_t_prime_covariance(X, Y, CalibrationProblem.from_arrays(d.A, d.points, setup=setup, point_cov=d.point_cov))
    h = 1e-6
    L = np.linalg.cholesky(d.point_cov)
    numeric = np.zeros((6, 6))
    for i in range(len(d.A)):
        J = np.empty((6, 3))
        for k in range(3):
            p = d.points.copy()
            p[i] += h * L[i, :, k]
            X2, Y2 = solvers.y_kron_t_prime(d.A, p, setup)
            J[:, k] = -error_vector(cam, Y2 if setup == "eye_to_hand" else X2) / h
        numeric += J @ J.T
    np.testing.assert_allclose(analytic, numeric, rtol=1e-3, atol=1e-4 * np.abs(numeric).max())


def test_closed_form_pose_method_gets_numerical_delta_covariance():
    """Pose-based closed forms: numerical delta method below the sample limit, honest on average."""
    rng = np.random.default_rng(28)
    values = []
    for _ in range(40):
        d = simulate.realistic_cell(15, rng)
        res = solve("YKronRT", d.A, d.B, point_cov=d.point_cov)
        assert res.cov_kind == "delta-numerical"
        values.append(nees(res.Y, d.Y, res.cov))
    # 40 draws: sd of the mean ~0.55 if chi-square(6); the ML covariance would be far off for YKronRT.
    assert 4.5 < np.mean(values) < 7.5


def test_cov_kind_of_refined_and_large_closed_form_results():
    rng = np.random.default_rng(29)
    d = simulate.realistic_cell(api.DELTA_METHOD_MAX_SAMPLES + 1, rng)
    assert solve("YKronT'", d.A, d.points, refine=True).cov_kind == "fisher"
    assert solve("YKronRT", d.A, d.B).cov_kind == "fisher-optimistic"
