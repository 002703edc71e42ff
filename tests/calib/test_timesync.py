"""handeye.calib.timesync on synthetic eye-in-hand streams with a known clock offset."""

import numpy as np
import pytest

from handeye.calib import timesync as ts
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError, InsufficientDataError


def _streams(rng, offset, *, noise_rad=0.0):
    """Robot (50 Hz, true clock) and camera (30 Hz, clock late by ``offset``) streams, eye-in-hand."""
    X = tf.make_transform(tf.random_rotations(1, 1.0, rng)[0], [0.05, -0.02, 0.1])    # T_flange_cam
    Y = tf.make_transform(tf.random_rotations(1, 1.0, rng)[0], [0.8, 0.1, 0.0])       # T_base_marker
    freq = rng.uniform(0.2, 0.7, size=(3, 2))
    phase = rng.uniform(0, 2 * np.pi, size=(3, 2))

    def A_at(t):
        rv = 0.4 * np.sin(np.outer(t, freq[:, 0]) * 2 * np.pi + phase[:, 0])
        p = [0.5, 0.0, 0.6] + 0.1 * np.sin(np.outer(t, freq[:, 1]) * 2 * np.pi + phase[:, 1])
        return tf.from_rotvec_translation(rv, p)

    t_a = np.arange(0.0, 30.0, 0.02)
    t_true_b = np.arange(0.013, 30.0, 1 / 30)
    B = tf.invert(A_at(t_true_b) @ X) @ Y                  # T_cam_marker
    if noise_rad:
        B = B @ tf.from_rotvec_translation(rng.normal(scale=noise_rad, size=(len(B), 3)), np.zeros((len(B), 3)))
    return t_a, A_at(t_a), t_true_b - offset, B, A_at, X, Y


def test_interpolation_reproduces_smooth_motion():
    rng = np.random.default_rng(1)
    t_a, A, _, _, A_at, _, _ = _streams(rng, 0.0)
    tq = np.array([-1.0, 0.5, 10.011, 29.97, 31.0])
    Tq, valid = ts.interpolate_poses(tq, t_a, A)
    assert valid.tolist() == [False, True, True, True, False]
    rot, trans = tf.pose_error(Tq[valid], A_at(tq[valid]))
    # 50 Hz samples of a <0.7 Hz motion: interpolation error far below a mm / 0.1 deg.
    assert trans.max() < 1e-4 and np.rad2deg(rot.max()) < 0.05


def test_interpolation_flags_gaps():
    t = np.array([0.0, 0.1, 1.0, 1.1])
    T = np.broadcast_to(np.eye(4), (4, 4, 4))
    _, valid = ts.interpolate_poses([0.05, 0.5, 1.05], t, T, max_gap=0.2)
    assert valid.tolist() == [True, False, True]


@pytest.mark.parametrize("offset", [0.0, 0.137, -0.42])
def test_offset_found_from_angular_speed(offset):
    rng = np.random.default_rng(7)
    t_a, A, t_b, B, *_ = _streams(rng, offset, noise_rad=np.deg2rad(0.3))
    est = ts.estimate_clock_offset(t_a, A, t_b, B, max_offset=1.0)
    assert est.offset == pytest.approx(offset, abs=0.01)
    assert est.score > 0.9


def test_offset_beyond_the_search_range_is_reported():
    rng = np.random.default_rng(7)
    # Just outside the range the correlation still rises towards the edge; far outside it need not.
    t_a, A, t_b, B, *_ = _streams(rng, 0.45)
    with pytest.raises(CalibrationError, match="larger than max_offset = 0.3"):
        ts.estimate_clock_offset(t_a, A, t_b, B, max_offset=0.3)


def test_refined_offset_minimises_the_given_cost():
    rng = np.random.default_rng(3)
    offset = 0.21
    t_a, A, t_b, B, _, X, Y = _streams(rng, offset)

    def residual(A_pairs, B_pairs):
        # Truth-based residual: the spread of A X B around Y (m); zero only when paired in time.
        return float(np.linalg.norm((A_pairs @ X @ B_pairs)[:, :3, 3] - Y[:3, 3], axis=1).mean())

    cost = ts.calibration_cost(t_a, A, t_b, B, residual)
    est = ts.refine_clock_offset(cost, 0.15, half_width=0.1)
    assert est.offset == pytest.approx(offset, abs=2e-3)
    assert est.score < cost(0.15)


def test_pairing_keeps_only_covered_samples():
    rng = np.random.default_rng(5)
    t_a, A, t_b, B, *_ = _streams(rng, 0.5)
    # Shifted by 1 s, the last half second of stream b falls after stream a ends.
    t, A_p, B_p, idx = ts.pair_streams(t_a, A, t_b, B, 1.0)
    assert len(t) == len(A_p) == len(B_p) == len(idx)
    assert (t + 1.0 <= t_a[-1]).all() and (t + 1.0 >= t_a[0]).all()
    assert len(idx) < len(t_b)


def test_bad_streams_are_named():
    T = np.broadcast_to(np.eye(4), (3, 4, 4))
    with pytest.raises(CalibrationError, match=r"time\[2\]"):
        ts.check_stream([0.0, 1.0, 1.0], T)
    with pytest.raises(InsufficientDataError):
        ts.check_stream([0.0], T[:1])
    still = np.broadcast_to(np.eye(4), (200, 4, 4))
    t = np.arange(200) * 0.05
    with pytest.raises(InsufficientDataError, match="does not rotate"):
        ts.estimate_clock_offset(t, still, t, still, max_offset=0.5)


def test_dropouts_are_left_out_of_the_correlation():
    rng = np.random.default_rng(9)
    t_a, A, t_b, B, *_ = _streams(rng, 0.25, noise_rad=np.deg2rad(0.3))
    # The marker is out of view for 0.8 s every 4 s.
    keep = (t_b % 4.0) > 0.8
    t_b, B = t_b[keep], B[keep]
    grid = np.arange(1.0, 9.0, 0.01)
    w = ts.angular_speed(t_b, B, grid, baseline=0.3, max_gap=0.1)
    assert np.isnan(w).any() and np.isfinite(w).sum() > len(w) // 2
    assert np.isnan(w[(grid[:-30] % 4.0) < 0.75]).all()
    est = ts.estimate_clock_offset(t_a, A, t_b, B, max_offset=1.0, max_gap=0.1)
    assert est.offset == pytest.approx(0.25, abs=0.01)
