"""handeye.calib.monitor: the monitoring engine over simulated production shifts (handeye.calib.simulate.shift_stream)."""

import dataclasses

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from bench import shift as bench_shift
from handeye.calib import model, simulate, solve
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError
from handeye.calib.monitor import (EngineState, MonitorEngine, MonitorSettings, WorkspaceMoments, workspace_distance,
                                   workspace_sigma)
from handeye.calib.monitor.kernels import parts, sample_floats
from handeye.calib.problem import CalibrationProblem
from handeye.calib.setup import Setup

PROFILE = simulate.RealisticProfile()


def _armed(seed: int = 1, settings: MonitorSettings | None = None):
    return bench_shift.armed_cell(seed, settings, PROFILE)


@pytest.mark.parametrize("setup", [Setup.EYE_TO_HAND, Setup.EYE_IN_HAND])
def test_point_jacobians_match_finite_differences(setup):
    rng = np.random.default_rng(0)
    C = tf.from_rotvec_translation(rng.normal(size=3) * 0.3, [0.1, -0.2, 0.9])
    K = tf.from_rotvec_translation(rng.normal(size=3) * 0.3, [0.02, 0.01, 0.05])
    A = tf.from_rotvec_translation(rng.normal(size=3) * 0.3, [0.5, 0.1, 0.4])
    theta = np.array([0.01, 0.003, -0.01])
    M = (A if setup == Setup.EYE_TO_HAND else tf.invert(A))[None]
    h, H_C, H_tK, H_th, H_xi = model.point_jacobians(C, K, M, theta, setup)
    eps = 1e-7
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        C2 = tf.make_transform(tf.so3_exp(d[:3]) @ C[:3, :3], C[:3, 3] + d[3:])
        np.testing.assert_allclose((model.point_jacobians(C2, K, M, theta, setup)[0] - h)[0] / eps, H_C[0, :, k],
                                   atol=1e-5)
        A2 = A @ tf.from_rotvec_translation(d[:3], d[3:])
        M2 = (A2 if setup == Setup.EYE_TO_HAND else tf.invert(A2))[None]
        np.testing.assert_allclose((model.point_jacobians(C, K, M2, theta, setup)[0] - h)[0] / eps, H_xi[0, :, k],
                                   atol=1e-5)
    for k in range(3):
        K2 = K.copy()
        K2[k, 3] += eps
        np.testing.assert_allclose((model.point_jacobians(C, K2, M, theta, setup)[0] - h)[0] / eps, H_tK[0, :, k],
                                   atol=1e-5)
        th2 = theta.copy()
        th2[k] += eps
        np.testing.assert_allclose((model.point_jacobians(C, K, M, th2, setup)[0] - h)[0] / eps, H_th[0, :, k],
                                   atol=1e-5)


def sample_model(C, t_K, A, theta, setup, factor=None, z=None):
    """The engine's fast path (`sample_floats`) on arrays."""
    h, H, (xx, xy, xz, yy, yz, zz) = sample_floats(parts(C), tuple(t_K.tolist()), A[:3].ravel().tolist(),
                                                   theta.tolist(), setup == Setup.EYE_TO_HAND, factor, z)
    return np.array(h), H, np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


@settings(max_examples=60, deadline=None)
@given(setup=st.sampled_from([Setup.EYE_TO_HAND, Setup.EYE_IN_HAND]), seed=st.integers(0, 2**32 - 1),
       n_factor=st.sampled_from([0, 1, 24]))
def test_the_fast_path_is_the_reference_model(setup, seed, n_factor):
    """The engine's per-sample model on floats equals `handeye.calib.model`'s (the reference that ``auto`` and the arming
    use) on random states: prediction, Jacobian and robot cofactor, kinematic error included."""
    rng = np.random.default_rng(seed)
    C = tf.from_rotvec_translation(rng.normal(size=3), rng.normal(size=3) * 0.5 + [0.0, 0.0, 0.9])
    K = tf.from_rotvec_translation(rng.normal(size=3), rng.normal(size=3) * 0.05)
    A = tf.from_rotvec_translation(rng.normal(size=3), rng.normal(size=3) * 0.5)
    theta = rng.normal(size=3) * [0.01, 0.003, 0.01]
    F, z = (rng.normal(size=(6, n_factor)) * 1e-3, rng.normal(size=n_factor)) if n_factor else (None, None)
    A_err = A if F is None else A @ tf.from_rotvec_translation((F @ z)[:3], (F @ z)[3:])
    M = (A_err if setup == Setup.EYE_TO_HAND else tf.invert(A_err))[None]
    h, H_C, H_tK, H_th, H_xi = model.point_jacobians(C, K, M, theta, setup)
    assume(abs(h[0, 2]) > 1e-3)          # a point at the camera's centre has no projection
    cof = model.robot_cofactor(C, K, M, setup)[0]
    H = np.concatenate([H_C[0], H_tK[0], H_th[0]] + ([] if F is None else [H_xi[0] @ F]), axis=1)
    got = sample_model(C, K[:3, 3], A, theta, setup, F, z)
    scale = max(1.0, np.abs(h).max())
    np.testing.assert_allclose(got[0], h[0], rtol=1e-10, atol=1e-12 * scale)
    np.testing.assert_allclose(got[1], H, rtol=1e-9, atol=1e-9 * max(1.0, np.abs(H).max()))
    np.testing.assert_allclose(got[2], cof, rtol=1e-10, atol=1e-12 * max(1.0, np.abs(cof).max()))


