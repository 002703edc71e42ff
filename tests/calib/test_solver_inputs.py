"""Property tests of the solver API: any input gives a finite result or a CalibrationError naming it.

Eye-to-hand data (``X = T_flange_marker``, ``Y = T_base_cam``) unless a test
says eye-in-hand. Example counts are bounded so the file runs in ~10 s.
"""

import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from handeye.calib import METHODS, CalibrationError, simulate, solve
from handeye.calib import solvers
from handeye.calib import transforms as tf
from handeye.calib.api import closed_form
from handeye.calib.refine import refine
from handeye.calib.robust import robust_solve
from handeye.calib.problem import CalibrationProblem

FAST = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])

DATA = simulate.paper_setup(8, np.random.default_rng(5), noise_A=(0.005, 0.001), noise_B=(0.005, 0.001))
POSE_METHODS = [m for m, i in METHODS.items() if i.needs == "poses"]

# Floats of every kind a file or a bug can produce: huge, tiny, NaN, inf, negative zero.
WILD = st.floats(allow_nan=True, allow_infinity=True, width=64)


def _assert_finite(res):
    for name in ("X", "Y", "cov"):
        v = getattr(res, name)
        assert v is None or np.isfinite(v).all(), name
    assert np.isfinite(res.residuals.translation).all()


