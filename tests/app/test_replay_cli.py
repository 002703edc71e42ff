"""``handeye replay`` accepts every import format (handeye.app.cli -> handeye.app.commands.replay -> handeye.app.runs.replay -> handeye.app.formats.load)."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from handeye.app.cli import main
from handeye.calib import simulate
from handeye.calib import transforms as tf
from tests.app.verdict_status import printed_status

DATA = Path(__file__).parents[1] / "data"


def _msg(T):
    t, q = tf.to_xyz_quat(T)
    return {"translation": dict(zip("xyz", map(float, t))), "rotation": dict(zip("xyzw", map(float, q)))}


@pytest.fixture(scope="module")
def cell():
    return simulate.realistic_cell(15, np.random.default_rng(8), setup="eye_to_hand")


def _replay(capsys, *argv):
    rc = main(["replay", *map(str, argv)])
    out, err = capsys.readouterr()
    assert rc == printed_status(out), err
    return out


def _rows(out):
    """{solver: cells} of the markdown table printed by replay."""
    rows = [line.strip("|").split("|") for line in out.splitlines() if line.startswith("| Y")]
    return {r[0].strip(): [c.strip() for c in r[1:]] for r in rows}


def test_replay_easy_handeye2(cell, tmp_path, capsys):
    doc = {"parameters": {"calibration_type": "eye_on_base"},
           "samples": [{"robot": _msg(R), "tracking": _msg(B)} for R, B in zip(tf.invert(cell.A), cell.B)]}
    (tmp_path / "cell.samples").write_text(yaml.safe_dump(doc))
    out = _replay(capsys, tmp_path / "cell.samples", "-m", "YKronT'", "-m", "YKronRT")
    assert "eye_to_hand, 15 samples" in out
    rows = _rows(out)
    assert set(rows) == {"YKronT'", "YKronRT"} and all(r[0] == "15" for r in rows.values())
    # Simulated with 1 mm lateral / 3 mm depth noise: residuals of a few mm.
    assert all(0.5 < float(r[2]) < 6 for r in rows.values())


def test_replay_easy_handeye_ros1_needs_and_takes_setup(cell, tmp_path, capsys):
    doc = {"hand_world_samples": [_msg(R) for R in tf.invert(cell.A)],
           "camera_marker_samples": [_msg(B) for B in cell.B]}
    (tmp_path / "samples.yaml").write_text(yaml.safe_dump(doc))
    assert main(["replay", str(tmp_path / "samples.yaml")]) == 1
    assert "pass setup=" in capsys.readouterr().err
    out = _replay(capsys, tmp_path / "samples.yaml", "--setup", "eye_to_hand")
    # The default solver is calibrate's: auto; one solver, no comparison table (but with --verbose).
    assert "eye_to_hand, 15 samples); result of auto" in out and "| auto |" not in out and not _rows(out)
    assert "| auto | 15 |" in _replay(capsys, tmp_path / "samples.yaml", "--setup", "eye_to_hand", "--verbose")


def test_replay_industrial_calibration(capsys):
    out = _replay(capsys, DATA / "circle_grid" / "cal_data.yaml", "-m", "YKronT'", "-v")
    assert "eye_in_hand, 15 samples" in out
    assert float(_rows(out)["YKronT'"][2]) == pytest.approx(10.1, abs=0.5)   # mm, as in tests/regression


def test_replay_pose_streams(capsys):
    out = _replay(capsys, DATA / "ethz" / "robot_arm_sim", "-m", "YKronT'", "-v")
    assert "eye_in_hand" in out
    assert float(_rows(out)["YKronT'"][2]) < 1.6   # 1.22 mm, as in tests/regression


def test_an_unknown_source_names_every_known_format_first_a_handeye_session(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["replay", str(tmp_path / "empty")]) == 1
    err = capsys.readouterr().err
    assert "no known sample format; known: a handeye session (a directory with session.json), or " in err
    assert len(err.strip().splitlines()) == 1
