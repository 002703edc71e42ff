"""The moved test of the monitoring engine: the windowed GLR change detector (handeye.calib.change)."""

import numpy as np
import pytest

from handeye.calib.change import ChangeDetector, DetectorConfig
from handeye.calib.errors import ParameterError


def test_config_validation_names_the_field():
    with pytest.raises(ParameterError, match="window"):
        DetectorConfig(window=1)
    with pytest.raises(ParameterError, match="long_window"):
        DetectorConfig(window=20, long_window=10)
    with pytest.raises(ParameterError, match="false_alarm_rate"):
        DetectorConfig(false_alarm_rate=0.5)


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


def test_long_window_test_is_for_a_move_beyond_a_shared_offset():
    """Innovations sharing one camera offset drawn from N(0, Q) (a drift since their baselines) inflate the
    plain GLR; with ``offset_var`` Q the long window's statistic is chi-square with 6 dof again."""
    rng = np.random.default_rng(52)
    q = np.full(6, 0.05)
    plain, shared = [], []
    for _ in range(300):
        a = ChangeDetector(DetectorConfig(window=5, long_window=40))
        b = ChangeDetector(DetectorConfig(window=5, long_window=40))
        offset = rng.normal(size=6) * np.sqrt(q)
        for _ in range(40):
            H = rng.normal(size=(3, 6))
            r = H @ offset + rng.normal(size=3)
            a.update(r, np.eye(3), H)
            b.update(r, np.eye(3), H, q)
        plain.append(a.statistics[1])
        shared.append(b.statistics[1])
    assert np.mean(plain) > 20.0
    assert 5.3 < np.mean(shared) < 6.7


def test_onset_is_the_change_point():
    """After a jump, `onset` counts the innovations since it (the change point within the short window)."""
    rng = np.random.default_rng(53)
    for since in (3, 8, 15):
        det = ChangeDetector(DetectorConfig(window=20, long_window=None))
        for k in range(60):
            H = rng.normal(size=(3, 6))
            r = rng.normal(size=3) + (H @ [0.0, 0.0, 0.0, 2.0, -1.5, 1.0] if k >= 60 - since else 0.0)
            det.update(r, np.eye(3), H)
        assert abs(det.onset() - since) <= 1


def test_an_error_the_window_shares_is_no_move_once_marginalised():
    """Innovations that share one random offset (variance s^2 per axis: a calibration's systematic error at
    nearby poses) besides their white noise: with ``shared_var = s^2`` the window statistic is chi-square
    with 6 dof, without it the offset reads as a move."""
    rng = np.random.default_rng(52)
    s2 = 4.0
    stats = {0.0: [], s2: []}
    for _ in range(400):
        b = rng.normal(scale=np.sqrt(s2), size=3)
        Hs = [rng.normal(size=(3, 6)) for _ in range(10)]
        rs = [b + rng.normal(size=3) for _ in range(10)]
        for var in stats:
            det = ChangeDetector(DetectorConfig(window=10, long_window=None))
            det.shared_var = var
            for H, r in zip(Hs, rs):
                det.update(r, np.eye(3), H)
            stats[var].append(det.statistic)
    assert 5.3 < np.mean(stats[s2]) < 6.7
    assert np.mean(stats[0.0]) > 12.0


def test_the_shared_error_term_matches_brute_force_and_skips_baseline_innovations():
    """``g^T (F + s^2 G G^T)^-1 g`` with ``G`` summed over the innovations against the model only (an
    innovation against a pose's earlier visits has that error cancelled)."""
    rng = np.random.default_rng(53)
    det = ChangeDetector(DetectorConfig(window=6, long_window=None))
    det.shared_var = 0.7
    F, g, G = np.zeros((6, 6)), np.zeros(6), np.zeros((6, 3))
    for k in range(6):
        H, r = rng.normal(size=(3, 6)), rng.normal(size=3)
        S_inv = np.linalg.inv(np.eye(3) + 0.3 * np.diag(rng.random(3)))
        shared = k % 2 == 0
        det.update(r, S_inv, H, shared=shared)
        F += H.T @ S_inv @ H
        g += H.T @ S_inv @ r
        G += H.T @ S_inv if shared else 0.0
    assert det.statistic == pytest.approx(g @ np.linalg.solve(F + 0.7 * G @ G.T, g), rel=1e-6)   # (its ridge)


