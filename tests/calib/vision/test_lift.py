"""Inverse-depth plane fit, ray intersection and their covariances on synthetic depth."""

import numpy as np
import pytest

from handeye.calib import transforms as tf
from handeye.calib.errors import DepthError, MarkerNotFoundError
from handeye.calib.vision.lift import (DepthNoiseModel, fit_plane, intersect_ray, pnp_covariance, polygon_pixels,
                                      solve_pnp)
from handeye.calib.vision.markers import marker_object_points

K = np.array([[570.0, 0, 319.5], [0, 570.0, 239.5], [0, 0, 1]])
DIST = np.zeros(5)


def _plane_depth(n, d, shape=(480, 640)):
    """Exact depth image of the plane n . p = d."""
    v, u = np.mgrid[: shape[0], : shape[1]].astype(float)
    x, y = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
    return d / (n[0] * x + n[1] * y + n[2])


N_TRUE = np.array([0.2, -0.1, 1.0]) / np.linalg.norm([0.2, -0.1, 1.0])
D_TRUE = 0.75
SQUARE = np.array([[290.0, 210.0], [350.0, 210.0], [350.0, 270.0], [290.0, 270.0]])


def test_fit_recovers_plane_and_center_covariance_is_honest():
    rng = np.random.default_rng(0)
    # Independent pixel noise here, so no credit limit for correlated pixels.
    noise = DepthNoiseModel(k=1.7e-3, sigma_0=0.0, k_sys=0.0, max_independent_pixels=1e9)
    z_true = _plane_depth(N_TRUE, D_TRUE)
    rows, cols = polygon_pixels(SQUARE, z_true.shape, 1.0)
    xy_c = np.array([0.01, -0.02])
    p_true = xy_c.tolist() + [1.0]
    p_true = np.array(p_true) * D_TRUE / (N_TRUE @ p_true)
    errs, covs = [], []
    for _ in range(200):
        z = z_true.copy()
        z[rows, cols] += rng.normal(size=len(rows)) * noise.sigma(z_true[rows, cols])
        fit = fit_plane(z, rows, cols, K, DIST, noise)
        p, cov = intersect_ray(fit, xy_c, np.zeros((2, 2)), noise)
        errs.append(p - p_true)
        covs.append(cov)
    errs = np.array(errs)
    np.testing.assert_allclose(fit.normal, N_TRUE, atol=0.02)
    assert 0.8 < fit.chi2_ratio < 1.2
    nees = np.einsum("ni,nij,nj->n", errs, np.linalg.inv(np.array(covs) + 1e-18 * np.eye(3)), errs)
    # Only the along-ray direction is random here (rank-1 cov): NEES ~ chi2(1), mean 1.
    z_err = errs[:, 2]
    z_sig = np.sqrt(np.mean([c[2, 2] for c in covs]))
    assert 0.8 < z_err.std() / z_sig < 1.25
    assert abs(z_err.mean()) < 3 * z_sig / np.sqrt(len(z_err))
    assert np.isfinite(nees).all()


def test_correlated_pixels_limit_the_credit():
    z = _plane_depth(N_TRUE, D_TRUE)
    rows, cols = polygon_pixels(SQUARE, z.shape, 1.0)
    free = fit_plane(z, rows, cols, K, DIST, DepthNoiseModel(max_independent_pixels=1e9))
    capped = fit_plane(z, rows, cols, K, DIST, DepthNoiseModel(max_independent_pixels=200))
    np.testing.assert_allclose(capped.cov, free.cov * free.n_inliers / 200)


def test_systematic_and_lateral_terms_enter_the_covariance():
    noise = DepthNoiseModel(k_sys=1e-3)
    z = _plane_depth(N_TRUE, D_TRUE)
    rows, cols = polygon_pixels(SQUARE, z.shape, 1.0)
    fit = fit_plane(z, rows, cols, K, DIST, noise)
    _, cov0 = intersect_ray(fit, [0, 0], np.zeros((2, 2)), DepthNoiseModel(k_sys=0.0))
    p, cov1 = intersect_ray(fit, [0, 0], np.diag([1e-6, 1e-6]), noise)
    assert cov1[2, 2] > cov0[2, 2] + 0.9 * (1e-3 * p[2] ** 2) ** 2
    # A 1e-3 normalized-coordinate sigma moves the point laterally by ~z * 1e-3.
    assert np.sqrt(cov1[0, 0]) == pytest.approx(p[2] * 1e-3, rel=0.2)


def test_rejects_too_few_valid_pixels():
    z = _plane_depth(N_TRUE, D_TRUE)
    z[200:280, 280:360] = 0.0
    rows, cols = polygon_pixels(SQUARE, z.shape, 1.0)
    with pytest.raises(DepthError, match="have depth"):
        fit_plane(z, rows, cols, K, DIST, DepthNoiseModel())


def test_rejects_step_and_noise():
    z = _plane_depth(N_TRUE, D_TRUE)
    z[:, 320:] += 0.05  # half the marker on a different surface
    rows, cols = polygon_pixels(SQUARE, z.shape, 1.0)
    with pytest.raises(DepthError, match="bad plane fit"):
        fit_plane(z, rows, cols, K, DIST, DepthNoiseModel())
    rng = np.random.default_rng(1)
    z = rng.uniform(0.5, 1.5, size=(480, 640))
    with pytest.raises(DepthError, match="bad plane fit"):
        fit_plane(z, rows, cols, K, DIST, DepthNoiseModel())


def test_robust_fit_ignores_a_few_outliers():
    z = _plane_depth(N_TRUE, D_TRUE)
    rng = np.random.default_rng(2)
    z = z + rng.normal(size=z.shape) * DepthNoiseModel().sigma(z)
    rows, cols = polygon_pixels(SQUARE, z.shape, 1.0)
    bad = rng.choice(len(rows), size=len(rows) // 20, replace=False)
    z[rows[bad], cols[bad]] = 2.0  # flying pixels on the background
    fit = fit_plane(z, rows, cols, K, DIST, DepthNoiseModel())
    assert fit.n_inliers <= len(rows) - len(bad)
    np.testing.assert_allclose(fit.normal, N_TRUE, atol=0.02)


def test_pnp_candidates_and_covariance():
    # Tilted 35 deg: head-on, a 5 cm marker's tilt is hardly observable (both IPPE solutions fit).
    R = tf.from_rotvec_translation([np.deg2rad(35), 0, 0], [0, 0, 0])[:3, :3] @ np.diag([1.0, -1.0, -1.0])
    T = tf.make_transform(R, [0.02, -0.01, 0.6])
    obj = marker_object_points(0.05)
    P = tf.transform_points(T, obj)
    px = P[:, :2] / P[:, 2:] * 570 + [319.5, 239.5]
    cands = solve_pnp(px, obj, K, DIST, square=True)
    rot, trans = tf.pose_error(cands[0][0], T)
    assert rot < 1e-4 and trans < 1e-6
    cov = pnp_covariance(T, obj, K, 0.3)
    assert cov.shape == (6, 6) and np.all(np.linalg.eigvalsh(cov) > 0)
    # The range of a 5 cm marker at 0.6 m is far less certain than its lateral position.
    assert cov[5, 5] > 10 * cov[3, 3]


def test_collinear_corners_are_a_skip_not_a_crash():
    obj = np.array([[0, 0, 0], [0.04, 0, 0], [0.08, 0, 0], [0.12, 0, 0.0]])
    img = np.array([[100, 100], [140, 100], [180, 100], [220, 100.0]])
    with pytest.raises(MarkerNotFoundError, match="degenerate"):
        solve_pnp(img, obj, K, DIST, square=False)
