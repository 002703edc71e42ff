"""The month benchmark (`bench.month`) on a short month: it scores against the truth it simulates."""

import numpy as np

from bench import month
from handeye.calib.setup import Setup


def test_a_short_month_is_scored_per_day_with_its_bumps_and_alarms():
    spec = month.CellSpec(0, Setup.EYE_TO_HAND, False, 2.0, 4, 0.8)
    run = month.run_cell(spec)
    # a bump in each of the four half-days "weeks", each flagged, none falsely
    assert len(run.bumped) == 4 and len(run.moved) >= 4
    row = month.cell_row(run)
    assert row[0] == "eye-to-hand, poses only, seed 0"
    assert row[-4] == 0 and row[-3] == "4/4"
    assert set(np.unique(run.day)) == {0, 1}
    # the settled mask leaves out the 40 samples after each bump (scored every SCORE_EVERY)
    assert (~run.settled).sum() == 4 * 40 // month.SCORE_EVERY
    assert np.all(run.error_mm > 0) and np.all(run.sigma_mm > 0)
    days = month.day_rows([run])
    assert [d[0] for d in days] == [0, 1]
    assert "1 cells" in month.summary([run])
