"""handeye.calib.model: the shared measurement model (Jacobians, camera correction, noise levels, LOO)."""

import numpy as np
import pytest

from handeye.calib import model
from handeye.calib import transforms as tf
from handeye.calib.api import closed_form
from handeye.calib.refine import refine
from handeye.calib.simulate import realistic_cell
from handeye.calib.problem import CalibrationProblem


def _numeric_jacobian(problem, C, K, theta, eps=1e-7):
    r0 = problem.raw(C, K, theta)
    base = np.concatenate([r0[0].ravel()] + ([] if r0[1] is None else [r0[1].ravel()]))
    cols = []
    for k in range(problem.n_params):
        d = np.zeros(problem.n_params)
        d[k] = eps
        C2, K2, th2 = problem.retract(C, K, theta, d)
        r = problem.raw(C2, K2, th2)
        cols.append((np.concatenate([r[0].ravel()] + ([] if r[1] is None else [r[1].ravel()])) - base) / eps)
    return np.column_stack(cols)


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
@pytest.mark.parametrize("poses", [False, True])
def test_jacobian_matches_finite_differences(setup, poses):
    rng = np.random.default_rng(3)
    d = realistic_cell(12, rng, setup=setup)
    C, K, M = model.split(d.X, d.Y, d.A, setup)
    B = d.B if poses else d.points
    theta = np.array([0.01, 0.004, -0.008])
    prob = model.Linearization(M, B, np.broadcast_to(np.eye(3), (12, 3, 3)), sigma_rot=1.0, free=(True, True, True))
    r, e, J_t, J_e = prob.raw(C, K, theta)
    J = J_t.reshape(-1, prob.n_params) if e is None else np.vstack([J_t.reshape(-1, prob.n_params),
                                                                      J_e.reshape(-1, prob.n_params)])
    np.testing.assert_allclose(J, _numeric_jacobian(prob, C, K, theta), atol=2e-5)


def test_camera_correction_round_trip():
    rng = np.random.default_rng(0)
    p = rng.uniform([-0.3, -0.2, 0.5], [0.3, 0.2, 1.2], size=(20, 3))
    corr = model.CameraCorrection(depth_scale=0.015, depth_offset=0.003, focal_scale=-0.01)
    m = corr.measure(p)
    # Depth follows (1 + s) z + d; lateral coordinates scale by (1 + f) on top of the ray move.
    np.testing.assert_allclose(m[:, 2], 1.015 * p[:, 2] + 0.003)
    np.testing.assert_allclose(m[:, 0] / m[:, 2], 0.99 * p[:, 0] / p[:, 2])
    np.testing.assert_allclose(corr.correct(m), p, atol=1e-12)


def test_refine_unchanged_through_the_public_model():
    """The paper's refinement is the model with no nuisance and theta = 0: same estimate as LM on the model."""
    rng = np.random.default_rng(5)
    d = realistic_cell(25, rng)
    start = closed_form("YKronT'", d.A, d.points)
    res = refine(start, CalibrationProblem.from_arrays(d.A, d.points, point_cov=d.point_cov))
    C, K, M = model.split(start.X, start.Y, d.A, "eye_to_hand")
    prob = model.Linearization(M, d.points, model.whitener(d.point_cov))
    C2, K2, _, cost, _, _ = model.minimize(prob, C, K)
    np.testing.assert_allclose(C2, res.Y, atol=1e-9)
    assert cost == pytest.approx(res.refinement.cost)


def test_variance_components_recover_point_and_robot_noise():
    """Simulated 1 mm / 3 mm camera noise and 0.8 mm robot error: both levels found within 20%."""
    rng = np.random.default_rng(11)
    d = realistic_cell(600, rng, robot_noise=(0.0008 * model.ROBOT_ROTATION_PER_M, 0.0008))
    C, K, M = model.split(d.X, d.Y, d.A, "eye_to_hand")
    noise = model.NoiseLevels(point_scale=0.3, robot=1e-4)
    for _ in range(12):
        cof = model.robot_cofactor(C, K, M, "eye_to_hand")
        prob = model.Linearization(M, d.points, model.whitener(noise.point_cov(d.point_cov, cof)))
        C, K, _, _, _, _ = model.minimize(prob, C, K)
        noise, dof = model.variance_components(prob, C, K, None, d.point_cov, cof, noise)
    assert noise.point_scale == pytest.approx(1.0, rel=0.2)
    assert noise.robot == pytest.approx(0.0008, rel=0.2)
    assert dof.sum() == pytest.approx(3 * 600 - 9, rel=0.02)


