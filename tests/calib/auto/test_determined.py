"""handeye.calib.auto.determined: what a recording whose tool never turns (or turns about one axis) determines."""

import numpy as np
import pytest

from handeye.calib import model, solve
from handeye.calib import transforms as tf
from handeye.calib.auto.determined import held_equivalent, motion_prior
from handeye.calib.errors import CalibrationError, DegenerateMotionError
from handeye.calib.problem import CalibrationProblem
from handeye.calib.refine import error_vector
from handeye.calib.simulate import realistic_cell, with_gross_outliers

#: The camera's systematic error of the cells here: ``auto`` must determine it from a grid too.
CAMERA = model.CameraCorrection(depth_scale=0.015, depth_offset=0.003)


def _cell(seed, setup, n=100, **motion):
    """A realistic cell seen through `CAMERA`: the data, the problem of its measured points, the true camera."""
    d = realistic_cell(n, np.random.default_rng(seed), setup=setup, **motion)
    problem = CalibrationProblem.from_arrays(d.A, CAMERA.measure(d.points), setup=setup)
    return d, problem, d.Y if setup == "eye_to_hand" else d.X


def _offset(d, setup):
    return (d.X if setup == "eye_to_hand" else d.Y)[:3, 3]


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_open_directions_of_each_motion(setup):
    """Pure translations leave 3 directions of the translations open, one rotation axis 1, two axes none; a
    robot's 0.01 deg of rotation noise does not hide it."""
    rng = np.random.default_rng(3)
    for motion, k in (({"angle_range": 0.0}, 3), ({"rotation_axis": (0.0, 1.0, 0.0)}, 1), ({}, 0)):
        for noise in ((0.0, 0.0), (np.deg2rad(0.01), 0.0)):
            d = realistic_cell(30, rng, setup=setup, robot_noise=noise, **motion)
            M = model.split(np.eye(4), np.eye(4), d.A, setup)[2]
            open_dirs = model.open_translations(M, 1e-3)
            assert open_dirs.shape == (6, k)
            # Open: the marker points do not move along them.
            for v in open_dirs.T:
                w = np.einsum("nij,j->ni", M[:, :3, :3], v[3:]) - v[:3]
                assert np.abs(w).max() < 1e-3 * np.linalg.norm(v)


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
@pytest.mark.parametrize("motion", [{"angle_range": 0.0}, {"rotation_axis": (0.0, 0.0, 1.0)}])
def test_what_a_grid_determines_is_within_its_stated_covariance(setup, motion):
    """12 cells: the camera's rotation against its 3x3 covariance (NEES, mean 3 when honest) and the camera
    transform against the truth moved to the value held (`held_equivalent`); the depth scale found; the
    result names what is open and how to close it."""
    nees_rot, nees_all, dof = [], [], []
    for seed in range(12):
        d, problem, _ = _cell(seed, setup, **motion)
        res = solve("auto", problem)
        assert len(res.undetermined) == 1 and "not separated" in res.undetermined[0]
        assert "--marker-offset" in res.undetermined[0]
        assert any(note.startswith("determined: the camera's rotation to") for note in res.auto.notes)
        mp = motion_prior(problem)
        X, Y = held_equivalent(d.X, d.Y, d.A, setup, mp)
        e = error_vector(res.camera_transform, model.split(X, Y, d.A, setup)[0])
        nees_rot.append(e[:3] @ np.linalg.solve(res.cov[:3, :3], e[:3]))
        nees_all.append(e @ np.linalg.solve(res.cov, e))
        dof.append(6 - (0 if setup == "eye_to_hand" else mp.open.shape[1]))
        scale = res.auto.camera_correction["depth_scale"]
        assert scale.estimated and abs(scale.value - CAMERA.depth_scale) < 4 * scale.sigma
    assert 1.5 < np.mean(nees_rot) < 5.0, np.mean(nees_rot)
    assert 0.5 * dof[0] < np.mean(nees_all) < 1.6 * dof[0], (np.mean(nees_all), dof[0])


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_the_known_offset_completes_a_grid(setup):
    """With the true marker offset the grid's answer is complete (nothing undetermined, the note says it was
    held) and its error matches the stated 6x6 covariance."""
    nees = []
    for seed in range(12):
        d, problem, T_true = _cell(seed, setup, angle_range=0.0)
        res = solve("auto", d.A, problem.points, setup=setup, marker_offset=_offset(d, setup))
        assert res.undetermined == ()
        assert any("was given and is held as given: it completes" in note for note in res.auto.notes)
        np.testing.assert_allclose(model.split(res.X, res.Y, d.A, setup)[1][:3, 3], _offset(d, setup), atol=1e-4)
        nees.append(error_vector(res.camera_transform, T_true) @ np.linalg.solve(res.cov, error_vector(
            res.camera_transform, T_true)))
    assert 3.0 < np.mean(nees) < 9.6, np.mean(nees)


