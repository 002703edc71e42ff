"""handeye replay --monitor: a recorded production session through the monitoring engine, with the trace."""

import csv
import dataclasses

import numpy as np
import yaml

from app.cli import main
from app.monitor_replay import TRACE_COLUMNS
from app.session import SessionWriter, read_session
from calib import simulate
from calib.observation import Observation


def _write(root, name, A, points, covs, t, q, extra_meta=None):
    with SessionWriter.create(root, "eye_to_hand", name=name, source="test") as w:
        for i in range(len(A)):
            w.add_sample(Observation(i, float(t[i]), A[i], points[i], covs[i], meta=dict(extra_meta or {}),
                                     joints=q[i]))
    return w.path


def _sessions(tmp_path, bumps):
    real = simulate.realistic_profile(30, np.random.default_rng([7, 0]))
    d = real.data
    cal = _write(tmp_path, "cal", d.A, d.points, d.point_cov, 1e9 + np.arange(30.0), real.q)
    shift = dataclasses.replace(simulate.Shift(), hours=2.0, bumps=bumps)
    s = simulate.shift_stream(real, shift, np.random.default_rng([7, 1]))
    # Another program's session: a meta key handeye does not know is kept, not refused.
    prod = _write(tmp_path, "prod", s.A, s.points, s.point_cov, 2e9 + s.t, s.q, {"cycle": "pick"})
    return cal, prod, s


def test_replay_monitor_finds_the_bump_and_writes_the_trace(tmp_path, capsys):
    cal, prod, s = _sessions(tmp_path, ((1.0, 5.0, 0.3),))
    out = tmp_path / "trace"
    rc = main(["replay", str(prod), "--monitor", "--reference", str(cal), "--trace-dir", str(out)])
    text = capsys.readouterr().out
    assert rc == 3
    assert "MOVED at sample" in text and "re-learnt the camera" in text
    with open(out / "monitor_trace.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0].keys()) == TRACE_COLUMNS
    assert len(rows) == len(s.t)
    moved = [int(r["sample"]) for r in rows if r["alarm"] == "moved"]
    bump = int(s.bumped[0])
    assert len(moved) == 1 and bump <= moved[0] <= bump + 20
    alarms = yaml.safe_load((out / "alarms.yaml").read_text())
    assert alarms["camera_transform"] == "T_base_cam"
    assert [a["sample"] for a in alarms["alarms"] if a["alarm"] == "moved"] == moved
    assert (out / "monitor_trace.png").stat().st_size > 10_000
    # The trace's camera transform before and after the bump differs by about the bump.
    xyz = np.array([[float(r[k]) for k in ("x_mm", "y_mm", "z_mm")] for r in rows])
    assert 2.0 < np.linalg.norm(xyz[-1] - xyz[bump - 1]) < 30.0
    assert read_session(prod).observations[0].meta["cycle"] == "pick"


def test_replay_monitor_of_a_still_camera_has_no_moved_alarm(tmp_path, capsys):
    cal, prod, s = _sessions(tmp_path, ())
    rc = main(["replay", str(prod), "--monitor", "--reference", str(cal / "session.json").replace("session.json", ""),
               "--trace-dir", str(tmp_path / "t")])
    assert rc == 0
    assert "0 skipped" in capsys.readouterr().out


def test_replay_monitor_without_reference_is_one_line(tmp_path, capsys):
    cal, prod, s = _sessions(tmp_path, ())
    rc = main(["replay", str(prod), "--monitor"])
    err = capsys.readouterr().err
    assert rc == 1 and "--reference" in err and "Traceback" not in err