@pytest.mark.parametrize("n", [1, 3, 200])
def test_workspace_moments_give_the_workspace_figures(n):
    """RMS distance and 1-sigma over the points from their moments, for any number of points (one: a rank-0
    spread, three: a plane)."""
    rng = np.random.default_rng(2)
    points = rng.normal(size=(n, 3)) * [0.2, 0.15, 0.1] + [0.0, 0.0, 0.9]
    moments = WorkspaceMoments(points)
    for _ in range(3):
        C1 = tf.from_rotvec_translation(rng.normal(size=3), rng.normal(size=3))
        C2 = tf.from_rotvec_translation(rng.normal(size=3) * 0.01, rng.normal(size=3) * 0.01) @ C1
        theta = rng.normal(size=3) * [0.01, 0.003, 0.01]
        L = rng.normal(size=(36, 36))
        cov = L @ L.T * 1e-6
        assert moments.sigma(C1, theta, cov) == pytest.approx(workspace_sigma(C1, theta, points, cov), rel=1e-10)
        # The drift factor: |F d| is the sigma of d d^T, and to first order where C, theta put the points.
        d = np.r_[tf.so3_log(C2[:3, :3] @ C1[:3, :3].T), C2[:3, 3] - C1[:3, 3], rng.normal(size=3) * 0.01,
                  rng.normal(size=3) * [1e-4, 3e-5, 1e-4]]
        F = moments.drift_factor(C1, theta)
        assert np.linalg.norm(F @ d) == pytest.approx(moments.sigma(C1, theta, np.outer(d, d)), rel=1e-8)
        moved = (tf.transform_points(C2, model.CameraCorrection(*(theta + d[9:])).correct(points))
                 - tf.transform_points(C1, model.CameraCorrection(*theta).correct(points)))
        assert np.linalg.norm(F @ d) == pytest.approx(np.sqrt(np.mean(np.sum(moved ** 2, axis=1))), rel=0.05)
        # Without a change of the correction, the exact distance between the two camera transforms.
        d[9:] = 0.0
        assert np.linalg.norm(F @ d) == pytest.approx(workspace_distance(C2, C1, model.CameraCorrection(
            *theta).correct(points)), rel=0.02)


def test_samples_of_any_array_type_give_the_same_update():
    """Lists, float32 and float64 arrays of the same sample are the same update; the quick checks of float64
    arrays refuse what the general validators refuse."""
    real, res, engine = _armed(5)
    stream = simulate.shift_stream(real, dataclasses.replace(simulate.Shift(), hours=0.2),
                                   np.random.default_rng([5, 1]), PROFILE)
    F = PROFILE.dh_error_factor(stream.q)
    twin = _armed(5)[2]
    for i in range(len(stream.t)):
        a = engine.update(stream.t[i], stream.A[i], stream.points[i], stream.point_cov[i], F[i])
        b = twin.update(stream.t[i], stream.A[i].tolist(), stream.points[i].tolist(), stream.point_cov[i].tolist(),
                        F[i].tolist())
        np.testing.assert_array_equal(a.camera_transform, b.camera_transform)
        assert a.nis == b.nis and a.statistic == b.statistic
    A, p, S, f = stream.A[0].copy(), stream.points[0], stream.point_cov[0], F[0]
    bent = A.copy()
    bent[0, 0] += 1e-3
    with pytest.raises(CalibrationError, match="T_base_flange.*proper rotation"):
        engine.update(stream.t[-1], bent, p, S, f)
    bad_cov = S.copy()
    bad_cov[0, 1] += 1e-3
    with pytest.raises(CalibrationError, match="point_cov is not symmetric"):
        engine.update(stream.t[-1], A, p, bad_cov, f)
    with pytest.raises(CalibrationError, match="robot_factor.*NaN or inf"):
        engine.update(stream.t[-1], A, p, S, np.where(np.arange(f.size).reshape(f.shape) == 7, np.inf, f))
    with pytest.raises(CalibrationError, match="point_cam.*beyond"):
        engine.update(stream.t[-1], A, np.array([0.0, 0.0, 2e6]), S, f)
    assert engine.update(stream.t[-1], A, p, S, f).index == len(stream.t) + 1


def test_a_still_camera_raises_no_moved_alarm_and_stays_as_good_as_its_calibration():
    shift = dataclasses.replace(simulate.Shift(), hours=3.0, bumps=())
    run = bench_shift.run_seed(1, shift, MonitorSettings(), PROFILE)
    assert not [i for i, kind in run.alarms if kind == "moved"]
    assert np.percentile(run.error_mm, 95) <= run.bound_mm
    # The stated covariance matches the error (NEES of 6 dof, loose: one seed, correlated samples).
    assert 2.0 < np.mean(run.nees) < 12.0


def test_the_noise_level_follows_the_innovations_and_weighs_what_the_samples_add():
    """Production points twice as noisy (1-sigma) as the arming's level: the tracked noise scale follows (about 4,
    the variance's ratio), and the stated 1-sigma does not shrink below that of a twin fed the arming's level."""
    real, res, engine = _armed(1)
    twin = _armed(1)[2]
    stream = simulate.shift_stream(real, dataclasses.replace(simulate.Shift(), hours=2.0, bumps=()),
                                   np.random.default_rng([1, 1]), PROFILE)
    F = PROFILE.dh_error_factor(stream.q)
    rng = np.random.default_rng(9)
    last = twin_last = None
    for i in range(len(stream.t)):
        noisy = stream.points[i] + rng.multivariate_normal(np.zeros(3), 3.0 * stream.point_cov[i])
        last = engine.update(stream.t[i], stream.A[i], noisy, stream.point_cov[i], F[i]).sigma_mm
        twin_last = twin.update(stream.t[i], stream.A[i], stream.points[i], stream.point_cov[i], F[i]).sigma_mm
    assert 2.0 < engine.filter.scale < 8.0
    assert 0.4 < twin.filter.scale < 2.0
    assert last > twin_last


