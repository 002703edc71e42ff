"""replay: re-solve a session with several solvers and print the comparison table."""

import numpy as np
import pytest

from handeye.app import exit_status
from handeye.app.cli import main
from handeye.app.runs.replay import format_table, replay
from handeye.app.session import SessionWriter, read_session
from handeye.calib.observation import Observation
from handeye.calib.simulate import realistic_cell
from tests.app.verdict_status import printed_status


def _write_sim_session(root, setup="eye_to_hand", n=25, seed=0):
    d = realistic_cell(n, np.random.default_rng(seed), setup=setup)
    key = "T_base_cam" if setup == "eye_to_hand" else "T_flange_cam"
    truth = {key: d.Y if setup == "eye_to_hand" else d.X}
    with SessionWriter.create(root, setup, truth=truth, source="test") as w:
        for i in range(n):
            w.add_sample(Observation(i, float(i), d.A[i], d.points[i], d.point_cov[i], d.B[i], None))
        w.add_skip(99.0, "marker not found")
    return w.path, d


def test_replay_table_all_solvers(tmp_path, capsys):
    path, _ = _write_sim_session(tmp_path)
    rc = main(["replay", str(path), "-m", "all", "--refine"])
    out = capsys.readouterr().out
    assert rc == printed_status(out), out
    for m in ("YKronT'", "YQuatT'", "XKronRT", "YAxisR"):
        assert f"| {m} |" in out
    assert "err [mm]" in out and "eye_to_hand, 25 samples" in out


def test_replay_recovers_truth_both_setups(tmp_path):
    for setup in ("eye_to_hand", "eye_in_hand"):
        path, _ = _write_sim_session(tmp_path / setup, setup=setup, n=30, seed=1)
        s = read_session(path)
        key = "T_base_cam" if setup == "eye_to_hand" else "T_flange_cam"
        rows = replay(s.observations, s.setup, ["YKronT'", "YQuatT'"], refine=True, truth=s.truth[key])
        for r in rows:
            assert r.error is None, r.error
            deg, mm = r.truth_error
            assert mm < 5.0 and deg < 1.0, (setup, r.method, mm, deg)
        assert "| YKronT' |" in format_table(rows, setup)


def test_replay_reports_failing_solver_row(tmp_path):
    """A pose-based solver on a point-only session fails in its row; the rest still run."""
    d = realistic_cell(10, np.random.default_rng(2))
    with SessionWriter.create(tmp_path, "eye_to_hand") as w:
        for i in range(10):
            w.add_sample(Observation(i, float(i), d.A[i], d.points[i], d.point_cov[i]))
    rows = replay(read_session(w.path).observations, "eye_to_hand", ["YKronT'", "XKronRT"])
    assert rows[0].error is None and rows[1].result is None and rows[1].error
    assert "failed:" in format_table(rows, "eye_to_hand")


def _write_grid_session(root, setup, n=40, seed=3):
    """A session of a grid recording: every sample at one tool orientation (realistic cell, no rotation)."""
    d = realistic_cell(n, np.random.default_rng(seed), setup=setup, angle_range=0.0)
    key = "T_base_cam" if setup == "eye_to_hand" else "T_flange_cam"
    with SessionWriter.create(root, setup, truth={key: d.Y if setup == "eye_to_hand" else d.X}, source="test") as w:
        for i in range(n):
            w.add_sample(Observation(i, float(i), d.A[i], d.points[i], d.point_cov[i]))
    return w.path, d


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_replay_of_a_grid_gives_what_it_determines(tmp_path, capsys, setup):
    """A grid recording (the tool never turns) is answered, with a warning naming what is open and how to close
    it, instead of the closed forms' refusal; --marker-offset (mm) completes it: no warning, the truth found."""
    path, d = _write_grid_session(tmp_path, setup)
    assert main(["replay", str(path), "--verbose"]) == exit_status.WARN
    out = capsys.readouterr().out
    assert out.splitlines()[2].startswith("WARN") and "are not separated (the tool never turned)" in out
    assert "its error over the workspace is unknown while part of the answer is open" in out
    assert "| auto | 40 |" in out and "give --marker-offset X,Y,Z" in out
    offset = (d.X if setup == "eye_to_hand" else d.Y)[:3, 3] * 1e3
    rc = main(["replay", str(path), "--verbose", "--marker-offset", ",".join(f"{v:.3f}" for v in offset)])
    out = capsys.readouterr().out
    assert rc == printed_status(out), out
    assert "not separated" not in out
    row = next(line for line in out.splitlines() if line.startswith("| auto |"))
    err_mm, err_deg = (float(c) for c in row.split("|")[-5:-3])
    assert err_mm < 5.0 and err_deg < 0.5, row


def test_replay_takes_the_marker_offset_from_the_config(tmp_path, capsys):
    """``[marker] offset_m`` of ``-c CONFIG`` completes a grid as --marker-offset does; a bad flag is refused."""
    path, d = _write_grid_session(tmp_path, "eye_to_hand")
    config = tmp_path / "cell.toml"
    config.write_text("[marker]\noffset_m = [" + ", ".join(f"{v:.6f}" for v in d.X[:3, 3]) + "]\n")
    rc = main(["replay", str(path), "-c", str(config)])
    out = capsys.readouterr().out
    assert rc == printed_status(out) and "not separated" not in out
    with pytest.raises(SystemExit) as e:
        main(["replay", str(path), "--marker-offset", "1,2"])
    assert e.value.code == 2 and "expected X,Y,Z in mm" in capsys.readouterr().err
