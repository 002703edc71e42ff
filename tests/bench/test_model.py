"""Smoke test of the model benchmark's sections (tiny sizes): they run and print their tables."""

import dataclasses

import numpy as np
import pytest

from bench import model as bench_model
from handeye.calib import model, simulate, solve
from handeye.calib import transforms as tf


def test_model_benchmark_sections_run():
    rng = np.random.default_rng(0)
    assert "flips found by auto" in bench_model.section_flips(rng, 1)
    assert "| auto |" in bench_model.section_board(rng, 1)
    text = bench_model.section_realistic(rng, 1)
    assert "extended CRLB" in text and "NEES" in text and "generating model" in text and "The workspace" in text
    assert "focal scale only" in bench_model.section_effects(rng, 1)
    assert "CPU min" in bench_model.section_speed(rng, 1, n=50)


def test_generating_bound_is_the_extended_bound_when_only_the_camera_depth_is_unknown():
    """Without robot, focal or misregistration error the generating model is the extended model with
    depth scale and offset free and the repeatability as white robot noise: the two bounds agree."""
    prof = simulate.RealisticProfile().bias_free()
    real = simulate.realistic_profile(30, np.random.default_rng(4), prof)
    ext = bench_model.extended_cov(real.data, prof.repeatability_m, free=(True, True, False))
    gen = bench_model.generating_cov(real, prof)
    assert bench_model.translation_rms(gen) == pytest.approx(bench_model.translation_rms(ext), rel=1e-3)
    assert np.allclose(gen, ext, rtol=1e-3, atol=1e-3 * np.abs(ext).max())


def test_generating_bound_grows_with_the_unknown_focal_error():
    """A 1% focal error that the data cannot separate from the camera's position dominates the bound."""
    prof = simulate.RealisticProfile()
    real = simulate.realistic_profile(30, np.random.default_rng(4), prof)
    no_focal = dataclasses.replace(prof, focal_scale=0.0)
    assert (bench_model.translation_rms(bench_model.generating_cov(real, prof))
            > 1.3 * bench_model.translation_rms(bench_model.generating_cov(real, no_focal)))


def test_an_unknown_focal_scale_costs_the_camera_position_but_not_the_workspace():
    """The focal scale trades against the camera's distance (and the depth offset): free, it makes the
    camera translation bound several times larger, but where the camera puts points of the workspace it
    calibrated on hardly moves."""
    real = simulate.realistic_profile(30, np.random.default_rng(4), simulate.RealisticProfile())
    d = real.data
    seen = tf.transform_points(tf.invert(d.Y), simulate.workspace_points(real, 100, np.random.default_rng(5)))
    free = bench_model.extended_cov(d, real.robot_rms_m)
    known = bench_model.extended_cov(d, real.robot_rms_m, free=(True, True, False))
    assert bench_model.translation_rms(free) > 3 * bench_model.translation_rms(known)
    assert bench_model.workspace_rms(free, d.Y, seen) < 1.1 * bench_model.workspace_rms(known, d.Y, seen)


def test_workspace_jacobian_is_the_derivative_of_the_reported_point():
    rng = np.random.default_rng(6)
    real = simulate.realistic_profile(30, rng, simulate.RealisticProfile().bias_free())
    Y = real.data.Y
    seen = tf.transform_points(tf.invert(Y), simulate.workspace_points(real, 5, rng))
    delta = 1e-7 * rng.normal(size=9)
    Y_moved = tf.make_transform(tf.so3_exp(delta[:3]) @ Y[:3, :3], Y[:3, 3] + delta[3:6])
    moved = tf.transform_points(Y_moved, model.CameraCorrection(*delta[6:]).correct(seen))
    predicted = tf.transform_points(Y, seen) + bench_model.workspace_jacobian(Y, seen) @ delta
    assert np.allclose(moved, predicted, atol=1e-12)


def test_workspace_error_is_zero_at_the_truth_and_a_camera_shift_elsewhere():
    real = simulate.realistic_profile(30, np.random.default_rng(7), simulate.RealisticProfile())
    P = simulate.workspace_points(real, 50, np.random.default_rng(8))
    assert bench_model.workspace_error(real.data.Y, real.camera, real, P) < 1e-12
    shifted = real.data.Y.copy()
    shifted[:3, 3] += [0.003, 0.0, -0.004]
    assert bench_model.workspace_error(shifted, real.camera, real, P) == pytest.approx(0.005)
    # Without its correction, the camera's 1.5% depth scale alone puts points ~12 mm off at 0.8 m.
    assert bench_model.workspace_error(real.data.Y, model.CameraCorrection(), real, P) > 0.008


def test_auto_puts_workspace_points_nearly_where_it_does_without_systematic_errors():
    """Depth scale and offset, focal and DH error: auto's T_base_cam with its camera correction is used on
    the workspace within 1.25x of the bias-free cell's error (200 cells: 1.18x); the paper's model is not."""
    prof = simulate.RealisticProfile()
    auto, paper = {"real": [], "bias-free": []}, {"real": [], "bias-free": []}
    for seed in range(20):
        for label, p in (("real", prof), ("bias-free", prof.bias_free())):
            cell = simulate.realistic_profile(30, np.random.default_rng(300 + seed), p)
            d = cell.data
            P = simulate.workspace_points(cell, 100, np.random.default_rng([300 + seed, 1]))
            res = solve("auto", d.A, d.points)
            auto[label].append(bench_model.workspace_error(res.Y, res.camera_correction, cell, P))
            res = solve("YKronT'", d.A, d.points, refine=True)
            paper[label].append(bench_model.workspace_error(res.Y, model.CameraCorrection(), cell, P))
    ratio = {name: np.sqrt(np.mean(np.square(e["real"])) / np.mean(np.square(e["bias-free"])))
             for name, e in (("auto", auto), ("paper", paper))}
    assert ratio["auto"] < 1.35
    assert ratio["paper"] > 2.0


def test_uncorrected_points_are_predicted_better_by_the_exported_transform():
    """A 2% depth scale and 8 mm offset: held out, the rigid-only export predicts the raw points far better
    than the camera transform without its correction."""
    d = simulate.realistic_cell(30, np.random.default_rng(9), translation_range=0.25)
    raw = model.CameraCorrection(depth_scale=0.02, depth_offset=0.008).measure(d.points)
    exported, bare = bench_model.uncorrected_heldout(d.A, raw, "eye_to_hand", 5)
    assert exported < 0.6 * bare
