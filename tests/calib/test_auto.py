"""solve("auto"): extended model, camera correction, identifiability, flips, self-check."""

import numpy as np
import pytest

from calib import model, solve
from calib.auto import self_check
from calib import transforms as tf
from calib.errors import CalibrationError
from calib.refine import error_vector
from calib.simulate import realistic_cell, with_gross_outliers


def _trans_err(T, T_true):
    return float(np.linalg.norm(error_vector(T, T_true)[3:]))


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
@pytest.mark.parametrize("poses", [False, True])
def test_exact_on_noise_free_data(setup, poses):
    rng = np.random.default_rng(4)
    d = realistic_cell(12, rng, setup=setup, sigma_lateral=0.0, sigma_depth=0.0, pose_noise=(0.0, 0.0))
    res = solve("auto", d.A, d.B if poses else d.points, setup=setup)
    cam_true = d.Y if setup == "eye_to_hand" else d.X
    rot, trans = tf.pose_error(res.camera_transform, cam_true)
    assert trans < 1e-7 and rot < 1e-8
    assert res.info["measurements"] == (["points", "orientations"] if poses else ["points"])
    for c in res.info["camera_correction"].values():
        assert abs(c["value"]) < 1e-6


def test_depth_scale_is_estimated_and_removes_the_bias():
    """2% depth scale error, N = 40: the paper's refined model is biased, auto estimates the scale."""
    errs_plain, errs_auto, z = [], [], []
    for seed in range(6):
        rng = np.random.default_rng(100 + seed)
        d = realistic_cell(40, rng)
        p = d.points * 1.02
        plain = solve("YKronT'", d.A, p, refine=True)
        auto = solve("auto", d.A, p)
        errs_plain.append(_trans_err(plain.Y, d.Y))
        errs_auto.append(_trans_err(auto.Y, d.Y))
        c = auto.info["camera_correction"]["depth_scale"]
        assert c["estimated"]
        z.append((c["value"] - 0.02) / c["sigma"])
    assert np.mean(errs_auto) < 0.5 * np.mean(errs_plain)
    assert np.sqrt(np.mean(np.square(z))) < 2.5          # the stated sigma is honest


def test_unidentifiable_camera_parameters_stay_nominal_with_a_message():
    """Motions 1 cm wide: no depth range, so depth offset/scale are fixed and the message says what to move."""
    rng = np.random.default_rng(6)
    d = realistic_cell(20, rng, translation_range=0.01)
    res = solve("auto", d.A, d.points)
    corr = res.info["camera_correction"]
    assert not corr["depth_offset"]["estimated"] and corr["depth_offset"]["value"] == 0.0
    assert any("depth_offset" in n and "distance" in n for n in res.info["notes"]), res.info["notes"]
    none = solve("auto", d.A, d.points, camera_correction="none")
    assert not any(c["estimated"] for c in none.info["camera_correction"].values())


def test_camera_correction_argument_is_checked():
    rng = np.random.default_rng(1)
    d = realistic_cell(10, rng)
    with pytest.raises(CalibrationError, match="camera_correction"):
        solve("auto", d.A, d.points, camera_correction="all")
    with pytest.raises(CalibrationError, match="auto"):
        solve("YKronT'", d.A, d.points, camera_correction="depth")


def test_gross_outliers_are_rejected():
    rng = np.random.default_rng(12)
    d = realistic_cell(40, rng)
    p, bad = with_gross_outliers(d.points, 0.2, rng)
    res = solve("auto", d.A, p, rng=np.random.default_rng(0))
    assert set(bad) <= set(res.rejected.tolist())
    assert _trans_err(res.Y, d.Y) < 0.005


def test_half_turn_flips_of_a_symmetric_board_are_undone():
    """6 of 19 marker poses flipped by a half turn about the board normal (origin to the far corner)."""
    rng = np.random.default_rng(21)
    d = realistic_cell(19, rng, pose_noise=(np.deg2rad(0.3), 0.001))
    center = np.array([0.09, 0.06, 0.0])                   # board center in the marker frame
    F = tf.make_transform(tf.so3_exp(np.array([0.0, 0.0, np.pi])), 2 * center)
    B = d.B.copy()
    flipped = rng.choice(19, size=6, replace=False)
    B[flipped] = B[flipped] @ F
    res = solve("auto", d.A, B)
    assert sorted(res.info["flips"]["flipped"]) == sorted(flipped.tolist())
    assert res.residuals.max_translation < 0.02
    assert _trans_err(res.Y, d.Y) < 0.005
    # Without the fix every pose-based solver sees >100 mm residuals.
    assert solve("YQuatT'", d.A, B).residuals.max_translation > 0.1


def test_self_check_is_in_every_auto_result_and_warns_when_the_model_is_wrong():
    rng = np.random.default_rng(13)
    d = realistic_cell(30, rng)
    good = solve("auto", d.A, d.points)
    sc = good.info["self_check"]
    assert sc["consistent"] and sc["warning"] is None and 1 / 1.5 < sc["loo_ratio"] < 1.5
    n_camera = sum(c["estimated"] for c in good.info["camera_correction"].values())
    assert sc["loo_errors_m"].shape == (30,) and sc["dof"] == 3 * 30 - 9 - n_camera
    # Noise levels 3x too small for the data (an overconfident model): the held-out check says so.
    noise = model.NoiseLevels(point_scale=good.info["noise"]["point_scale"] / 9, robot=1e-6)
    bad = self_check(good.X, good.Y, d.A, d.points, setup="eye_to_hand", noise=noise)
    assert not bad["consistent"] and bad["loo_ratio"] > 2 and "not trustworthy" in bad["warning"]
    # Any estimate can be checked, its noise levels estimated at the estimate.
    cf = solve("YKronT'", d.A, d.points)
    assert 1 / 1.5 < self_check(cf.X, cf.Y, d.A, d.points, setup="eye_to_hand")["loo_ratio"] < 1.5


@pytest.mark.parametrize("n", [5, 6])
def test_few_samples_solve_with_a_self_check(n):
    """At the minimum sample count every sample is needed: no held-out comparison of variants, still a result."""
    d = realistic_cell(n, np.random.default_rng(n))
    for B in (d.points, d.B):
        res = solve("auto", d.A, B)
        assert res.residuals.rms_translation < 0.01 and res.info["self_check"] is not None
