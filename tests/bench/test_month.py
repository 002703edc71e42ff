"""The month benchmark (`bench.month`) on a short month: it scores against the truth it simulates."""

import numpy as np
import pytest
import yaml

from bench import month
from bench.shift import workspace_error
from handeye.app.cli import main
from handeye.app.session import read_session
from handeye.calib import simulate, solve
from handeye.calib import transforms as tf
from handeye.calib.problem import CalibrationProblem
from handeye.calib.setup import Setup


def test_a_short_month_is_scored_per_day_with_its_bumps_and_alarms():
    spec = month.CellSpec(0, Setup.EYE_TO_HAND, False, 2.0, 4, 0.8)
    run = month.run_cell(spec)
    # a bump in each of the four half-days "weeks", each flagged, none falsely
    assert len(run.bumped) == 4 and len(run.moved) >= 4
    row = month.cell_row(run)
    assert row[0] == "eye-to-hand, poses only, seed 0"
    assert row[-5] == 0 and row[-4] == f"4/4 ({sum(run.limits):.1f})" and row[-3] == "-"
    # the best test's chance of flagging each bump within 20 samples: these bumps it flags almost surely
    assert len(run.limits) == 4 and all(0.5 < p <= 1.0 for p in run.limits), run.limits
    assert set(np.unique(run.day)) == {0, 1}
    # the settled mask leaves out the 40 samples after each bump (scored every SCORE_EVERY)
    assert (~run.settled).sum() == 4 * 40 // month.SCORE_EVERY
    assert np.all(run.error_mm > 0) and np.all(run.sigma_mm > 0)
    days = month.day_rows([run])
    assert [d[0] for d in days] == [0, 1]
    assert "1 cells" in month.summary([run])


def test_the_bumps_flagged_late_or_never_are_listed_with_the_limits_chance():
    assert month.late_text([3, None, None, 7], [None, 66, None, None], [0.9, 0.2, 0.1, 0.8]) == "66 (20%), never (10%)"
    assert month.late_text([3], [None], [0.9]) == "-"


def test_the_oracle_registers_every_sample_since_the_last_bump():
    spec = month.CellSpec(1, Setup.EYE_IN_HAND, False, 1.0, 4, 0.8)
    rng = np.random.default_rng(7)
    m = month.month_of(spec, rng)
    prof = simulate.RealisticProfile(pose_error_m=m.stop_error_m)
    real = simulate.realistic_profile(month.CALIBRATION_POSES, rng, prof, distance=0.8, setup=spec.setup)
    d = real.data
    problem = CalibrationProblem.from_arrays(d.A, d.points, setup=spec.setup, point_cov=d.point_cov)
    result = solve("auto", problem, rng=rng)
    stream = month.month_stream(real, m, rng, prof)
    P = simulate.workspace_points(real, 50, rng)
    first, second = stream.bumped[:2]
    scored = np.array([5, first - 1, first + 9, second - 1, second + 30])
    got = month.oracle_errors(real, result, stream, P, scored)
    assert np.isnan(got[:2]).all()       # nothing to re-learn before the first bump
    for k, (b, i) in zip((2, 3, 4), ((first, first + 9), (first, second - 1), (second, second + 30))):
        # eye-in-hand: the camera points registered to the marker's in the flange frame give T_flange_cam
        A = np.linalg.inv(stream.A_stops[stream.stop[b:i + 1]])
        parent = A[:, :3, :3] @ result.Y[:3, 3] + A[:, :3, 3]
        C = tf.register_points(result.camera_correction.correct(stream.points[b:i + 1]), parent)
        want = workspace_error(C, result.camera_correction, real.camera, stream.C[i], P) * 1e3
        assert got[k] == pytest.approx(want, rel=1e-6)
    # and a late oracle knows the camera: within a few mm of the truth, far from its error before the bump
    assert got[4] < 5.0


@pytest.mark.parametrize("setup, joints", [(Setup.EYE_TO_HAND, True), (Setup.EYE_IN_HAND, False)])
def test_a_cells_sessions_replay_through_the_monitor_as_the_benchmark_ran_it(tmp_path, capsys, setup, joints):
    spec = month.CellSpec(0, setup, joints, 0.5, 4, 0.8)
    run = month.run_cell(spec, sessions=tmp_path)
    cell = tmp_path / spec.directory
    assert spec.directory == ("eye-to-hand_joints_seed-0" if joints else "eye-in-hand_poses-only_seed-0")
    calibration, samples = read_session(cell / "calibration"), read_session(cell / "month")
    assert len(calibration.observations) == month.CALIBRATION_POSES and len(samples.observations) == 1440
    assert all((o.joints is not None) == joints for o in samples.observations[:10] + calibration.observations[:10])
    assert samples.observations[0].t > calibration.observations[-1].t + 3000.0
    out = tmp_path / "replay"
    assert main(["replay", str(cell / "month"), "--monitor", "--reference", str(cell / "calibration"), "--out",
                 str(out)]) == 3
    alarms = yaml.safe_load((out / "alarms.yaml").read_text())
    moved = [a["sample"] for a in alarms["alarms"] if a["alarm"] == "moved"]
    # The replay arms from its own solve of the calibration session: each bump the benchmark's engine flagged
    # within 20 samples the replay flags within 20 too, and it raises no other moved alarm.
    flagged = [b for b in run.bumped if any(0 <= m - b <= 20 for m in run.moved)]
    assert flagged and all(any(0 <= m - b <= 20 for m in moved) for b in flagged), (run.bumped, run.moved, moved)
    assert len(moved) == len(run.moved), (run.moved, moved)
    capsys.readouterr()
