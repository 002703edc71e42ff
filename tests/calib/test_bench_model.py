"""Smoke test of the model benchmark's sections (tiny sizes): they run and print their tables."""

import numpy as np

from app.benchmarks import model as bench_model


def test_model_benchmark_sections_run():
    rng = np.random.default_rng(0)
    assert "flips found by auto" in bench_model.section_flips(rng, 1)
    assert "| auto |" in bench_model.section_board(rng, 1)
    text = bench_model.section_realistic(rng, 1)
    assert "extended CRLB" in text and "NEES" in text
