"""calibration_in_use.yaml with versions, through the engine on a simulated production cell: a re-learn proposes
version 2, the policy holds it for approval, a restart in the middle of the approval loses nothing, the approval
puts it in use and the consumer takes it."""

import numpy as np
import yaml

from bench.monitor_campaign import ProgramDriver, ScriptedConsumer, calibration, cell
from handeye.app import calibration_in_use
from handeye.app.calibration_versions import Approvals, History, write_approval
from handeye.app.consumers import CalibrationLoop
from handeye.calib.monitor import AlarmLevel, EngineState, MonitorEngine
from handeye.calib.setup import Setup

KEY = (Setup.EYE_TO_HAND, 0, 12, 8, False)


def _run(directory, consumer, policy="approve", continues=None):
    loop = CalibrationLoop.of(History(policy), [consumer], run=directory, approvals=Approvals([directory]))
    in_use = calibration_in_use.InUseFile(directory, loop=loop)
    if continues is not None:
        in_use.resume(continues)
    return in_use


def _doc(directory):
    return yaml.safe_load((directory / calibration_in_use.FILE_NAME).read_text())


def test_a_restart_in_the_middle_of_an_approval_keeps_the_version_and_the_approval(tmp_path):
    c = cell(*KEY)
    result, problem = calibration(*KEY)
    d = ProgramDriver(c, MonitorEngine(), np.random.default_rng(3))
    d.engine.arm(result, problem)
    consumer = ScriptedConsumer("prompt")
    first, second = tmp_path / "run1", tmp_path / "run2"
    first.mkdir()
    second.mkdir()
    in_use = _run(first, consumer)
    d.on_update = lambda upd: (in_use.update(d.engine, upd, d.t), in_use.poll(d.engine, d.t))
    in_use.armed(d.engine, d.t)
    in_use.poll(d.engine, d.t)
    assert consumer.has == 1 and _doc(first)["in_use_by"] == {"prompt consumer": 1}
    for i in range(30):
        d.visit(i % 8, 30.0)
    d.C = c.moved(d.C, np.array([0.0, np.deg2rad(0.5), 0.0]), np.array([0.01, 0.0, 0.0]))
    alarms = []
    for i in range(30, 90):
        upd = d.visit(i % 8, 30.0)
        alarms += [i] if upd.alarm == AlarmLevel.MOVED else []
        if in_use.loop.history.waiting_for_approval is not None:
            break
    assert len(alarms) == 1, alarms
    h = in_use.loop.history
    assert h.waiting_for_approval.number == 2 and h.in_use.number == 1 and consumer.has == 1
    doc = _doc(first)
    assert doc["calibration_version"] == 1 and doc["pending"]["version"] == 2
    assert doc["pending"]["approve_with"] == f"handeye approve {first}"
    assert doc["pending"]["evidence"]["moved_mm"] > 5.0
    level, sentence = in_use.loop.status(d.t)
    assert level == "moved" and "waiting for approval" in sentence and "still uses version 1" in sentence
    # The run stops; a person approves it meanwhile; the next run continues from it.
    in_use.end(d.engine, d.t)
    write_approval(first, 2, "ann@cell7", d.t + 5)
    engine = MonitorEngine(d.engine.settings)
    engine.resume(calibration_in_use.read(first / calibration_in_use.FILE_NAME, Setup.EYE_TO_HAND))
    d.engine = engine
    in_use = _run(second, consumer, continues=first / calibration_in_use.FILE_NAME)
    in_use.armed(engine, d.t + 10)
    assert in_use.loop.history.waiting_for_approval.number == 2       # nothing lost across the restart
    in_use.poll(engine, d.t + 10)
    h = in_use.loop.history
    assert h.in_use.number == 2 and h.in_use.approved_by == "ann@cell7" and h.pending is None
    assert consumer.has == 2 and in_use.loop.status(d.t + 10) is None
    doc = _doc(second)
    assert doc["calibration_version"] == 2 and doc["in_use_by"] == {"prompt consumer": 2} and "pending" not in doc
    np.testing.assert_allclose(doc["camera_transform"]["matrix"], h.in_use.camera_transform, atol=1e-12)
    assert [v["state"] for v in doc["calibration_history"]["versions"]] == ["replaced", "in_use"]
    assert engine.state in (EngineState.ARMED, EngineState.WARMING)


def test_status_and_approve_on_the_command_line(tmp_path, capsys):
    """``handeye status`` answers for a run (and for a cell config: its newest run), ``handeye approve`` refuses a
    version that is not pending, approves the one that is, and status then says who approved it."""
    from handeye.app.cli import main

    c = cell(*KEY)
    result, problem = calibration(*KEY)
    d = ProgramDriver(c, MonitorEngine(), np.random.default_rng(3))
    d.engine.arm(result, problem)
    run = tmp_path / "sessions" / "20261206-010203-000000_eye_to_hand"
    run.mkdir(parents=True)
    in_use = _run(run, ScriptedConsumer("prompt"))
    d.on_update = lambda upd: (in_use.update(d.engine, upd, d.t), in_use.poll(d.engine, d.t))
    in_use.status = lambda: in_use.loop.status(d.t) or ("ok", "calibrated and quiet")
    in_use.armed(d.engine, d.t)
    for i in range(30):
        d.visit(i % 8, 30.0)
    d.C = c.moved(d.C, np.array([0.0, np.deg2rad(0.5), 0.0]), np.array([0.01, 0.0, 0.0]))
    for i in range(30, 90):
        d.visit(i % 8, 30.0)
        if in_use.loop.history.waiting_for_approval is not None:
            break
    in_use.end(d.engine, d.t)
    config = tmp_path / "cell.toml"
    config.write_text(f'[session]\nroot = "{tmp_path / "sessions"}"\n')
    for target in (str(run), str(config)):
        assert main(["status", target]) == 3
        out = capsys.readouterr().out
        assert out.startswith("MOVED: camera moved") and "waiting for approval" in out
        assert "in use by: prompt consumer: version 1" in out and "pending: version 2" in out
    assert main(["approve", str(run), "--version", "3"]) == 1
    assert "version 3 is not pending; version 2 is" in capsys.readouterr().err
    assert main(["approve", str(run), "--by", "ann"]) == 0
    assert "approved version 2" in capsys.readouterr().out
    main(["status", str(run)])
    assert "approved by ann at" in capsys.readouterr().out
    assert main(["status", str(tmp_path / "nothing")]) == 1
