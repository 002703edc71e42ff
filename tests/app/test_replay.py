"""replay: re-solve a session with several solvers and print the comparison table."""

import numpy as np

from app.cli import main
from app.runs.replay import format_table, replay
from app.session import SessionWriter, read_session
from calib.observation import Observation
from calib.simulate import realistic_cell


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
    assert main(["replay", str(path), "-m", "all", "--refine"]) == 0
    out = capsys.readouterr().out
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
