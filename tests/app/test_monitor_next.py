"""What `monitor`'s summary tells the plant to do next (`ShiftRecord.next_steps`): after a move, before and after its
re-learn, a drift."""

import argparse
import dataclasses
import shlex
import types
from pathlib import Path

import numpy as np

from bench.shift import armed_cell
from handeye.app.calibration_in_use import FILE_NAME
from handeye.app.commands.common import command_with
from handeye.app.commands.monitor import print_monitor_summary
from handeye.app.commands.replay import monitor_next_steps as replay_next_steps
from handeye.app.runs.monitor import MonitorReport
from handeye.app.shift_record import ShiftRecord
from handeye.calib import simulate
from handeye.calib.monitor import AlarmLevel, EngineState
from handeye.calib.setup import Setup

VERIFY = "handeye verify -c 'my cell.toml'"
CALIBRATE = "handeye calibrate -c 'my cell.toml' --yes-move"


def _shift(tmp_path, shift, seed=0):
    """An armed engine through ``shift`` on a realistic cell: (report after each sample, as the summary sees it)."""
    real, _, engine = armed_cell(seed)
    s = simulate.shift_stream(real, shift, np.random.default_rng([seed, 1]))
    F = simulate.RealisticProfile().dh_error_factor(s.q)
    record = ShiftRecord(Setup.EYE_TO_HAND)
    session = tmp_path / "run one"
    session.mkdir()
    (session / FILE_NAME).write_text("format: handeye-result\n")
    for i in range(len(s.t)):
        upd = engine.update(s.t[i], s.A[i], s.points[i], s.point_cov[i], F[i])
        record.add(i, upd, engine)
        yield MonitorReport(session, i + 1, 0, estimate=upd.camera_transform, last=upd, record=record)


def _next(report, **kw):
    args = argparse.Namespace(argv=["monitor", "-c", "my cell.toml", "--reference", "old run", "--hook", "beep"])
    return report.record.next_steps(report.session / FILE_NAME,
                                    continue_with=command_with(args, "--reference", report.session), **kw)


def test_after_a_move_the_summary_says_what_holds_the_old_camera_and_how_to_go_on(tmp_path, capsys):
    seen = {}
    # Knocked at the third sample: the stops have too few visits from before to re-learn it at once.
    for report in _shift(tmp_path, dataclasses.replace(simulate.Shift(), hours=1.0, bumps=((90 / 3600, 5.0, 0.3),))):
        last = report.record.last
        key = ("relearning" if last.state == EngineState.RELEARNING else
               "relearnt" if any(a["alarm"] == AlarmLevel.MOVED for a in report.record.alarms) else "quiet")
        seen.setdefault(key, _next(report, verify_with=VERIFY, calibrate=CALIBRATE))
        seen[key + " last"] = _next(report, verify_with=VERIFY, calibrate=CALIBRATE)
    assert set(seen) == {"quiet", "quiet last", "relearning", "relearning last", "relearnt", "relearnt last"}
    session = tmp_path / "run one"
    go_on = f"  go on monitoring from this calibration in use: {shlex.join(['handeye', 'monitor', '-c', 'my cell.toml', '--hook', 'beep', '--reference', str(session)])}"
    # A still camera: only how to go on, from this run's calibration in use instead of the old reference.
    assert seen["quiet"] == ["next:", go_on]
    # Moved, not re-learnt yet: the robot program is off, the stops (or a recalibration) will fix it.
    lines = seen["relearning"]
    assert lines[0] == "next:" and lines[-1] == go_on and len(lines) == 3
    assert "not re-learnt it yet" in lines[1] and lines[1].endswith(CALIBRATE)
    # Re-learnt: give the calibration in use to what still holds the old camera, check it, go on.
    lines = seen["relearnt last"]
    assert len(lines) == 4 and lines[-1] == go_on
    mm = report.record.moved_total[0]
    assert "moved once and was re-learnt" in lines[1] and f"it is {mm:.1f} mm" in lines[1]
    assert "is off by the move" in lines[1] and str(session / FILE_NAME) in lines[1]
    assert 4.0 < mm < 12.0, mm  # 5 mm and 0.3 deg (about 4 mm at the workspace)
    assert lines[2] == f"  check it on fresh poses when the cell is free: {VERIFY} --result " \
                       f"{shlex.quote(str(session / FILE_NAME))} --yes-move"
    # The verification is not offered where it cannot be run (a simulated camera is unmoved in a new process).
    assert _next(report, calibrate=CALIBRATE) == [lines[0], lines[1], lines[3]]
    # replay --monitor, of a recording of that run, says the same, its commands with the cell's config.
    replayed = replay_next_steps(types.SimpleNamespace(record=report.record, out=session), Path("my cell.toml"))
    assert replayed[1] == lines[1] and replayed[2].endswith(f"--result {shlex.quote(str(session / FILE_NAME))} "
                                                            "--yes-move") and VERIFY in replayed[2]
    assert replayed[3] == "  go on monitoring from this calibration in use: " + shlex.join(
        ["handeye", "monitor", "-c", "my cell.toml", "--reference", str(session)])
    # The summary prints them after the files, with the recording to open.
    (session / "recording.rrd").write_bytes(b"")
    print_monitor_summary(report, Setup.EYE_TO_HAND, lines)
    out = capsys.readouterr().out
    assert out.index("calibration_in_use.yaml: ") < out.index("\nnext:\n") < out.index(go_on) \
        < out.index("  open the recording:  ")


def test_a_drifting_camera_is_said_with_the_calibration_in_use_that_followed_it(tmp_path):
    said = []
    # 3 mm/h, six times the random walk's hour: the drifting alarm comes hours before the stops read a move.
    for report in _shift(tmp_path, dataclasses.replace(simulate.Shift(), hours=2.0, drift_mm_h=3.0, bumps=())):
        if report.record.last.level == AlarmLevel.DRIFTING:
            said.append(_next(report))
    assert not any(a["alarm"] == AlarmLevel.MOVED for a in report.record.alarms) and said
    lines = said[-1]
    assert len(lines) == 3 and lines[1].startswith("  the camera is drifting: ") and FILE_NAME in lines[1]


def test_a_run_without_a_sample_has_no_next_steps(tmp_path):
    assert ShiftRecord(Setup.EYE_TO_HAND).next_steps(tmp_path / FILE_NAME, continue_with="handeye monitor") == []


def test_a_slow_hook_is_told_to_background_its_work(caplog):
    """Hooks run in line with the sampling: one that takes more than a second is named in a warning that says
    no sample is taken meanwhile; a quick one is not."""
    import logging

    from handeye.app.runs.monitor import HOOK_SLOW_S, run_hook

    with caplog.at_level(logging.WARNING, logger="handeye.app.runs.monitor"):
        run_hook("true", {}, "monitor.calibration_hook")
        assert not caplog.records
        run_hook(f"sleep {HOOK_SLOW_S + 0.2}", {}, "monitor.calibration_hook")
    (record,) = caplog.records
    assert "monitor.calibration_hook 'sleep 1.2' took 1.2 s: no sample is taken while a hook runs" in record.message