@pytest.mark.parametrize("setup", [Setup.EYE_TO_HAND, Setup.EYE_IN_HAND])
def test_repeated_visits_of_the_same_stops_do_not_make_the_estimate_overconfident(setup):
    """Two days of a 4-stop program from a pose-only source (no joints): each stop repeats its own robot error
    (0.4 mm beyond the DH error, which without joints repeats too) at every visit, and the mount breathes 1 mm a
    day. The stated 1-sigma keeps covering the live error over the workspace (mean (error / sigma)^2 near 1, not
    the 5-80 of a filter that takes each visit as independent news), and the camera correction, which four stops
    cannot separate from the camera's pose, stays within 3 sigma of the arming's."""
    from handeye.calib.simulate_month import Month, month_stream

    rng = np.random.default_rng([7, int(setup == Setup.EYE_TO_HAND)])
    prof = dataclasses.replace(PROFILE, pose_error_m=0.4e-3)
    real = simulate.realistic_profile(30, rng, prof, setup=setup)
    d = real.data
    problem = CalibrationProblem.from_arrays(d.A, d.points, setup=setup, point_cov=d.point_cov)
    res = solve("auto", problem, rng=rng)
    engine = MonitorEngine()
    engine.arm(res, problem)
    theta0, theta_sd = engine.filter.u[3:6].copy(), np.sqrt(np.diag(engine.filter.P)[9:12])
    m = month_stream(real, Month(days=2.0, stop_error_m=0.4e-3, thermal_mm=1.0, bumps=()), rng, prof)
    P = simulate.workspace_points(real, 100, rng)
    ratio, wander = [], 0.0
    for i in range(len(m.t)):
        upd = engine.update(m.t[i], m.A_stops[m.stop[i]], m.points[i], m.point_cov[i])
        assert not upd.alarm == "moved"
        if i % 20 == 0 and m.t[i] > 86400.0:
            err = bench_shift.workspace_error(upd.camera_transform, engine.camera_correction, real.camera, m.C[i], P)
            ratio.append((err * 1e3 / upd.sigma_mm) ** 2)
            wander = max(wander, float(np.max(np.abs(engine.filter.u[3:6] - theta0) / theta_sd)))
    assert 0.2 < np.mean(ratio) < 2.5
    assert wander < 3.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_still_camera_is_not_drifting(seed):
    """No drift, no bumps, 8 hours of 4 stops: the production stops refine the arming calibration by 1-2 mm over
    the workspace in the first half hour, which is no drift; the drift figure (the camera's walk since the
    calibration in use) stays small and no *drifting* alarm is raised."""
    shift = dataclasses.replace(simulate.Shift(), bumps=(), drift_mm_h=0.0)
    real, res, engine = _armed(seed)
    stream = simulate.shift_stream(real, shift, np.random.default_rng([seed, 1]), PROFILE)
    F = PROFILE.dh_error_factor(stream.q)
    ups = [engine.update(stream.t[i], stream.A[i], stream.points[i], stream.point_cov[i], F[i])
           for i in range(len(stream.t))]
    assert not engine.alarms
    assert max(u.drift_mm for u in ups) < engine.settings.tolerance_mm


def test_a_bump_is_flagged_and_relearnt_from_the_production_stops_alone():
    shift = dataclasses.replace(simulate.Shift(), hours=2.0, bumps=((1.0, 5.0, 0.3),))
    run = bench_shift.run_seed(2, shift, MonitorSettings(), PROFILE)
    s = bench_shift.summarize(run)
    assert s["false"] == 0
    assert s["delays"][0] is not None and s["delays"][0] <= bench_shift.DETECT_WITHIN
    assert s["recovery"][0] is not None and s["recovery"][0] <= bench_shift.RECOVER_WITHIN
    after = run.bumped[0] + bench_shift.RECOVER_WITHIN
    assert np.percentile(run.error_mm[after:], 95) <= run.bound_mm


@pytest.mark.parametrize("seed", [2, 4])
def test_a_second_knock_while_the_relearnt_camera_settles_is_flagged(seed):
    """Two 5 mm / 0.3 deg knocks 10 samples apart: the second comes while the first's re-learnt camera settles (its
    stops have no baselines yet), and is flagged as a move of its own within 20 samples, not taken in silently."""
    shift = dataclasses.replace(simulate.Shift(), hours=2.5, bumps=((2.0, 5.0, 0.3), (2.0 + 10 * 30 / 3600 + 1e-6,
                                                                                      5.0, 0.3)))
    cell = bench_shift.seed_cell(seed, shift, MonitorSettings())
    engine, stream = cell.engine, cell.stream
    F = cell.profile.dh_error_factor(stream.q)
    second = stream.bumped[1]
    moved, state = [], None
    for i in range(len(stream.t)):
        if i == second:
            state = engine.state
        if engine.update(stream.t[i], stream.A[i], stream.points[i], stream.point_cov[i], F[i]).alarm == "moved":
            moved.append(i)
    assert state == "settling"
    assert len(moved) == 2 and 0 <= moved[1] - second <= bench_shift.DETECT_WITHIN, (moved, second)


def test_slow_drift_is_followed_and_its_rate_reported():
    shift = dataclasses.replace(simulate.Shift(), hours=3.0, bumps=(), drift_mm_h=2.0)
    real, res, engine = _armed(3, MonitorSettings(walk_mm_per_sqrt_h=2.0))
    stream = simulate.shift_stream(real, shift, np.random.default_rng([3, 1]), PROFILE)
    F = PROFILE.dh_error_factor(stream.q)
    ups = [engine.update(stream.t[i], stream.A[i], stream.points[i], stream.point_cov[i], F[i])
           for i in range(len(stream.t))]
    assert not [u for u in ups if u.alarm == "moved"]
    # 6 mm of drift by the end: the arming calibration is off by about that over the workspace, the live one is not.
    P = simulate.workspace_points(real, 100, np.random.default_rng(0))
    held = bench_shift.workspace_error(res.Y, res.camera_correction, real.camera, stream.Y[-1], P)
    live = bench_shift.workspace_error(ups[-1].camera_transform, engine.camera_correction, real.camera,
                                       stream.Y[-1], P)
    assert held > 4e-3
    assert live < 0.5 * held
    assert 1.0 < ups[-1].drift_rate_mm_h < 3.5
    # Heading for the 2 mm tolerance: a drifting alarm, with the time left.
    drifting = [u for u in ups if u.alarm == "drifting"]
    assert drifting and "tolerance" in drifting[0].message