def _solve_or_clean_error(call):
    """The call returns a finite result or raises CalibrationError; nothing else, and no warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            res = call()
        except CalibrationError as e:
            assert str(e)
            return None
    _assert_finite(res)
    return res


@FAST
@given(method=st.sampled_from(list(METHODS)), which=st.sampled_from(["A", "B"]),
       sample=st.integers(0, 7), entry=st.integers(0, 15), value=WILD,
       refine_=st.booleans(), setup=st.sampled_from(["eye_to_hand", "eye_in_hand"]))
def test_one_wild_entry_gives_finite_result_or_calibration_error(method, which, sample, entry, value, refine_, setup):
    A, B = DATA.A.copy(), DATA.B.copy()
    (A if which == "A" else B)[sample].reshape(16)[entry] = value
    B_in = B[:, :3, 3] if METHODS[method].needs == "points" else B
    _solve_or_clean_error(lambda: solve(method, A, B_in, setup=setup, refine=refine_))


@FAST
@given(method=st.sampled_from(list(METHODS)),
       A=hnp.arrays(np.float64, st.tuples(st.integers(0, 7), st.sampled_from([3, 4]), st.sampled_from([3, 4])),
                    elements=WILD),
       B=hnp.arrays(np.float64, st.tuples(st.integers(0, 7), st.sampled_from([3, 4])), elements=WILD))
def test_arbitrary_float_arrays_never_crash(method, A, B):
    _solve_or_clean_error(lambda: solve(method, A, B))
    _solve_or_clean_error(lambda: closed_form(method, A, np.broadcast_to(np.eye(4), (len(B), 4, 4))))


# Python values of every shape and type a JSON/YAML/TOML file can hold.
JSONISH = st.recursive(
    st.none() | st.booleans() | st.integers() | WILD | st.text(max_size=3) | st.complex_numbers(),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=2), inner, max_size=2),
    max_leaves=20,
)


@FAST
@given(A=JSONISH, B=JSONISH, method=st.sampled_from(["YKronT'", "YQuatT'", "XKronT"]))
def test_arbitrary_python_values_raise_calibration_error(A, B, method):
    _solve_or_clean_error(lambda: solve(method, A, B))


@pytest.mark.parametrize("make", [
    lambda a: a.tolist(),
    lambda a: a.astype(object),
])
def test_lists_and_object_arrays_of_numbers_are_accepted(make):
    res = solve("YQuatT'", make(DATA.A), make(DATA.B))
    assert np.allclose(res.Y, solve("YQuatT'", DATA.A, DATA.B).Y)


@pytest.mark.parametrize("bad,match", [
    (lambda a: a + 1e-3j, "complex"),
    (lambda a: a.astype(complex), "complex"),
    (lambda a: np.where(np.arange(a.size).reshape(a.shape) == 5, "x", a.astype(object)), "real numbers"),
    (lambda a: a.tolist()[:3] + [a.tolist()[3][:2]] + a.tolist()[4:], "rectangular"),
    (lambda a: a > 0, "real numbers"),
    (lambda a: None, "numeric array"),
    (lambda a: "poses.csv", "numeric array"),
])
def test_malformed_containers_are_named(bad, match):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # complex must be refused, not cast with a ComplexWarning
        with pytest.raises(CalibrationError, match=rf"^A .*{match}|^A\[?.*{match}"):
            solve("YQuatT'", bad(DATA.A), DATA.B)


def test_huge_coordinate_is_refused_naming_the_sample():
    A = DATA.A.copy()
    A[3, 0, 3] = 1e155
    with pytest.raises(CalibrationError, match=r"A\[3\].*1e\+155"):
        solve("YKronT'", A, DATA.points, refine=True)


def test_marker_point_at_the_camera_origin_is_refused_naming_the_sample():
    p = DATA.points.copy()
    p[2] = 0.0
    with pytest.raises(CalibrationError, match=r"B\[2\].*camera origin"):
        solve("YKronT'", DATA.A, p)
    B = DATA.B.copy()
    B[4, :3, 3] = 0.0
    for method in POSE_METHODS:
        with pytest.raises(CalibrationError, match=r"B\[4\].*camera origin"):
            solve(method, DATA.A, B, refine=True)


@pytest.mark.parametrize("name", ["x_axis_rx", "x_quat_r_star", "x_kron_r_star", "x_kron_rt", "x_kron_t",
                                  "y_axis_r", "y_quat_r_star", "y_kron_rt", "y_quat_t_prime"])
def test_public_solver_functions_validate(name):
    fn = getattr(solvers, name)
    with pytest.raises(CalibrationError, match="complex"):
        fn(DATA.A.astype(complex), DATA.B)
    with pytest.raises(CalibrationError, match=r"B\[1\].*NaN"):
        B = DATA.B.copy()
        B[1, 0, 0] = np.nan
        fn(DATA.A, B)
    with pytest.raises(CalibrationError, match="rectangular"):
        fn(DATA.A, [b.tolist() for b in DATA.B[:-1]] + [[1.0, 2.0]])


def test_the_problem_refine_and_robust_take_is_validated():
    init = closed_form("YKronT'", DATA.A, DATA.points)
    with pytest.raises(CalibrationError, match="point_cov.*complex"):
        refine(init, CalibrationProblem.from_arrays(DATA.A, DATA.points, point_cov=np.eye(3) * (1e-6 + 0j)))
    with pytest.raises(CalibrationError, match=r"point_cov\[0\].*NaN"):
        refine(init, CalibrationProblem.from_arrays(DATA.A, DATA.points, point_cov=np.full((8, 3, 3), np.nan)))
    with pytest.raises(CalibrationError, match=r"B\[0\].*camera origin"):
        robust_solve(lambda sub: closed_form("YKronT'", sub), CalibrationProblem.from_arrays(DATA.A, np.zeros((8, 3))),
                     rng=np.random.default_rng(0))


def test_x_kron_t_robust_uses_subsets_it_can_solve():
    """XKronT needs 5 poses; its LMedS subsets must have 5, not the default 4 (every subset failed)."""
    d = simulate.paper_setup(20, np.random.default_rng(3), noise_A=(0.01, 0.002), noise_B=(0.01, 0.002))
    B = d.B.copy()
    B[[2, 11], :3, 3] += 0.3  # two gross outliers
    res = solve("XKronT", d.A, B, robust=True)
    assert res.robust.subset == 5
    assert {2, 11} <= set(res.rejected.tolist()) and len(res.rejected) <= 3
    rot, trans = tf.pose_error(res.Y, d.Y)
    assert trans < 0.02 and np.rad2deg(rot) < 1.0


def test_result_never_carries_nan():
    res = solve("YKronT'", DATA.A, DATA.points)
    from dataclasses import replace

    with pytest.raises(CalibrationError, match="cov.*not finite"):
        replace(res, cov=np.full((6, 6), np.nan))