def test_linearised_leave_one_out_matches_refits():
    rng = np.random.default_rng(2)
    d = realistic_cell(15, rng)
    C, K, M = model.split(d.X, d.Y, d.A, "eye_to_hand")
    prob = model.Linearization(M, d.points, model.whitener(d.point_cov))
    C, K, _, _, _, _ = model.minimize(prob, C, K)
    errors, predicted = model.leave_one_out(prob, C, K, point_cov=d.point_cov)
    exact = []
    for i in range(15):
        keep = np.arange(15) != i
        sub = model.Linearization(M[keep], d.points[keep], model.whitener(d.point_cov[keep]))
        Ci, Ki, _, _, _, _ = model.minimize(sub, C, K)
        exact.append(np.linalg.norm(d.points[i] - model.predict_points(Ci, Ki[:3, 3], M[i:i + 1])[0]))
    np.testing.assert_allclose(errors, exact, rtol=0.05, atol=5e-5)
    # The predicted held-out error exceeds the noise alone (the fit's own uncertainty adds to it).
    assert np.all(predicted > np.sqrt(np.trace(d.point_cov, axis1=1, axis2=2)))


def test_leave_one_out_after_step_matches_a_refit_with_the_parameter_freed():
    """Held-out errors after one Gauss-Newton step with the depth scale freed, from the fit without it,
    match those of the converged fit with it: the step decides whether that refit is worth making."""
    rng = np.random.default_rng(8)
    d = realistic_cell(30, rng)
    p = d.points * 1.02
    C, K, M = model.split(d.X, d.Y, d.A, "eye_to_hand")
    W = model.whitener(d.point_cov)
    C0, K0, _, _, _, _ = model.minimize(model.Linearization(M, p, W), C, K)
    freed = model.Linearization(M, p, W, free=(True, False, False))
    theta0 = np.zeros(3)
    errors, predicted, delta = model.leave_one_out_after_step(freed, C0, K0, theta0, point_cov=d.point_cov)
    C1, K1, theta1, _, _, _ = model.minimize(freed, C0, K0, theta0)
    exact, exact_pred = model.leave_one_out(freed, C1, K1, theta1, point_cov=d.point_cov)
    assert theta1[0] == pytest.approx(delta[-1], rel=1e-3)          # the step is the fit, to first order
    np.testing.assert_allclose(errors, exact, rtol=1e-3, atol=1e-6)
    np.testing.assert_allclose(predicted, exact_pred, rtol=1e-3)
    # Freeing the scale of a 2% depth error lowers the held-out error.
    before, _ = model.leave_one_out(model.Linearization(M, p, W), C0, K0, point_cov=d.point_cov)
    assert np.sqrt(np.mean(errors**2)) < 0.9 * np.sqrt(np.mean(before**2))


def test_skew_and_so3_live_in_transforms():
    v = np.array([0.1, -0.2, 0.3])
    np.testing.assert_allclose(tf.skew(v) @ np.array([1.0, 2.0, 3.0]), np.cross(v, [1.0, 2.0, 3.0]), atol=1e-15)
    np.testing.assert_allclose(tf.so3_log(tf.so3_exp(v)), v)
    assert tf.so3_exp(np.zeros((4, 2, 3))).shape == (4, 2, 3, 3)


def test_rigid_stand_in_of_a_camera_correction_is_its_least_squares_rigid_fit():
    rng = np.random.default_rng(21)
    points = np.c_[rng.uniform(-0.3, 0.3, (40, 2)), rng.uniform(0.6, 1.0, 40)]
    G, misfit = model.CameraCorrection().rigid_stand_in(points)
    assert np.allclose(G, np.eye(4)) and misfit < 1e-12
    corr = model.CameraCorrection(depth_scale=0.015, depth_offset=0.003, focal_scale=-0.01)
    G, misfit = corr.rigid_stand_in(points)
    target = corr.correct(points)
    assert misfit == pytest.approx(np.sqrt(np.mean(np.sum((tf.transform_points(G, points) - target) ** 2, axis=1))))
    assert misfit < np.sqrt(np.mean(np.sum((points - target) ** 2, axis=1))) / 3
    for _ in range(20):      # no rigid transform nearby fits better
        moved = tf.from_rotvec_translation(rng.normal(scale=1e-4, size=3), rng.normal(scale=1e-4, size=3)) @ G
        assert np.sqrt(np.mean(np.sum((tf.transform_points(moved, points) - target) ** 2, axis=1))) > misfit
