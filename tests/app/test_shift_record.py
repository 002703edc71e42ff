"""The shift record's files survive a Ctrl-C that lands while they are written (handeye.app.files.uninterrupted)."""

import os
import re
import signal

import pytest

from handeye.app.files import uninterrupted
from handeye.app.shift_record import ShiftRecord
from handeye.calib.setup import Setup


def test_a_signal_inside_the_block_waits_for_its_end():
    done = []
    with pytest.raises(KeyboardInterrupt):
        with uninterrupted():
            os.kill(os.getpid(), signal.SIGINT)
            done.append("after the signal")
    assert done == ["after the signal"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_ctrl_c_while_the_report_is_drawn_keeps_every_file(tmp_path, monkeypatch):
    """The first shift report of a run imports matplotlib; a Ctrl-C inside that import left it half-initialised,
    and the run's final write ended in a traceback (KeyError 'PolyCollection:kwdoc'). Now the files are
    written whole, then the interrupt comes."""
    rec = ShiftRecord(Setup.EYE_TO_HAND, "session", "reference")
    for k in range(5):
        rec.rows.append((1.8e9 + 30.0 * k, 0.1 * k, 0.5, 0.4, 0.2, ""))
    drawn = rec._figure

    def interrupted_figure():
        os.kill(os.getpid(), signal.SIGINT)
        return drawn()

    monkeypatch.setattr(rec, "_figure", interrupted_figure)
    with pytest.raises(KeyboardInterrupt):
        rec.write(tmp_path)
    assert {p.name for p in tmp_path.iterdir()} == {"alarms.yaml", "monitor_trace.png", "report.html"}
    assert "handeye monitoring report" in (tmp_path / "report.html").read_text()


def test_the_timeline_runs_on_the_local_clock(tmp_path):
    """The monitoring report's time axis is the local clock, with its day and UTC offset (it read 'hours since'
    from 0 to 0.012)."""
    import datetime as dt

    rec = ShiftRecord(Setup.EYE_TO_HAND, "session", "reference")
    for k in range(5):
        rec.rows.append((1.8e9 + 10.0 * k, 0.1 * k, 0.5, 0.4, 0.2, ""))
    rec.write(tmp_path)
    page = (tmp_path / "report.html").read_text()
    local = dt.datetime.fromtimestamp(1.8e9).astimezone()
    offset = local.strftime("%z")
    assert f"local time ({local:%Y-%m-%d}, UTC{offset[:3]}:{offset[3:]})" in page and "hours since" not in page
    svg = page[page.index("<svg"):page.index("</svg>")]
    assert re.findall(r"<text[^>]*>([^<]*)</text>", svg)[0] == f"{local:%H:%M}"   # the first tick: a clock time


def test_the_alarms_read_plainly_and_the_statistic_is_in_the_appendix(tmp_path):
    """An alarm's line in the monitoring report says what happened; the detector's statistic (GLR) is in the
    appendix only (it was in the alarms table a customer reads)."""
    rec = ShiftRecord(Setup.EYE_TO_HAND, "session", "reference")
    for k in range(5):
        rec.rows.append((1.8e9 + 10.0 * k, 0.1 * k, 0.5, 0.4, 0.2, "moved" if k == 3 else ""))
    rec.alarms.append({"sample": 3, "time": "2027-01-15T08:00:30+00:00", "t": 1.8e9 + 30, "alarm": "moved",
                       "message": "camera moved (GLR statistic 52.3 > 39.8); re-learning it from the production stops"})
    rec.write(tmp_path)
    page = re.sub(r"<svg.*?</svg>", "", (tmp_path / "report.html").read_text(), flags=re.S)
    front, appendix = page.split("<h2>Appendix")
    assert "GLR" not in front and "<td>camera moved</td>" in front
    assert "camera moved (GLR statistic 52.3 &gt; 39.8)" in appendix
