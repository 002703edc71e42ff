"""ML refinement (handeye.calib.refine): convergence, Cramér-Rao efficiency, both setups, bad input."""

import dataclasses

import numpy as np
import pytest

from handeye.calib import simulate
from handeye.calib import transforms as tf
from handeye.calib.api import closed_form, solve
from handeye.calib.errors import CalibrationError, DegenerateMotionError, InsufficientDataError
from handeye.calib.refine import cramer_rao_bound, error_vector, refine, residuals
from handeye.calib.problem import CalibrationProblem

SETUPS = ["eye_to_hand", "eye_in_hand"]


def camera(T_setup, X, Y):
    return Y if T_setup == "eye_to_hand" else X


@pytest.mark.parametrize("setup", SETUPS)
def test_refined_points_reach_cramer_rao_bound(setup):
    """RMS error of the refined camera transform within 15% of the CRLB (60 trials, N=40)."""
    rng = np.random.default_rng(11)
    se_rot, se_t, b_rot, b_t = [], [], [], []
    for _ in range(60):
        d = simulate.realistic_cell(40, rng, setup=setup)
        res = solve("YKronT'", d.A, d.points, setup=setup, refine=True, point_cov=d.point_cov)
        assert res.converged and res.method == "YKronT'+ML"
        e = error_vector(res.camera_transform, camera(setup, d.X, d.Y))
        se_rot.append(e[:3] @ e[:3])
        se_t.append(e[3:] @ e[3:])
        r, t, _ = cramer_rao_bound(d.X, d.Y, d.A_true, d.point_cov, setup=setup)
        b_rot.append(r**2)
        b_t.append(t**2)
    ratio_rot = np.sqrt(np.mean(se_rot) / np.mean(b_rot))
    ratio_t = np.sqrt(np.mean(se_t) / np.mean(b_t))
    assert 0.85 < ratio_rot < 1.15
    assert 0.85 < ratio_t < 1.15


def test_refinement_beats_closed_form_and_keeps_method_name():
    rng = np.random.default_rng(2)
    d = simulate.realistic_cell(60, rng)
    start = closed_form("YKronRT", d.A, d.B)
    res = refine(start, CalibrationProblem.from_arrays(d.A, d.B, setup=start.setup))
    assert res.method == "YKronRT+ML"
    assert res.refinement.cost < res.refinement.initial_cost
    assert tf.pose_error(res.Y, d.Y)[1] < tf.pose_error(start.Y, d.Y)[1]
    assert res.cov.shape == (6, 6) and np.all(np.linalg.eigvalsh(res.cov) > 0)


@pytest.mark.parametrize("setup", SETUPS)
def test_noise_free_points_converge_to_truth_from_a_far_start(setup):
    rng = np.random.default_rng(3)
    d = simulate.realistic_cell(20, rng, setup=setup)
    p_true = d.B_true[:, :3, 3]
    P = tf.from_rotvec_translation([0.1, -0.15, 0.1], [0.05, -0.03, 0.04])
    start = closed_form("YKronT'", d.A, p_true, setup=setup)
    start = dataclasses.replace(start, X=start.X @ P, Y=P @ start.Y)
    res = refine(start, CalibrationProblem.from_arrays(d.A, p_true, setup=start.setup, point_cov=np.eye(3) * 1e-6))
    rot, t = tf.pose_error(camera(setup, res.X, res.Y), camera(setup, d.X, d.Y))
    assert rot < 1e-8 and t < 1e-8
    assert res.residuals.max_translation < 1e-8


@pytest.mark.parametrize("setup", SETUPS)
def test_pose_refinement_recovers_both_transforms(setup):
    rng = np.random.default_rng(4)
    d = simulate.realistic_cell(50, rng, setup=setup)
    res = refine(closed_form("YQuatT'", d.A, d.B, setup=setup), CalibrationProblem.from_arrays(d.A, d.B, setup=setup))
    assert res.marker_rotation_known and res.residuals.rotation is not None
    for est, true in ((res.X, d.X), (res.Y, d.Y)):
        rot, t = tf.pose_error(est, true)
        assert rot < np.deg2rad(0.5) and t < 0.005


def test_default_noise_model_used_without_point_cov():
    rng = np.random.default_rng(5)
    d = simulate.realistic_cell(40, rng)
    res = refine(closed_form("YKronT'", d.A, d.points), CalibrationProblem.from_arrays(d.A, d.points))
    assert res.refinement.variance_factor > 0
    assert tf.pose_error(res.Y, d.Y)[1] < 0.01


def test_residuals_are_point_distances():
    rng = np.random.default_rng(6)
    d = simulate.realistic_cell(10, rng)
    r = residuals(d.X, d.Y, CalibrationProblem.from_arrays(d.A, d.points, setup="eye_to_hand"))
    np.testing.assert_allclose(r.translation, np.linalg.norm(d.points - d.B_true[:, :3, 3], axis=1), atol=1e-12)
    assert r.rotation is None


def test_bad_input_raises_clear_errors():
    rng = np.random.default_rng(7)
    d = simulate.realistic_cell(10, rng)
    start = closed_form("YKronT'", d.A, d.points)
    bad = d.points.copy()
    bad[3, 1] = np.nan
    with pytest.raises(CalibrationError, match=r"B\[3\]"):
        refine(start, CalibrationProblem.from_arrays(d.A, bad))
    with pytest.raises(CalibrationError, match="point_cov"):
        refine(start, CalibrationProblem.from_arrays(d.A, d.points, point_cov=np.ones((2, 3, 3))))
    with pytest.raises(CalibrationError, match="positive definite"):
        refine(start, CalibrationProblem.from_arrays(d.A, d.points, point_cov=-np.eye(3)))
    with pytest.raises(InsufficientDataError):
        refine(start, CalibrationProblem.from_arrays(d.A[:2], d.points[:2]))
    # A robot that never moves constrains neither rotation nor marker offset.
    A = d.A.copy()
    A[:, :3, :3] = A[0, :3, :3]
    A[:, :3, 3] = A[0, :3, 3]
    with pytest.raises(DegenerateMotionError):
        refine(start, CalibrationProblem.from_arrays(A, d.points))
