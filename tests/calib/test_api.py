"""The public ``solve`` API: names, input validation, degenerate motions, pipeline, observations."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from handeye.calib import (
    METHODS,
    CalibrationError,
    DegenerateMotionError,
    InsufficientDataError,
    Observation,
    observations_to_arrays,
    simulate,
    solve,
)
from handeye.calib import transforms as tf
from handeye.calib.api import closed_form, resolve_method

ALL = list(METHODS)


@pytest.fixture(scope="module")
def cell():
    return simulate.realistic_cell(30, np.random.default_rng(21))


def test_methods_table_describes_every_method():
    assert ALL == ["XAxisRX", "XQuatR*", "XKronR*", "XKronRT", "XKronT",
                   "YAxisR", "YQuatR*", "YKronRT", "YQuatT'", "YKronT'"]
    for name, info in METHODS.items():
        assert info.name == name
        assert info.equation == ("AX=XB" if name[0] == "X" else "AX=YB")
        assert info.needs in ("poses", "points")
        assert info.representation in ("axis-angle", "quaternion", "Kronecker")
        assert info.paper_equations and info.reference
    assert [m for m, i in METHODS.items() if i.needs == "points"] == ["YKronT'"]
    assert METHODS["YKronT'"].paper_equations[-1] == 20
    assert METHODS["YQuatT'"].paper_equations[-1] == 19


@pytest.mark.parametrize("alias,name", [
    ("ykront", "YKronT'"), ("YKRONT'", "YKronT'"), ("yquatt", "YQuatT'"), ("  YQuatR*  ", "YQuatR*"),
    ("xquatr", "XQuatR*"), ("xkronr", "XKronR*"), ("xkront", "XKronT"), ("XAxisRX", "XAxisRX"),
    ("yaxisr", "YAxisR"), ("ykronrt", "YKronRT"), ("xkronrt", "XKronRT"),
])
def test_method_names_case_insensitive(alias, name, cell):
    assert resolve_method(alias).name == name
    B = cell.points if METHODS[name].needs == "points" else cell.B
    assert solve(alias, cell.A, B).method == name


@pytest.mark.parametrize("bad", ["ykronT''x", "tsai", "", None])
def test_unknown_method_lists_valid_names(bad, cell):
    with pytest.raises(CalibrationError, match="YKronT'.*XAxisRX|XAxisRX.*YKronT'"):
        solve(bad, cell.A, cell.points)


def test_returns_full_result_eye_to_hand(cell):
    est = solve("YKronT'", cell.A, cell.points, point_cov=cell.point_cov)
    assert est.setup == "eye_to_hand" and est.n_samples == 30
    assert est.T_base_cam is est.Y and est.T_flange_marker is est.X
    assert est.cov.shape == (6, 6) and np.all(np.linalg.eigvalsh(est.cov) > 0)
    assert est.residuals.translation.shape == (30,)
    assert est.residuals.rotation is None and not est.marker_rotation_known
    r, t = tf.pose_error(est.Y, cell.Y)
    assert np.rad2deg(r) < 1.0 and t < 0.01
    with pytest.raises(AttributeError):
        est.T_flange_cam


def test_returns_full_result_eye_in_hand():
    d = simulate.realistic_cell(30, np.random.default_rng(22), setup="eye_in_hand")
    for method, B in (("YKronT'", d.points), ("YQuatT'", d.B)):
        est = solve(method, d.A, B, setup="eye_in_hand")
        assert est.T_flange_cam is est.X and est.T_base_marker is est.Y
        assert est.camera_transform is est.X
        assert est.cov.shape == (6, 6)
        r, t = tf.pose_error(est.X, d.X)
        assert np.rad2deg(r) < 2.0 and t < 0.02, (method, np.rad2deg(r), t)


def test_pose_stack_for_point_method_uses_translations(cell):
    a = solve("YKronT'", cell.A, cell.B)
    b = solve("YKronT'", cell.A, cell.B[:, :3, 3])
    # Equal to rounding: a strided view and a contiguous copy may sum in another order (numpy 2.2 on Python 3.10).
    np.testing.assert_allclose(a.X, b.X, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.Y, b.Y, rtol=0, atol=1e-12)


def test_points_for_pose_method_are_refused(cell):
    with pytest.raises(CalibrationError, match="YQuatR\\* needs marker poses.*YKronT'"):
        solve("YQuatR*", cell.A, cell.points)


@pytest.mark.parametrize("A_shape,B_shape,match", [
    ((30, 3, 3), (30, 3), "A must have shape"),
    ((30, 4, 4), (30, 4), "B must have shape"),
    ((30, 4, 4), (30,), "B must have shape"),
    ((30, 4, 4), (29, 3), "same number of samples"),
])
def test_wrong_shapes(A_shape, B_shape, match, cell):
    A = cell.A if A_shape == (30, 4, 4) else np.zeros(A_shape)
    B = cell.points[: B_shape[0]] if B_shape[-1] == 3 and len(B_shape) == 2 else np.zeros(B_shape)
    with pytest.raises(CalibrationError, match=match):
        solve("YKronT'", A, B)


def test_nan_and_non_rotation_are_refused(cell):
    A = cell.A.copy()
    A[4, 0, 3] = np.nan
    with pytest.raises(CalibrationError, match=r"A\[4\] contains NaN"):
        solve("YKronT'", A, cell.points)
    p = cell.points.copy()
    p[2, 1] = np.inf
    with pytest.raises(CalibrationError, match=r"B\[2\] contains NaN or inf"):
        solve("YKronT'", cell.A, p)
    B = cell.B.copy()
    B[7, :3, :3] *= 1.1
    with pytest.raises(CalibrationError, match=r"B\[7\] rotation is not a proper rotation"):
        solve("YQuatT'", cell.A, B)


def test_bad_setup_and_point_cov(cell):
    with pytest.raises(CalibrationError, match="setup"):
        solve("YKronT'", cell.A, cell.points, setup="eye_on_hand")
    with pytest.raises(CalibrationError, match="point_cov"):
        solve("YKronT'", cell.A, cell.points, point_cov=np.eye(2))


@pytest.mark.parametrize("method", ALL)
def test_too_few_samples_names_minimum(method, cell):
    n = METHODS[method].min_samples - 1
    B = cell.points if METHODS[method].needs == "points" else cell.B
    with pytest.raises(InsufficientDataError, match=f"at least {n + 1} samples, got {n}"):
        solve(method, cell.A[:n], B[:n])


# ------------------------------------------------------------------ degenerate motions


def motion_set(kind: str, setup: str, rng, n=20, marker_noise=(np.deg2rad(1.0), 0.002)):
    """Robot poses of a degenerate (or good) kind and the marker measurements they produce."""
    d = simulate.realistic_cell(3, rng, setup=setup)
    R0, p0 = d.A_true[0, :3, :3], d.A_true[0, :3, 3]
    t = p0 + rng.uniform(-0.1, 0.1, size=(n, 3))
    if kind == "one_axis":
        R = R0 @ Rotation.from_rotvec(np.outer(rng.uniform(-0.5, 0.5, n), [0.0, 1.0, 0.0])).as_matrix()
    elif kind == "pure_translation":
        R = np.broadcast_to(R0, (n, 3, 3))
    elif kind == "identical":
        R, t = np.broadcast_to(R0, (n, 3, 3)), np.broadcast_to(p0, (n, 3))
    else:  # good but small: +-10 deg about random axes
        R = tf.random_rotations(n, np.deg2rad(10.0), rng) @ R0
    A = tf.make_transform(R, t)
    B = tf.invert(d.Y) @ A @ d.X if setup == "eye_to_hand" else tf.invert(A @ d.X) @ d.Y
    noise = tf.from_rotvec_translation(rng.normal(scale=marker_noise[0], size=(n, 3)),
                                       rng.normal(scale=marker_noise[1], size=(n, 3)))
    return A, B @ noise


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
@pytest.mark.parametrize("kind,match", [
    ("one_axis", r"all rotations are about one axis \(\+-2\d\.\d deg about flange axis .*rotate about at least two"),
    ("pure_translation", "no rotation: pure translations cannot determine"),
    ("identical", "no motion: all 20 robot poses are identical"),
])
@pytest.mark.parametrize("method", ALL)
def test_degenerate_motion_is_detected(method, kind, match, setup):
    A, B = motion_set(kind, setup, np.random.default_rng(1))
    B = B[:, :3, 3] if METHODS[method].needs == "points" else B
    with pytest.raises(DegenerateMotionError, match=match):
        solve(method, A, B, setup=setup)


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
@pytest.mark.parametrize("points", [False, True])
@pytest.mark.parametrize("kind", ["one_axis", "pure_translation"])
def test_auto_answers_what_a_degenerate_motion_determines(setup, points, kind):
    """Where the closed forms refuse, ``auto`` gives what the motions determine and names the rest with the
    motion that closes it (`handeye.calib.auto.determined`); motions that determine nothing stay a typed refusal."""
    A, B = motion_set(kind, setup, np.random.default_rng(1))
    res = solve("auto", A, B[:, :3, 3] if points else B, setup=setup)
    assert len(res.undetermined) == 1 and "not separated" in res.undetermined[0]
    assert ("a second axis" if kind == "one_axis" else "about two axes") in res.undetermined[0]
    A, B = motion_set("identical", setup, np.random.default_rng(1))
    with pytest.raises(DegenerateMotionError, match="no motion: all 20 robot poses are identical"):
        solve("auto", A, B[:, :3, 3] if points else B, setup=setup)


@pytest.mark.parametrize("kind", ["one_axis", "pure_translation"])
@pytest.mark.parametrize("method", ALL)
def test_degenerate_motion_with_robot_noise_is_detected(method, kind):
    """0.01 deg of robot rotation noise must not make a degenerate motion set look solvable."""
    rng = np.random.default_rng(4)
    A, B = motion_set(kind, "eye_to_hand", rng)
    A = A @ tf.from_rotvec_translation(rng.normal(scale=np.deg2rad(0.01), size=(len(A), 3)), np.zeros((len(A), 3)))
    B = B[:, :3, 3] if METHODS[method].needs == "points" else B
    with pytest.raises(DegenerateMotionError, match="one axis" if kind == "one_axis" else "no rotation"):
        solve(method, A, B)


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
@pytest.mark.parametrize("method", ALL)
def test_mildly_noisy_good_motion_is_not_flagged(method, setup):
    rng = np.random.default_rng(2)
    A, B = motion_set("good", setup, rng)
    d = simulate.realistic_cell(20, rng, setup=setup)  # default noise, +-40 deg
    for A_, B_ in ((A, B), (d.A, d.B)):
        B_ = B_[:, :3, 3] if METHODS[method].needs == "points" else B_
        closed_form(method, A_, B_, setup=setup)


# ------------------------------------------------------------------ pipeline wiring


def test_robust_rejects_a_gross_outlier_and_refine_runs(cell):
    p = cell.points.copy()
    p[5] += [0.2, -0.1, 0.1]
    plain = solve("YKronT'", cell.A, p)
    robust = solve("YKronT'", cell.A, p, robust=True, refine=True, rng=np.random.default_rng(0))
    assert robust.inliers is not None and not robust.inliers[5]
    assert 5 in robust.rejected
    assert robust.cov.shape == (6, 6)
    err_plain = tf.pose_error(plain.Y, cell.Y)[1]
    err_robust = tf.pose_error(robust.Y, cell.Y)[1]
    assert err_robust < err_plain


def test_solve_is_deterministic_without_rng(cell):
    a = solve("YKronT'", cell.A, cell.points, robust=True)
    b = solve("YKronT'", cell.A, cell.points, robust=True)
    np.testing.assert_array_equal(a.Y, b.Y)


# ------------------------------------------------------------------ observations


def make_observations(cell):
    obs = []
    for i in range(len(cell.A)):
        has_point = i % 4 != 1
        has_pose = i % 3 != 2
        obs.append(Observation(
            index=i, t=float(i), T_base_flange=cell.A[i],
            point_cam=cell.points[i] if has_point else None,
            point_cov=cell.point_cov[i] if has_point else None,
            T_cam_marker=cell.B[i] if has_pose else None,
            pose_cov=np.eye(6) * 1e-6 if has_pose else None,
        ))
    return obs


def test_observations_to_points(cell):
    obs = make_observations(cell)
    A, B, cov, kept = observations_to_arrays(obs, "points")
    expected = [i for i in range(len(obs)) if i % 4 != 1]
    np.testing.assert_array_equal(kept, expected)
    np.testing.assert_array_equal(A, cell.A[expected])
    np.testing.assert_array_equal(B, cell.points[expected])
    np.testing.assert_array_equal(cov, cell.point_cov[expected])
    est = solve("YKronT'", A, B, point_cov=cov)
    assert est.n_samples == len(expected)


def test_observations_to_poses_maps_pose_covariance(cell):
    obs = make_observations(cell)
    A, B, cov, kept = observations_to_arrays(obs, "poses")
    np.testing.assert_array_equal(kept, [i for i in range(len(obs)) if i % 3 != 2])
    assert B.shape == (len(kept), 4, 4)
    t = B[0, :3, 3]
    # Left perturbation: delta_t_total = delta_rot x t + delta_t, so the variance grows with |t|^2.
    expected = 1e-6 * (np.eye(3) + (t @ t) * np.eye(3) - np.outer(t, t))
    np.testing.assert_allclose(cov[0], expected, atol=1e-15)


def test_observations_missing_cov_and_errors(cell):
    obs = make_observations(cell)
    obs[0].point_cov = None
    _, _, cov, _ = observations_to_arrays(obs, "points")
    assert cov is None
    with pytest.raises(CalibrationError, match="kind"):
        observations_to_arrays(obs, "pixels")
    with pytest.raises(InsufficientDataError, match="point_cam"):
        observations_to_arrays([Observation(0, 0.0, np.eye(4))], "points")