@pytest.mark.parametrize("seed", [0, 1, 5])
def test_the_stops_baselines_follow_a_drifting_camera(seed):
    """A mount drifting 2 mm/h (four times the default walk's hour) for 4 hours, no bump: each stop's baseline
    (its last visits' mean) is carried along the walk the filter followed since them, so the *moved* test's
    short window stays near its 6 degrees of freedom and raises no alarm (against raw baselines it averaged
    11-18 and alarmed on seeds 1 and 5)."""
    shift = dataclasses.replace(simulate.Shift(), hours=4.0, bumps=(), drift_mm_h=2.0)
    real, res, engine = _armed(seed)
    stream = simulate.shift_stream(real, shift, np.random.default_rng([seed, 1]), PROFILE)
    F = PROFILE.dh_error_factor(stream.q)
    short = []
    for i in range(len(stream.t)):
        upd = engine.update(stream.t[i], stream.A[i], stream.points[i], stream.point_cov[i], F[i])
        assert upd.alarm != "moved", (i, upd.message)
        short.append(engine.detector.statistics[0])
    assert np.mean(short[100:]) < 10.0


def test_a_three_stop_program_is_monitored_all_shift():
    """Three stops (the fewest that determine the camera) for 8 hours: each of the three bumps is flagged and
    re-learnt from those stops alone, and the engine is watching again after each."""
    shift = dataclasses.replace(simulate.Shift(), stops=3)
    run = bench_shift.run_seed(0, shift, MonitorSettings(), PROFILE)
    s = bench_shift.summarize(run)
    assert s["false"] == 0
    assert all(d is not None and d <= bench_shift.DETECT_WITHIN for d in s["delays"]), s["delays"]
    assert all(r is not None and r <= bench_shift.RECOVER_WITHIN for r in s["recovery"]), s["recovery"]
    assert s["p95"] <= s["bound"]


def test_stops_that_repeat_only_roughly_are_no_move():
    """A program whose stops are a little different at each visit (every joint 0.5 deg off, about 1 cm at the
    tool: vision-guided picks): the stop's earlier visits are carried to this visit's pose by the model, so the
    difference is no move (the raw point comparison raised 16-17 false alarms per 8-hour shift), and a bump is
    still flagged and re-learnt."""
    shift = dataclasses.replace(simulate.Shift(), hours=3.0, bumps=((2.0, 5.0, 0.3),), stop_jitter_deg=0.5)
    run = bench_shift.run_seed(1, shift, MonitorSettings(), PROFILE)
    s = bench_shift.summarize(run)
    assert s["false"] == 0, run.alarms
    assert s["delays"][0] is not None and s["delays"][0] <= bench_shift.DETECT_WITHIN
    assert s["recovery"][0] is not None and s["recovery"][0] <= bench_shift.RECOVER_WITHIN


def test_a_compressed_clock_gives_the_same_shift():
    """A simulation run 30x faster than its world (samples stamped with the wall clock) with ``time_scale=30``
    is the same shift to the engine: same states, alarms and estimates, drift rates per world hour."""
    shift = dataclasses.replace(simulate.Shift(), hours=3.0, bumps=((1.5, 5.0, 0.3),), drift_mm_h=1.0)
    real, res, engine = _armed(2)
    fast = _armed(2, MonitorSettings(time_scale=30.0))[2]
    stream = simulate.shift_stream(real, shift, np.random.default_rng([2, 1]), PROFILE)
    F = PROFILE.dh_error_factor(stream.q)
    for i in range(len(stream.t)):
        a = engine.update(stream.t[i], stream.A[i], stream.points[i], stream.point_cov[i], F[i])
        b = fast.update(stream.t[i] / 30.0, stream.A[i], stream.points[i], stream.point_cov[i], F[i])
        assert (a.state, a.alarm) == (b.state, b.alarm)
        np.testing.assert_allclose(b.camera_transform, a.camera_transform, atol=1e-9)
        assert (a.drift_rate_mm_h is None) == (b.drift_rate_mm_h is None)
        if a.drift_rate_mm_h is not None:
            assert b.drift_rate_mm_h == pytest.approx(a.drift_rate_mm_h, rel=1e-6)
    assert [kind for _, _, kind in engine.alarms] == [kind for _, _, kind in fast.alarms]
    assert "moved" in [kind for _, _, kind in engine.alarms]


def test_two_stops_cannot_relearn_and_say_so():
    real, res, engine = _armed(4)
    shift = dataclasses.replace(simulate.Shift(), hours=1.0, stops=2, bumps=((0.5, 10.0, 0.5),))
    stream = simulate.shift_stream(real, shift, np.random.default_rng([4, 1]), PROFILE)
    F = PROFILE.dh_error_factor(stream.q)
    ups = [engine.update(stream.t[i], stream.A[i], stream.points[i], stream.point_cov[i], F[i])
           for i in range(len(stream.t))]
    moved = [u for u in ups if u.alarm == "moved"]
    assert len(moved) == 1
    assert ups[-1].state == "relearning" and ups[-1].level == "moved"
    assert "2 distinct stops" in ups[-1].message and "3 not on one line" in ups[-1].message


def test_bad_samples_are_refused_without_changing_the_state():
    real, res, engine = _armed(5)
    d = real.data
    before = engine.camera_transform, engine.cov
    F = PROFILE.dh_error_factor(real.q[:1])[0]
    with pytest.raises(CalibrationError, match="point_cam"):
        engine.update(1.0, d.A[0], [np.nan, 0.0, 0.8], None, F)
    with pytest.raises(CalibrationError, match="robot_factor"):
        engine.update(1.0, d.A[0], d.points[0], None, None)
    with pytest.raises(CalibrationError, match="T_base_flange"):
        engine.update(1.0, np.eye(3), d.points[0], None, F)
    np.testing.assert_array_equal(engine.camera_transform, before[0])
    np.testing.assert_array_equal(engine.cov, before[1])
    with pytest.raises(CalibrationError, match="not armed"):
        MonitorEngine().update(0.0, d.A[0], d.points[0])


