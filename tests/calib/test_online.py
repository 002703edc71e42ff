"""Online calibrator and change detector (calib.online)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib import simulate
from calib import transforms as tf
from calib.errors import CalibrationError, ParameterError
from calib.online import ChangeDetector, DetectorConfig, OnlineCalibrator, OnlineConfig
from calib.refine import nees


def moved_stream(n_before, n_after, bump, rng):
    """Realistic eye-to-hand cell whose camera moves by ``bump`` (T_camold_camnew) after ``n_before`` samples."""
    d = simulate.realistic_cell(n_before + n_after, rng)
    return d, simulate.moved_camera_points(d, n_before, bump)


def run(cal, A, pts, cov):
    return [cal.update(A[i], pts[i], cov[i]) for i in range(len(A))]


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_converges_to_truth_with_honest_covariance(setup):
    rng = np.random.default_rng(41)
    d = simulate.realistic_cell(600, rng, setup=setup)
    cal = OnlineCalibrator(OnlineConfig(setup=setup))
    ups = run(cal, d.A, d.points, d.point_cov)
    assert ups[5].camera_transform is None and ups[-1].camera_transform is not None
    truth = d.Y if setup == "eye_to_hand" else d.X
    rot, t = tf.pose_error(cal.camera_transform, truth)
    assert rot < np.deg2rad(0.1) and t < 0.002
    assert nees(cal.camera_transform, truth, cal.cov) < 22.5  # chi-square(6) 99.9%
    res = cal.result()
    assert res.method == "YKronT'+online" and res.n_samples == 600
    assert not any(u.alarm for u in ups)


@pytest.mark.parametrize("forgetting", [1.0, 0.98])
def test_nees_over_many_streams(forgetting):
    rng = np.random.default_rng(42)
    values = []
    for _ in range(25):
        d = simulate.realistic_cell(150, rng)
        cal = OnlineCalibrator(OnlineConfig(forgetting=forgetting))
        run(cal, d.A, d.points, d.point_cov)
        values.append(nees(cal.camera_transform, d.Y, cal.cov))
    assert 4.0 < np.mean(values) < 8.5


def test_state_size_does_not_grow():
    rng = np.random.default_rng(43)
    d = simulate.realistic_cell(400, rng)
    cal = OnlineCalibrator(OnlineConfig(forgetting=0.995))
    run(cal, d.A[:50], d.points[:50], d.point_cov[:50])
    size = cal.state_size
    run(cal, d.A[50:], d.points[50:], d.point_cov[50:])
    assert cal.state_size == size


@pytest.mark.parametrize("kind", ["translation", "rotation"])
def test_detects_camera_bump_within_20_samples(kind):
    rng = np.random.default_rng(44 if kind == "translation" else 45)
    for _ in range(5):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        if kind == "translation":
            bump = tf.make_transform(np.eye(3), 0.01 * axis)
        else:
            bump = tf.make_transform(Rotation.from_rotvec(np.deg2rad(0.5) * axis).as_matrix(), np.zeros(3))
        d, pts = moved_stream(200, 20, bump, rng)
        ups = run(OnlineCalibrator(), d.A, pts, d.point_cov)
        assert not any(u.alarm for u in ups[:200])
        assert any(u.alarm for u in ups[200:])


def test_no_false_alarm_on_long_unchanged_stream():
    rng = np.random.default_rng(46)
    d = simulate.realistic_cell(3000, rng)
    cal = OnlineCalibrator(OnlineConfig(forgetting=0.999))
    short, long = [], []
    for i in range(len(d.A)):
        assert not cal.update(d.A[i], d.points[i], d.point_cov[i]).alarm
        short.append(cal.detector.statistics[0])
        long.append(cal.detector.statistics[1])
    # Chi-square(6) in each window while nothing changes: mean 6.
    assert 4.5 < np.mean(short[200:]) < 7.5
    assert 4.5 < np.mean(long[200:]) < 7.5


def test_relearns_after_alarm():
    rng = np.random.default_rng(47)
    bump = tf.make_transform(np.eye(3), [0.0, 0.03, 0.0])
    d, pts = moved_stream(150, 250, bump, rng)
    cal = OnlineCalibrator()
    ups = run(cal, d.A, pts, d.point_cov)
    assert sum(u.alarm for u in ups) == 1
    rot, t = tf.pose_error(cal.camera_transform, d.Y @ bump)
    assert t < 0.003 and rot < np.deg2rad(0.2)


def test_default_noise_model_without_point_cov():
    rng = np.random.default_rng(48)
    d = simulate.realistic_cell(300, rng)
    cal = OnlineCalibrator()
    for i in range(300):
        cal.update(d.A[i], d.points[i])
    assert tf.pose_error(cal.camera_transform, d.Y)[1] < 0.003
    assert cal.result().info["noise_scale"] > 0


def test_bad_samples_raise_and_leave_state_alone():
    rng = np.random.default_rng(49)
    d = simulate.realistic_cell(40, rng)
    cal = OnlineCalibrator()
    run(cal, d.A, d.points, d.point_cov)
    before = cal.camera_transform
    bad = d.A[0].copy()
    bad[0, 0] = np.nan
    with pytest.raises(CalibrationError, match="NaN"):
        cal.update(bad, d.points[0], d.point_cov[0])
    with pytest.raises(CalibrationError, match="shape"):
        cal.update(d.A[0], d.points[0][:2])
    with pytest.raises(CalibrationError, match="rigid"):
        cal.update(2 * d.A[0], d.points[0])
    np.testing.assert_array_equal(cal.camera_transform, before)
    assert cal.n_samples == 40
    cal.reset()
    assert cal.camera_transform is None and cal.n_samples == 0


def test_config_validation_names_the_field():
    with pytest.raises(ParameterError, match="forgetting"):
        OnlineConfig(forgetting=1.5)
    with pytest.raises(ParameterError, match="setup"):
        OnlineConfig(setup="eye_on_hand")
    with pytest.raises(ParameterError, match="bootstrap"):
        OnlineConfig(bootstrap=3)
    with pytest.raises(ParameterError, match="window"):
        DetectorConfig(window=1)
    with pytest.raises(ParameterError, match="long_window"):
        DetectorConfig(window=20, long_window=10)


def test_detector_alone_is_chi_square_under_no_change():
    rng = np.random.default_rng(50)
    det = ChangeDetector(DetectorConfig(window=10, long_window=50))
    stats = []
    for _ in range(2000):
        H = rng.normal(size=(3, 6))
        det.update(rng.normal(size=3), np.eye(3), H)
        stats.append(det.statistics)
    stats = np.array(stats[50:])
    assert np.all((5.5 < stats.mean(axis=0)) & (stats.mean(axis=0) < 6.5))


@pytest.mark.parametrize("long_window", [None, 30])
def test_detector_window_sums_match_brute_force(long_window):
    """The running-sum windows give exactly the GLR of the last `window` / `long_window` innovations."""
    rng = np.random.default_rng(51)
    cfg = DetectorConfig(window=8, long_window=long_window)
    det = ChangeDetector(cfg)
    Hs, rs, Ss = [], [], []

    def brute(w):
        F = sum(H.T @ S @ H for H, S in zip(Hs[-w:], Ss[-w:]))
        g = sum(H.T @ S @ r for H, S, r in zip(Hs[-w:], Ss[-w:], rs[-w:]))
        return g @ np.linalg.solve(F, g)

    for k in range(120):
        H, r = rng.normal(size=(3, 6)), rng.normal(size=3) + (0.5 if k > 60 else 0.0)
        S_inv = np.linalg.inv(np.diag(rng.uniform(0.5, 2.0, size=3)))
        Hs.append(H), rs.append(r), Ss.append(S_inv)
        det.update(r, S_inv, H)
        if k >= 2:
            assert det.statistics[0] == pytest.approx(brute(cfg.window), rel=1e-6)
        if long_window is not None and k + 1 > cfg.window and (k + 1) % 4 == 0:
            assert det.statistics[1] == pytest.approx(brute(long_window), rel=1e-6)


@pytest.mark.parametrize("where", ["rotation inf", "translation nan", "point nan", "cov nan", "cov lower nan"])
def test_non_finite_sample_in_the_filter_raises_and_leaves_state_alone(where):
    rng = np.random.default_rng(52)
    d = simulate.realistic_cell(40, rng, setup="eye_in_hand")
    cal = OnlineCalibrator(OnlineConfig(setup="eye_in_hand", forgetting=0.99))
    run(cal, d.A, d.points, d.point_cov)
    before, cov_before = cal.camera_transform, cal.cov
    A, p, S = d.A[0].copy(), d.points[0].copy(), d.point_cov[0].copy()
    {"rotation inf": lambda: A.__setitem__((1, 2), np.inf), "translation nan": lambda: A.__setitem__((0, 3), np.nan),
     "point nan": lambda: p.__setitem__(2, np.nan), "cov nan": lambda: S.__setitem__((0, 1), np.nan),
     "cov lower nan": lambda: S.__setitem__((2, 1), np.nan)}[where]()
    with pytest.raises(CalibrationError, match="NaN or inf"):
        cal.update(A, p, S)
    np.testing.assert_array_equal(cal.camera_transform, before)
    np.testing.assert_array_equal(cal.cov, cov_before)
    assert cal.n_samples == 40