def test_detection_power_matches_a_simulated_glr_with_known_noise():
    """`detection_power` of `move_information`: the share of simulated windows (stops compared with their
    baselines' means, noise known) whose GLR statistic exceeds the threshold."""
    from scipy.stats import chi2

    from handeye.calib.change import detection_power, move_information

    rng = np.random.default_rng(52)
    S = 4
    H = rng.normal(size=(S, 3, 6))
    L = rng.normal(size=(S, 3, 3)) * 0.3 + np.eye(3)
    R = L @ L.transpose(0, 2, 1)
    m, n = np.array([5, 5, 4, 6]), np.array([60, 20, 3, 40])
    N = move_information(H, R, m, n)
    threshold = float(chi2.ppf(0.99, 6))
    delta = rng.normal(size=6)
    delta *= 2.5 / np.sqrt(delta @ N @ delta)          # non-centrality 6.25: a power near 0.2
    expected = detection_power(N, delta, threshold)
    trials, hits = 4000, 0
    W = [np.linalg.inv(R[j] * (1 / m[j] + 1 / n[j])) for j in range(S)]
    Ninv = np.linalg.inv(N)
    for _ in range(trials):
        g = np.zeros(6)
        for j in range(S):
            base = rng.multivariate_normal(np.zeros(3), R[j], size=n[j]).mean(axis=0)
            window = rng.multivariate_normal(H[j] @ delta, R[j], size=m[j]).mean(axis=0)
            g += H[j].T @ W[j] @ (window - base)
        hits += g @ Ninv @ g > threshold
    assert 0.1 < expected < 0.5
    assert abs(hits / trials - expected) < 4 * np.sqrt(expected * (1 - expected) / trials)
    # no move: the false-alarm rate; a stop without a baseline adds nothing
    assert abs(detection_power(N, np.zeros(6), threshold) - 0.01) < 1e-9
    assert np.allclose(move_information(H, R, m, np.array([60, 20, 0, 40])),
                       move_information(H[[0, 1, 3]], R[[0, 1, 3]], m[[0, 1, 3]], n[[0, 1, 3]]))


def test_detection_limit_inputs_are_checked():
    from handeye.calib.change import detection_power, move_information
    from handeye.calib.errors import CalibrationError

    with pytest.raises(CalibrationError, match="H \\(S, 3, 6\\)"):
        move_information(np.zeros((2, 3, 5)), np.zeros((2, 3, 3)), [1, 1], [1, 1])
    with pytest.raises(CalibrationError, match="visit counts"):
        move_information(np.zeros((1, 3, 6)), np.eye(3)[None], [-1], [1])
    with pytest.raises(CalibrationError, match="threshold"):
        detection_power(np.eye(6), np.zeros(6), 0.0)


def test_window_power_of_a_move_seen_at_stops_grows_with_its_size_and_the_visits():
    """`window_power`: a camera 0.8 m above four stops, looking down, moved across its line of sight and along
    it; no move is the false-alarm rate, a move along the line of sight (depth noise 3 mm) is harder to see than
    across it (1 mm), more visits see it better and the robot's repeatability worse."""
    from scipy.stats import chi2

    from handeye.calib import transforms as tf
    from handeye.calib.change import window_power
    from handeye.calib.simulate import point_covariance

    C = tf.make_transform(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 0.8])     # optical axis along the base's -z
    K = tf.make_transform(np.eye(3), [0.0, 0.0, 0.1])
    A = np.array([tf.make_transform(np.eye(3), [x, y, 0.0])
                  for x, y in ((0.1, 0.1), (-0.1, 0.1), (0.1, -0.1), (-0.15, -0.05))])
    R = point_covariance((tf.invert(C) @ A @ K)[:, :3, 3], 0.001, 0.003)
    threshold = float(chi2.ppf(1 - 1e-7, 6))

    def power(shift, visits=(5, 5, 5, 5), robot=None):
        after = C.copy()
        after[:3, 3] += shift
        return window_power(C, after, K, A, R, list(visits), [50] * 4, "eye_to_hand", robot, threshold)

    assert power(np.zeros(3)) == pytest.approx(1e-7, rel=1e-3)
    across, along = power([0.004, 0.0, 0.0]), power([0.0, 0.0, 0.004])
    assert along < across and across > 0.99
    assert power([0.0, 0.0, 0.004], visits=(10, 10, 10, 10)) > along
    assert power([0.0, 0.0, 0.004], robot=np.diag([np.deg2rad(0.01) ** 2] * 3 + [0.001 ** 2] * 3)) < along
