"""bench --shift's second-knock section (`app.benchmarks.shift.section_second_knock`)."""

from app.benchmarks import shift as bench_shift
from calib import simulate
from calib.monitor import MonitorSettings


def test_the_second_knock_section_counts_a_knock_while_the_relearnt_camera_settles():
    text = bench_shift.section_second_knock([2], simulate.Shift(), MonitorSettings(), gaps=(10,))
    header, rule, row = text.splitlines()
    assert "settling a re-learnt camera at the second" in header and "second flagged within 20 samples" in header
    cells = [c.strip() for c in row.strip("|").split("|")]
    # Seed 2: the first knock re-learnt within 10 samples, the second flagged in its own window, nothing else.
    assert cells[:4] == ["10", "1/1", "1/1", "0"], row
    assert 0.0 < float(cells[4]) < 5.0
