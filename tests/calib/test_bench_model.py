"""Smoke test of the model benchmark's sections (tiny sizes): they run and print their tables."""

import dataclasses

import numpy as np
import pytest

from app.benchmarks import model as bench_model
from calib import simulate


def test_model_benchmark_sections_run():
    rng = np.random.default_rng(0)
    assert "flips found by auto" in bench_model.section_flips(rng, 1)
    assert "| auto |" in bench_model.section_board(rng, 1)
    text = bench_model.section_realistic(rng, 1)
    assert "extended CRLB" in text and "NEES" in text and "generating model" in text
    assert "focal scale only" in bench_model.section_effects(rng, 1)
    assert "CPU min" in bench_model.section_speed(rng, 1, n=50)


def test_generating_bound_is_the_extended_bound_when_only_the_camera_depth_is_unknown():
    """Without robot, focal or misregistration error the generating model is the extended model with
    depth scale and offset free and the repeatability as white robot noise: the two bounds agree."""
    prof = simulate.RealisticProfile().bias_free()
    real = simulate.realistic_profile(30, np.random.default_rng(4), prof)
    ext = bench_model.extended_crlb(real.data, prof.repeatability_m, free=(True, True, False))
    assert bench_model.generating_bound(real, prof) == pytest.approx(ext, rel=1e-3)


def test_generating_bound_grows_with_the_unknown_focal_error():
    """A 1% focal error that the data cannot separate from the camera's position dominates the bound."""
    prof = simulate.RealisticProfile()
    real = simulate.realistic_profile(30, np.random.default_rng(4), prof)
    no_focal = dataclasses.replace(prof, focal_scale=0.0)
    assert bench_model.generating_bound(real, prof) > 1.3 * bench_model.generating_bound(real, no_focal)