def test_state_stays_bounded_over_a_shift():
    real, res, engine = _armed(6)
    stream = simulate.shift_stream(real, dataclasses.replace(simulate.Shift(), hours=2.0),
                                   np.random.default_rng([6, 1]), PROFILE)
    F = PROFILE.dh_error_factor(stream.q)
    sizes = []
    for i in range(len(stream.t)):
        engine.update(stream.t[i], stream.A[i], stream.points[i], stream.point_cov[i], F[i])
        sizes.append(engine.state_size)
    assert max(sizes[60:]) <= 1.5 * sizes[60]


@pytest.mark.parametrize("jitter_deg", [0.0, 0.5])
def test_eye_in_hand_camera_slipping_on_the_flange_is_flagged_and_relearnt(jitter_deg):
    """Eye-in-hand: C = T_flange_cam is followed, the base-marker pose is held; the camera slips at sample 100.
    With ``jitter_deg`` each visit of a stop is turned that much (1-sigma per axis) and shifted that angle
    times 1 m: stops that repeat only roughly (the raw point comparison raised 12-20 false alarms per shift)."""
    rng = np.random.default_rng(8)
    d = simulate.realistic_cell(34, rng, setup=Setup.EYE_IN_HAND)
    problem = CalibrationProblem.from_arrays(d.A[:30], d.points[:30], setup=Setup.EYE_IN_HAND,
                                             point_cov=d.point_cov[:30])
    res = solve("auto", problem, rng=rng)
    engine = MonitorEngine()
    engine.arm(res, problem)
    stops = d.A_true[30:34]
    slip = tf.from_rotvec_translation([0.0, 0.0, np.deg2rad(0.5)], [0.006, -0.004, 0.0])
    ups, truth = [], []
    for i in range(200):
        A = stops[i % 4]
        if jitter_deg:
            jitter = np.deg2rad(jitter_deg)
            A = A @ tf.from_rotvec_translation(rng.normal(scale=jitter, size=3), rng.normal(scale=jitter, size=3))
        X = d.X if i < 100 else d.X @ slip                     # T_flange_cam
        p_true = tf.transform_points(tf.invert(A @ X) @ d.Y, np.zeros(3))
        cov = simulate.point_covariance(p_true[None], 0.001, 0.003)[0]
        p = p_true + np.linalg.cholesky(cov) @ rng.normal(size=3)
        ups.append(engine.update(30.0 * i, A, p, cov))
        truth.append(X)
    moved = [i for i, u in enumerate(ups) if u.alarm == "moved"]
    assert moved and 100 <= moved[0] <= 120 and all(i >= 100 for i in moved)
    assert ups[0].camera_transform.shape == (4, 4) and engine.result().setup == Setup.EYE_IN_HAND
    rot, trans = tf.pose_error(ups[-1].camera_transform, truth[-1])
    assert trans < 3e-3 and np.rad2deg(rot) < 0.3, (trans, np.rad2deg(rot))
    # The held base-marker pose is the arming one.
    np.testing.assert_allclose(engine.result().Y[:3, :3], res.Y[:3, :3])


