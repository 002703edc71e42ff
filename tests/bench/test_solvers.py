"""Smoke test: the solver benchmark runs end to end and writes its table and plots."""

from bench import solvers as bench_solvers


def test_quick_benchmark_writes_table_and_plots(tmp_path):
    assert bench_solvers.main(["--tiny", "--out", str(tmp_path)]) == 0
    report = (tmp_path / "solvers.md").read_text()
    assert "`python -m bench --tiny` — seed 0," in report  # the command a user types (it named python -m ...)
    for needle in ("Experiment 1", "Experiment 2", "Realistic cell", "Cramér-Rao", "cv2.TSAI", "cv2.SHAH",
                   "YKronT'+ML", "outliers", "monitoring engine update", "Timing"):
        assert needle in report
    for png in ("solvers_samples.png", "solvers_noise.png", "solvers_realistic.png"):
        assert (tmp_path / png).stat().st_size > 10_000