def test_the_offset_s_stated_sigma_joins_the_camera_s():
    """An offset known to 10 mm: the camera's position (eye-to-hand grid) is no better known than that; held as
    given, it is known to what the grid determines."""
    d, problem, _ = _cell(1, "eye_to_hand", angle_range=0.0)
    held = solve("auto", d.A, problem.points, marker_offset=d.X[:3, 3])
    loose = solve("auto", d.A, problem.points, marker_offset=d.X[:3, 3], marker_offset_sigma=0.01)
    assert loose.sigma[1] > 0.01 > held.sigma[1]
    assert np.hypot(held.sigma[1], 0.01) == pytest.approx(loose.sigma[1], rel=0.1)
    assert loose.sigma[0] == pytest.approx(held.sigma[0], rel=0.05)       # the rotation does not depend on it
    assert any("held at its 1-sigma of 10.00 mm" in note for note in loose.auto.notes)


def test_one_axis_names_the_axis_and_pose_data_work_too():
    """Rotations about the flange's y axis: the sentence names it; marker poses (orientations) are used."""
    d = realistic_cell(40, np.random.default_rng(5), rotation_axis=(0.0, 1.0, 0.0))
    res = solve("auto", d.A, d.B)
    assert "[0.00, 1.00, 0.00], flange frame" in res.undetermined[0] and "a second axis" in res.undetermined[0]
    assert res.auto.measurements == ("points", "orientations")
    rot, _ = tf.pose_error(res.camera_transform, d.Y)
    assert rot < 4 * res.sigma[0]


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_outliers_in_a_grid_are_found(setup):
    """15% gross outliers in a grid: the outlier search runs around the registration start and names them all."""
    d = realistic_cell(80, np.random.default_rng(21), setup=setup, angle_range=0.0)
    points, bad = with_gross_outliers(d.points, 0.15, np.random.default_rng(1))
    res = solve("auto", d.A, points, setup=setup)
    assert res.auto.start == "registration+LMedS" and res.rejected.tolist() == bad.tolist()
    assert res.undetermined


def test_the_offset_is_held_with_full_motions_too():
    """A given offset is held whatever the motions: it stays as given, and nothing is undetermined."""
    d = realistic_cell(30, np.random.default_rng(6))
    res = solve("auto", d.A, d.points, marker_offset=d.X[:3, 3])
    np.testing.assert_allclose(res.X[:3, 3], d.X[:3, 3], atol=1e-4)
    assert res.undetermined == () and motion_prior(CalibrationProblem.from_arrays(d.A, d.points)).prior is None


def test_what_cannot_be_answered_is_still_refused():
    """Positions on one line at one orientation leave the camera's rotation about the line open: refused."""
    d = realistic_cell(20, np.random.default_rng(7), angle_range=0.0)
    A = d.A.copy()
    A[:, :3, 3] = A[0, :3, 3] + np.linspace(-0.1, 0.1, 20)[:, None] * np.array([1.0, 0.5, 0.0])
    points = (tf.invert(d.Y) @ A @ d.X)[:, :3, 3]
    with pytest.raises(DegenerateMotionError, match="lie on one line"):
        solve("auto", A, points)


def test_marker_offset_is_checked():
    d = realistic_cell(10, np.random.default_rng(8))
    with pytest.raises(CalibrationError, match="marker_offset must be 3 numbers"):
        solve("auto", d.A, d.points, marker_offset=[0.0, 0.1])
    with pytest.raises(CalibrationError, match="marker_offset_sigma must be one 1-sigma >= 0"):
        solve("auto", d.A, d.points, marker_offset=[0.0, 0.0, 0.1], marker_offset_sigma=-1.0)
    with pytest.raises(CalibrationError, match="marker_offset applies to method 'auto' only"):
        solve("YKronT'", d.A, d.points, marker_offset=[0.0, 0.0, 0.1])


def test_the_prior_is_part_of_the_linearization():
    """`handeye.calib.model.Linearization` with a `TranslationPrior`: its cost, gradient and normal matrix include it
    (the gradient against central differences of the cost along the marker-side translation)."""
    d = realistic_cell(20, np.random.default_rng(9))
    C, K, M = model.split(d.X, d.Y, d.A, "eye_to_hand")
    prior = model.held_prior(np.vstack([np.zeros((3, 3)), np.eye(3)]), np.r_[0.0, 0.0, 0.0, 0.01, 0.0, 0.0], 0.002)
    W = model.whitener(d.point_cov)
    plain, held = model.Linearization(M, d.points, W), model.Linearization(M, d.points, W, prior=prior)
    N0, g0, c0 = plain.normal_equations(C, K, None)
    N1, g1, c1 = held.normal_equations(C, K, None)
    r = prior.residual(C, K)
    assert c1 == pytest.approx(c0 + r @ r) and held.cost(C, K) == pytest.approx(c1)
    np.testing.assert_allclose(N1 - N0, prior.jacobian(9, 9).T @ prior.jacobian(9, 9))
    h = 1e-6
    for j in range(3):
        Kp, Km = K.copy(), K.copy()
        Kp[j, 3] += h
        Km[j, 3] -= h
        assert (held.cost(C, Kp) - held.cost(C, Km)) / (2 * h) == pytest.approx(2 * g1[6 + j], rel=1e-4, abs=1e-3)