def _real_stream_alarms(shared: bool) -> tuple[list, float, float]:
    """The ETH SR300 stream (tests/data/ethz/robot_arm, eye-in-hand, the camera never moved): the engine armed
    by ``auto`` from the first half, the second half one sample a second (poses 7-18 cm apart, as a robot's
    stops would be). Returns its *moved* alarms, the arming's shared error variance (m^2 per axis) and the
    largest test statistic."""
    from pathlib import Path

    from bench.crosssession import spaced
    from handeye.app.formats import load

    obs = load(Path(__file__).parents[1] / "data" / "ethz" / "robot_arm").observations
    first, second = obs[:len(obs) // 2], obs[len(obs) // 2:]
    problem = CalibrationProblem.from_observations(first, Setup.EYE_IN_HAND)
    engine = MonitorEngine()
    ref = engine.arm(solve("auto", problem), problem, t=first[-1].t)
    if not shared:
        engine.detector.shared_var = 0.0
    updates = [engine.update(o.t, o.T_base_flange, o.point_cam, o.point_cov) for o in spaced(second, 1.0)]
    return [k for k, u in enumerate(updates) if u.alarm == "moved"], ref.shared_var, max(u.statistic for u in updates)


def test_a_real_recording_of_a_still_camera_raises_no_moved_alarm():
    """Real errors are not white: nearby poses share the calibration's systematic error (here the held-out
    stretches of the arming half are predicted 3.69 mm against 3.44 mm for single samples, 0.77 mm per axis
    shared). Marginalised, the *moved* test stays quiet over the other half; taken as white it raised a
    false alarm 4 samples in (2026-12-02)."""
    alarms, shared_var, statistic = _real_stream_alarms(shared=True)
    assert alarms == []
    assert 0.5e-3 < np.sqrt(shared_var) < 1.0e-3
    # Taken as white the largest statistic is 35 against 21 (threshold 40; 42 and an alarm when a visit added the
    # point noise alone).
    assert _real_stream_alarms(shared=False)[2] > 1.5 * statistic


@pytest.mark.parametrize("gap_h", [0.0, 10.0])
def test_a_run_continued_from_the_last_raises_no_alarm_for_a_bump_it_has_relearnt(gap_h):
    """A 4-hour shift bumped at 1 h and split at 2 h into two runs (the second after ``gap_h`` hours, as the next
    shift): armed from the first run's snapshot (through its file form) the second raises no moved alarm and keeps
    the live estimate within the bound; armed again from the original calibration, what it sees at once is the
    camera away from that calibration (a moved or, as the filter takes the first samples for its refinement, a
    drifting alarm) and its error over the workspace is larger.

    The bump is 8 mm / 0.5 deg: a fresh engine has no stop visited before to compare with, only the calibration,
    whose own uncertainty (2 mm over the workspace) and the stops' own errors leave a 5 mm / 0.3 deg offset at the
    edge of what its first 20 samples can tell (GLR 41.1 with a 0.3 mm stop error, 37.7 with 0.5, threshold 39.8)."""
    from handeye.calib.monitor.snapshot import snapshot_from_dict, snapshot_to_dict

    shift = dataclasses.replace(simulate.Shift(), hours=4.0, bumps=((1.0, 8.0, 0.5),))
    real, res, engine = _armed(3)
    stream = simulate.shift_stream(real, shift, np.random.default_rng([3, 1]), PROFILE)
    F = PROFILE.dh_error_factor(stream.q)
    P = simulate.workspace_points(real, 100, np.random.default_rng(0))
    split = len(stream.t) // 2
    first = [engine.update(stream.t[i], stream.A[i], stream.points[i], stream.point_cov[i], F[i]).alarm
             for i in range(split)]
    assert first.count("moved") == 1
    snapshot = snapshot_from_dict(snapshot_to_dict(engine.snapshot()))
    carried, again = MonitorEngine(), _armed(3)[2]
    t0 = stream.t[split] + gap_h * 3600.0
    carried.resume(snapshot, t=t0)
    arming = bench_shift.workspace_error(res.Y, res.camera_correction, real.camera, real.data.Y, P)
    errors, errors_again, alarms, alarms_again = [], [], [], []
    for i in range(split, len(stream.t)):
        t = stream.t[i] + gap_h * 3600.0
        upd = carried.update(t, stream.A[i], stream.points[i], stream.point_cov[i], F[i])
        alarms.append(upd.alarm)
        errors.append(bench_shift.workspace_error(upd.camera_transform, carried.camera_correction, real.camera,
                                                  stream.Y[i], P))
        up2 = again.update(t, stream.A[i], stream.points[i], stream.point_cov[i], F[i])
        alarms_again.append(up2.alarm)
        errors_again.append(bench_shift.workspace_error(up2.camera_transform, again.camera_correction, real.camera,
                                                        stream.Y[i], P))
    assert "moved" not in alarms
    assert not any(alarms[:20])
    assert np.percentile(errors, 95) <= max(1e-3, 1.5 * arming)
    assert any(alarms_again[:20])
    assert np.mean(errors_again[:20]) > 1.5 * np.mean(errors[:20])
    assert carried.relearns == 1 and carried.moved_since(carried.origin)[0] > 2.0


def test_a_calibration_that_leaves_the_camera_open_does_not_arm():
    """A recording whose tool never turned leaves the marker's offset and the camera's position unseparated
    (`CalibrationResult.undetermined`): held at a guess, the production's other tool orientations would read as a
    move, so the engine refuses it with the reason and the fix."""
    d = simulate.realistic_cell(30, np.random.default_rng(4), angle_range=0.0)
    problem = CalibrationProblem.from_arrays(d.A, d.points, point_cov=d.point_cov)
    res = solve("auto", problem, rng=np.random.default_rng(4))
    assert res.undetermined
    with pytest.raises(CalibrationError, match="leaves part of the camera open.*marker-offset"):
        MonitorEngine().arm(res, problem)


def test_more_stops_than_slots_reuse_the_least_recently_visited_and_the_state_stays_sound():
    """A program of 40 stops (more than `STOP_SLOTS`) visited in turn: the state grows by a slot per new stop up
    to `STOP_SLOTS`, then each new stop takes the slot of the least recently visited one, whose error is
    marginalised; the state stays sound and no moved alarm is raised on a still camera."""
    from handeye.calib.monitor.filter import STOP_SLOTS, Layout, is_sound

    real, res, engine = _armed(2)
    n_factor = engine.n_factor
    stream = simulate.shift_stream(real, dataclasses.replace(simulate.Shift(), hours=1.0, bumps=(), stops=40,
                                                             drift_mm_h=0.0), np.random.default_rng([2, 1]), PROFILE)
    F = PROFILE.dh_error_factor(stream.q)
    alarms = []
    for i in range(len(stream.t)):
        alarms.append(engine.update(stream.t[i], stream.A[i], stream.points[i], stream.point_cov[i], F[i]).alarm)
        f = engine.filter
        assert len(f.slots) == len(f.last) == min(i + 1, STOP_SLOTS)
        assert f.P.shape == (Layout(n_factor, len(f.slots)).size,) * 2
        # the slot of this sample's stop was visited now, and is the most recent
        assert max(f.last) == f.last[f.slots.index(tuple(stream.A[i][:3].ravel().tolist()))]
    assert is_sound(engine.filter)
    assert "moved" not in alarms
    # the held stops are the last `STOP_SLOTS` visited
    recent = {tuple(stream.A[i][:3].ravel().tolist()) for i in range(len(stream.t) - STOP_SLOTS, len(stream.t))}
    assert {pose for pose in engine.filter.slots} == recent


def test_a_snapshot_carries_no_stop_errors_and_the_next_run_learns_them_again():
    """The stops' own errors are marginalised in the snapshot (its file form keeps its layout), and a run resumed
    from it holds none until it visits the stops again."""
    from handeye.calib.monitor.filter import Layout
    from handeye.calib.monitor.snapshot import snapshot_from_dict, snapshot_to_dict

    real, res, engine = _armed(1)
    stream = simulate.shift_stream(real, dataclasses.replace(simulate.Shift(), hours=0.5, bumps=()),
                                   np.random.default_rng([1, 1]), PROFILE)
    F = PROFILE.dh_error_factor(stream.q)
    for i in range(len(stream.t)):
        engine.update(stream.t[i], stream.A[i], stream.points[i], stream.point_cov[i], F[i])
    doc = snapshot_to_dict(engine.snapshot())
    n_factor = engine.n_factor
    assert len(doc["filter"]["state"]) == 12 + n_factor
    back = snapshot_from_dict(doc)
    layout, held = Layout(n_factor), Layout(n_factor, len(engine.filter.slots))
    assert len(engine.filter.slots) > 0 and back.filter.slots == ()
    assert back.filter.P.shape == (layout.size, layout.size)
    kept = np.r_[0:held.model, held.walk:held.size]
    np.testing.assert_allclose(back.filter.P, engine.filter.P[np.ix_(kept, kept)])
    again = MonitorEngine()
    again.resume(back, t=stream.t[-1] + 30.0)
    assert again.filter.slots == ()
    upd = again.update(stream.t[-1] + 30.0, stream.A[0], stream.points[0], stream.point_cov[0], F[0])
    assert len(again.filter.slots) == 1 and upd.alarm != "moved"


def test_the_walk_is_followed_only_where_the_stops_observe_it():
    """`observed_walk`: with stops that observe every direction well the walk is the whole random walk; where one
    visit of each stop tells nothing of a direction (here: a turn about the line of sight traded against a shift),
    the walk has no variance along it."""
    from handeye.calib.monitor.filter import observed_walk

    q = np.array([1e-10] * 3 + [1e-10] * 3)
    strong = np.eye(6) * 1e12
    np.testing.assert_allclose(observed_walk(q, strong, 3600.0), np.diag(q), rtol=1e-9, atol=1e-25)
    blind = np.r_[1.0, 0.0, 0.0, 0.0, -0.8, 0.0] / np.hypot(1.0, 0.8)
    info = 1e12 * (np.eye(6) - np.outer(blind, blind))
    Q = observed_walk(q, info, 3600.0)
    assert abs(blind @ Q @ blind) < 1e-6 * q[0]
    assert np.linalg.matrix_rank(Q, tol=1e-6 * q[0]) == 5
    assert not observed_walk(q, np.zeros((6, 6)), 3600.0).any()


def test_an_update_that_diverges_is_a_typed_error_and_the_state_is_kept():
    """An increment that is not finite (a sample far outside what the linearised model holds) raises
    `FilterDivergedError`, a `CalibrationError` the run loops log as a skipped sample, not a ValueError traceback
    from the rotation's exponential; the engine's state is what it was."""
    from handeye.calib.errors import FilterDivergedError
    from handeye.calib.monitor.filter import fuse

    real, res, engine = _armed(1)
    before = engine.filter
    n = before.P.shape[0]
    PHt = np.zeros((n, 3))
    PHt[0, 0] = 1.0
    with pytest.raises(FilterDivergedError) as e, np.errstate(all="ignore"):   # (inf x 0 in the gain's product)
        fuse(before, PHt, np.eye(3), np.array([np.inf, 0.0, 0.0]))
    assert isinstance(e.value, CalibrationError) and "sample skipped" in str(e.value)
    assert engine.filter is before and np.all(np.isfinite(before.C))


@pytest.mark.parametrize("run", ["run1", "run2"])
def test_the_demo_cell_is_one_moved_alarm_for_its_one_bump(run):
    """The demo's recording (tests/data/demo_monitor: a 10 mm / 0.5 deg bump after sample 15, 14 stops visited in
    turn), the engine armed from its first 12 samples as the demo arms itself. Their noise split put the noise on
    the robot (a 0.04 point scale, 0.17 mm on an exact arm); when a visit added the point noise alone, the stops of
    the re-learnt camera, visited again, read NIS 16-29 and raised two false moved alarms (run1, samples 34 and 44);
    when the noise scale followed samples the state dominates in full, it fell to 0.28 and run2 raised one at 36.
    The alarm comes within the first three samples after the bump: the demo's robot error is not in the state (its
    arming has no kinematic error), so each stop's prior holds a shared 1 mm robot error, and its stops, all new,
    are tested against the model with what their neighbours told of their error allowed for: run1's tell the
    knock at sample 18 (17 without that allowance, 16 before that prior)."""
    from pathlib import Path

    from handeye.app.monitoring import arm_engine
    from handeye.app.session import read_session

    session = read_session(Path(__file__).parents[1] / "data" / "demo_monitor" / run)
    obs = [o for o in session.observations if o.point_cam is not None]
    engine = MonitorEngine()
    arm_engine(engine, obs[:12], Setup(session.setup), t=obs[11].t)
    assert engine.reference.noise.point_scale < 0.1
    updates = [(o.index, engine.update(o.t, o.T_base_flange, o.point_cam, o.point_cov)) for o in obs[12:]]
    assert [i for i, u in updates if u.alarm == "moved"] in ([16], [17], [18])
    relearnt = [i for i, u in updates if u.message.startswith("re-learnt")]
    assert len(relearnt) == 1 and relearnt[0] <= 21
    assert updates[-1][1].state == EngineState.ARMED


@pytest.mark.parametrize("seed", [1, 4])
def test_a_second_knock_while_the_first_is_re_learnt_is_its_own_alarm(seed):
    """A 14-stop program (the re-learn registers the camera from 6 samples), knocked at sample 20 and again 3
    samples after the alarm, while the re-learn still gathers samples: the samples since the first alarm do not fit
    the camera the newest show, which is the second knock's own alarm (before: one alarm, the second knock taken
    silently into the re-learn), and the camera is re-learnt from after it."""
    rng = np.random.default_rng([seed, 77])
    cell = simulate.production_cell(Setup.EYE_TO_HAND, 30, 14, rng, joints=False)
    problem = CalibrationProblem.from_arrays(cell.A, cell.points, setup=Setup.EYE_TO_HAND, point_cov=cell.point_cov)
    engine = MonitorEngine()
    result = solve("auto", problem, rng=np.random.default_rng(seed))
    engine.arm(result, problem)
    P = simulate.workspace_points(cell.real, 100, np.random.default_rng(0))
    arming = bench_shift.workspace_error(result.Y, result.camera_correction, cell.real.camera, cell.C, P)
    C, alarms, messages, second = cell.C, [], [], None
    for k in range(80):
        if k == 20 or (alarms and second is None and k == alarms[0] + 3):
            second = None if k == 20 else k
            first = C
            C = cell.moved(C, np.deg2rad(0.5) * simulate.random_directions(1, rng)[0],
                           0.01 * simulate.random_directions(1, rng)[0])
        s = cell.sample(k % 14, C, rng)
        upd = engine.update(30.0 * k, s.A, s.point, s.point_cov)
        if upd.alarm == "moved":
            alarms.append(k)
            messages.append(upd.message)
    assert len(alarms) == 2 and alarms[0] < second < alarms[1] <= second + 10, alarms
    assert messages[1].startswith("camera moved again while re-learning"), messages[1]
    assert upd.state == EngineState.ARMED
    # Re-learnt from after the second knock: over the workspace the live camera is the camera since then, within
    # what the arming itself was good for.
    error = [bench_shift.workspace_error(engine.camera_transform, engine.camera_correction, cell.real.camera, T, P)
             for T in (C, first, cell.C)]
    assert error[0] < 2 * arming and error[0] < 0.5 * min(error[1:]), (np.array(error) * 1e3, arming * 1e3)


@pytest.mark.parametrize("n_stops", [4, 8])
def test_a_wild_point_while_re_learning_is_dropped_not_a_traceback(n_stops):
    """A cell with the robot's kinematic error in the state, bumped by 0.9 deg; while it re-learns, one marker
    point 50x too far (a depth glitch) joins the samples since the move. Fused, it drove the kinematic error to
    1e13 sigma and the next Jacobian to a singular noise: LinAlgError or a math domain error on 9 of 12 such cells
    (issue 39's versions state machine found it). Now the fit that holds it is no fit, the point leaves with the
    oldest samples, and the camera is re-learnt from the others."""
    rng = np.random.default_rng([0, 3])
    cell = simulate.production_cell(Setup.EYE_TO_HAND, 30, n_stops, rng, joints=True)
    problem = CalibrationProblem.from_arrays(cell.A, cell.points, setup=Setup.EYE_TO_HAND, point_cov=cell.point_cov,
                                             robot_shared_error=cell.factor)
    engine = MonitorEngine()
    engine.arm(solve("auto", problem, rng=np.random.default_rng(0)), problem)
    C, wild, alarms = cell.C, None, []
    for k in range(60):
        if k == 10:
            C = cell.moved(C, np.deg2rad(0.9) * simulate.random_directions(1, rng)[0], np.zeros(3))
        s = cell.sample(k % n_stops, C, rng)
        point = s.point
        if engine.state == EngineState.RELEARNING and wild is None:
            point, wild = point * 50.0, k
        upd = engine.update(30.0 * k, s.A, point, s.point_cov, s.factor)
        alarms += [k] * (upd.alarm == "moved")
    assert wild is not None and len(alarms) == 1 and alarms[0] < wild
    assert upd.state == EngineState.ARMED and np.all(np.isfinite(engine.filter.P))


def test_a_stop_opened_beside_held_ones_takes_its_share_of_their_prior(monkeypatch):
    """`open_slot` with ``shared``: three stops whose errors have a joint prior ``K`` (9, 9), opened one after the
    other, each regressed on those held before it and no sample in between, give the state exactly ``K`` over
    their slots and leave the rest alone. With two slots, the third takes the least recently visited one and is
    regressed on the other: the state holds that pair's prior."""
    from handeye.calib.monitor import filter as mf

    rng = np.random.default_rng(5)
    layout = mf.Layout(0)
    L = rng.normal(size=(layout.size, layout.size))
    P0 = 1e-6 * L.dot(L.T)
    start = mf.filter_state(np.eye(4), rng.normal(size=layout.size - 6), P0, 0.0)
    M = rng.normal(size=(9, 9))
    K = 1e-6 * (M.dot(M.T) + np.eye(9))
    poses = [tuple(float(x) for x in rng.normal(size=12)) for _ in range(3)]

    def opened(state, n, held, slots):
        """The state with stop ``n`` opened, regressed on the stops ``held``, in ``slots``."""
        if not held:
            return mf.open_slot(state, poses[n], K[3 * n:3 * n + 3, 3 * n:3 * n + 3])
        cols = np.concatenate([3 * h + np.arange(3) for h in held])
        K_hh, K_nh = K[np.ix_(cols, cols)], K[3 * n:3 * n + 3, cols]
        G = np.linalg.solve(K_hh, K_nh.T).T
        return mf.open_slot(state, poses[n], K[3 * n:3 * n + 3, 3 * n:3 * n + 3] - G.dot(K_nh.T),
                            (G, slots))

    state = start
    for n in range(3):
        state, k = opened(state, n, list(range(n)), list(range(n)))
        assert k == n
        state = mf.visit_slot(state._replace(walk_t=float(n + 1)), k)
    held = mf.layout_of(state)
    b = slice(held.model, held.walk)
    np.testing.assert_allclose(state.P[b, b], K, rtol=1e-9, atol=1e-18)
    assert not state.P[b, :held.model].any() and not state.P[b, held.walk:].any()
    rest = np.r_[0:held.model, held.walk:held.size]
    np.testing.assert_allclose(state.P[np.ix_(rest, rest)], P0)
    assert mf.is_sound(state)

    monkeypatch.setattr(mf, "STOP_SLOTS", 2)
    state = start
    for n in range(2):
        state, _ = opened(state, n, list(range(n)), list(range(n)))
        state = mf.visit_slot(state._replace(walk_t=float(n + 1)), n)
    assert mf.next_slot(state) == 0
    state, k = opened(state, 2, [1], [1])
    assert k == 0 and state.slots == (poses[2], poses[1])
    held = mf.layout_of(state)
    b = slice(held.model, held.walk)
    pair = np.r_[6:9, 3:6]
    np.testing.assert_allclose(state.P[b, b], K[np.ix_(pair, pair)], rtol=1e-9, atol=1e-18)
    assert mf.is_sound(state)
