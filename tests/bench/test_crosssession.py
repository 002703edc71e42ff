"""bench.crosssession: the monitoring engine's table on a real stream (tests/data/ethz/robot_arm_sim), and a
split every solver refuses."""

from pathlib import Path

import numpy as np

from bench.crosssession import MONITOR_BUMPS, MONITOR_SPACING_S, cross_session_rows, monitor_rows
from handeye.app.formats import load

DATA = Path(__file__).resolve().parents[1] / "data" / "ethz" / "robot_arm_sim"
CIRCLES = Path(__file__).resolve().parents[1] / "data" / "circle_grid" / "cal_data.yaml"


def test_monitor_rows_arm_from_one_half_and_judge_the_other():
    """Both directions at each spacing; the still camera raises no *moved* alarm, and bumps put into the
    stream are flagged after them (this stream: 1.1 mm per sample, far below a 5 mm bump). Every sample is at a
    new pose and carries no joints: 16 of the 20 knocks are flagged within the stream since a new pose's test
    allows for what its neighbours told of its error instead of taking it in (12 before)."""
    rows = monitor_rows([("sim", load(DATA))], np.random.default_rng(0))
    assert [(r[1], r[2]) for r in rows] == [(half, f"{s:g} s") for half in ("1st -> 2nd half", "2nd -> 1st half")
                                            for s in MONITOR_SPACING_S]
    assert all(r[5] == "0" for r in rows), [r[5] for r in rows]
    flagged = [int(r[9].split("/")[0]) for r in rows]
    assert all(0 <= f <= MONITOR_BUMPS for f in flagged) and sum(flagged) >= 14
    assert all(float(r[7]) < 2.5 for r in rows)      # live verification, mm


def test_a_block_whose_poses_turn_about_one_axis_is_a_row_saying_so():
    """The 10x10-circle recording's third block leaves training poses that all turn about one axis: every solver
    refuses them (as it should), and the table says so instead of the run ending in a traceback."""
    rows = cross_session_rows([("10x10 circles", load(CIRCLES))])
    assert len(rows) == 3 and all(len(row) == 11 for row in rows)
    refused = [row for row in rows if row[3].startswith("every solver refused")]
    assert [row[1] for row in refused] == ["block 3 from the others"]
    assert "rotations are about one axis" in refused[0][3]
    assert all(float(row[3]) > 0 for row in rows if row not in refused)
