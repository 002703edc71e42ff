"""bench.yaxisr and bench.overhead run end to end (tiny settings) and write their tables and plots."""

import numpy as np

from bench import overhead, yaxisr


def test_bench_yaxisr_exactness_and_files(tmp_path, capsys):
    exact = yaxisr.exactness(1000)
    assert exact[180.0]["unrotated"] == np.inf  # Zhuang's reduction as published is singular there
    assert max(w["pre-rotated"] for w in exact.values()) < 1e-9
    assert yaxisr.main(["--rounds", "2", "--out", str(tmp_path)]) == 0
    assert "YAxisR pre-rotated" in (tmp_path / "yaxisr.md").read_text()
    assert (tmp_path / "yaxisr.png").stat().st_size > 0
    assert "| 180 |" in capsys.readouterr().out


def test_bench_overhead_files(tmp_path):
    assert overhead.main(["--repeats", "1", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "overhead.md").read_text()
    assert all(m in text for m in ("YKronT'", "YAxisR", "closed_form(\"YKronT'\")"))
    assert (tmp_path / "overhead.png").stat().st_size > 0
