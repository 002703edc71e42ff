"""bench --shift: how it counts alarms (`bench.shift.classify_alarms`) and its second-knock section
(`bench.shift.section_second_knock`)."""

from hypothesis import given
from hypothesis import strategies as st

from bench import shift as bench_shift
from handeye.calib import simulate
from handeye.calib.monitor import MonitorSettings


def test_the_second_knock_section_counts_a_knock_while_the_relearnt_camera_settles():
    text = bench_shift.section_second_knock([2], simulate.Shift(), MonitorSettings(), gaps=(10,))
    header, rule, row = text.splitlines()
    assert "settling a re-learnt camera at the second" in header and "second flagged within 20 samples" in header
    cells = [c.strip() for c in row.strip("|").split("|")]
    # Seed 2: the first knock re-learnt within 10 samples, the second flagged in its own window, nothing else.
    assert cells[:4] == ["10", "1/1", "1/1", "0"], row
    assert 0.0 < float(cells[4]) < 5.0


def test_a_bump_flagged_after_its_window_is_late_not_a_false_alarm():
    """Bumps at samples 100, 200 and 300: the first flagged after 5 samples (and once more within its window), the
    second first at 23 (late), the third never; an alarm before any bump and one well after the first bump's
    alarm are the false ones."""
    moved = [50, 105, 110, 150, 223]
    delays, late, false = bench_shift.classify_alarms(moved, [100, 200, 300])
    assert delays == [5, None, None]
    assert late == [None, 23, None]
    assert false == 2
    s = {"delays": delays, "late": late}
    assert bench_shift.delays_text(s) == "5, late 23, -"


@given(st.lists(st.integers(0, 400), max_size=12, unique=True).map(sorted),
       st.lists(st.integers(1, 400), max_size=4, unique=True).map(sorted))
def test_every_alarm_is_in_a_bumps_window_a_bumps_late_alarm_or_false(moved, bumped):
    """Each bump has at most one first alarm, within its window or late (never both); every alarm is within the
    window of the bump before it, a bump's late alarm, or false."""
    delays, late, false = bench_shift.classify_alarms(moved, bumped)
    assert len(delays) == len(late) == len(bumped)
    assert all(d is None or n is None for d, n in zip(delays, late))

    def since_bump(i):
        before = [b for b in bumped if b <= i]
        return i - before[-1] if before else None

    in_window = [i for i in moved if since_bump(i) is not None and since_bump(i) <= bench_shift.DETECT_WITHIN]
    flagged_late = [n for n in late if n is not None]
    assert false == len(moved) - len(in_window) - len(flagged_late)
