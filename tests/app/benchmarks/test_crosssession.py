"""app.benchmarks.crosssession: the monitoring engine's table on a real stream (tests/data/ethz/robot_arm_sim)."""

from pathlib import Path

import numpy as np

from app.benchmarks.crosssession import MONITOR_BUMPS, MONITOR_SPACING_S, monitor_rows
from app.formats import load

DATA = Path(__file__).resolve().parents[2] / "data" / "ethz" / "robot_arm_sim"


def test_monitor_rows_arm_from_one_half_and_judge_the_other():
    """Both directions at each spacing; the still camera raises no *moved* alarm, and bumps put into the
    stream are flagged after them (this stream: 1.1 mm per sample, far below a 5 mm bump)."""
    rows = monitor_rows([("sim", load(DATA))], np.random.default_rng(0))
    assert [(r[1], r[2]) for r in rows] == [(half, f"{s:g} s") for half in ("1st -> 2nd half", "2nd -> 1st half")
                                            for s in MONITOR_SPACING_S]
    assert all(r[5] == "0" for r in rows), [r[5] for r in rows]
    flagged = [int(r[9].split("/")[0]) for r in rows]
    assert all(0 <= f <= MONITOR_BUMPS for f in flagged) and sum(flagged) >= 3 * len(rows)
    assert all(float(r[7]) < 2.5 for r in rows)      # live verification, mm
