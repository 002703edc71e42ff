"""The monitoring engine left alone for days on a still camera (issue 42): what repeated visits of the same few stops
may and may not teach it, checked against the truth, on samples drawn from the engine's own measurement model (so
that only the engine's handling of them is judged)."""

import numpy as np
import pytest

from bench.shift import workspace_error
from handeye.calib import simulate, solve
from handeye.calib.model import CameraCorrection
from handeye.calib.monitor import MonitorEngine, MonitorSettings
from handeye.calib.monitor.kernels import parts, sample_floats
from handeye.calib.noise import default_point_cov
from handeye.calib.problem import CalibrationProblem
from handeye.calib.robot_error import UR10_DH, ur_forward
from handeye.calib.setup import Setup
from handeye.calib.simulate_month import DAY_S

SAMPLE_S = 30.0


def _still_cell(seed: int, settings: MonitorSettings, stops: int = 4):
    """An eye-in-hand cell calibrated by ``auto`` from 30 poses, its engine, and a program of ``stops`` stops whose
    samples follow the engine's model at the true camera, marker and camera parameters (no stop repeats an error of
    its own), with the point noise at the calibration's level. Returns ``(engine, next_sample, score)``."""
    rng = np.random.default_rng([seed, 42])
    real = simulate.realistic_profile(30, rng, simulate.RealisticProfile(), setup=Setup.EYE_IN_HAND)
    d = real.data
    problem = CalibrationProblem.from_arrays(d.A, d.points, setup=Setup.EYE_IN_HAND, point_cov=d.point_cov)
    engine = MonitorEngine(settings)
    engine.arm(solve("auto", problem, rng=rng), problem)
    q = simulate.production_stops(real, stops, 10.0, rng)
    A = ur_forward(q, UR10_DH["d"], UR10_DH["a"], UR10_DH["alpha"], np.zeros(6))
    truth = parts(d.X), tuple(d.Y[:3, 3]), tuple(real.camera.as_array())
    h = [np.array(sample_floats(truth[0], truth[1], tuple(a[:3].ravel().tolist()), truth[2], False)[0]) for a in A]
    cov = default_point_cov(np.array(h))
    noise = [np.linalg.cholesky(engine.model.point_scale * c) for c in cov]
    P = simulate.workspace_points(real, 100, rng)

    def next_sample(i: int):
        j = i % stops
        return engine.update(i * SAMPLE_S, A[j], h[j] + noise[j] @ rng.normal(size=3), cov[j])

    def score():
        """The live workspace error against the truth and its stated 1-sigma, mm; the estimate's points."""
        f = engine.filter
        err = workspace_error(f.C, engine.camera_correction, real.camera, d.X, P) * 1e3
        where = f.C[:3, :3] @ CameraCorrection(*f.u[3:6]).correct(engine.reference.workspace).T + f.C[:3, 3:]
        return err, engine.workspace.sigma(f.C, f.u[3:6], f.P) * 1e3, where.T

    return engine, next_sample, score


@pytest.mark.parametrize("seed", [0, 1])
def test_a_still_eye_in_hand_camera_stays_where_its_stops_leave_it(seed):
    # Stops whose own error may be large (2 mm) tell almost nothing of where the camera is: over eight days of a still
    # camera the estimate must stay put, not walk along what the stops cannot see. (With the Jacobians re-taken at
    # every estimate it walked 2.7-5.1 mm in a week, its stated 1-sigma 3.6-4.0 mm.)
    engine, next_sample, score = _still_cell(seed, MonitorSettings(stop_error_mm=2.0))
    per_day = int(DAY_S / SAMPLE_S)
    errors = []
    for i in range(8 * per_day):
        upd = next_sample(i)
        assert not upd.alarm
        if i % per_day == per_day - 1:
            errors.append(score())
    (first, sigma, where), (last, _, now) = errors[0], errors[-1]
    moved = np.sqrt(np.mean(np.sum((now - where) ** 2, axis=1))) * 1e3
    assert moved < 0.25 * sigma
    assert last < first + 0.25 * sigma



def _breathing_month_alarms(seed: int, days: float, thermal_mm: float, walk: float = 0.0) -> list:
    """The alarms of an eye-to-hand cell (the UR10's DH error, the camera's systematic errors) whose mount breathes a
    daily cycle of ``thermal_mm`` for ``days``, no bump, poses only: ``[(sample, alarm, drift_mm, message)]``."""
    from handeye.calib.simulate_month import Month, month_stream

    rng = np.random.default_rng([seed, 7])
    month = Month(days=days, thermal_mm=thermal_mm, walk_mm_per_sqrt_h=walk, bumps=())
    prof = simulate.RealisticProfile(pose_error_m=month.stop_error_m)
    real = simulate.realistic_profile(30, rng, prof)
    d = real.data
    problem = CalibrationProblem.from_arrays(d.A, d.points, setup=Setup.EYE_TO_HAND, point_cov=d.point_cov)
    engine = MonitorEngine(MonitorSettings())
    engine.arm(solve("auto", problem, rng=rng), problem)
    stream = month_stream(real, month, rng, prof)
    alarms = []
    for i in range(len(stream.t)):
        s = stream.stop[i]
        u = engine.update(stream.t[i], stream.A_stops[s], stream.points[i], stream.point_cov[i])
        if u.alarm:
            alarms.append((i, u.alarm, u.drift_mm, u.message))
    return alarms


def test_a_mount_that_breathes_to_the_tolerance_every_day_is_one_drifting_alarm():
    # A 2.5 mm daily thermal cycle against the 2 mm tolerance: the camera reaches the tolerance every day and comes
    # back. That is one *drifting* alarm the plant acts on (the level holds while it recurs), not one a day; and never
    # a *moved* one. (Before: one on each of the 6 days, predicted from the cycle's rising hour.)
    alarms = _breathing_month_alarms(0, days=6.0, thermal_mm=2.5)
    assert [a for a in alarms if a[1] == "moved"] == []
    drifting = [a for a in alarms if a[1] == "drifting"]
    assert len(drifting) == 1, [(i, round(mm, 2)) for i, _, mm, _ in drifting]


@pytest.mark.parametrize("seed, setup, stops, distance, programs", [
    (103, Setup.EYE_IN_HAND, 6, 1.0, 1),      # one program (issue 42: 4.95 over its month)
    (4, Setup.EYE_TO_HAND, 5, 0.8, 4),        # four programs of five stops, one per shift (10.8 over its month)
])
def test_a_pose_only_source_s_robot_error_shared_by_the_stops_stays_in_the_stated_sigma(seed, setup, stops, distance,
                                                                                       programs):
    """Samples without joints: the UR10's DH error puts a program's stops 0.5-2.3 mm off in common, which no
    number of visits tells from the camera. Taken as each stop's own error, the stops pulled the camera off while
    its stated 1-sigma shrank; held as one error field the stops share (`robot_accuracy_mm`), the error stays
    within its bound every day and within what the stated 1-sigma says (3 days of `bench.month`, 4 bumps).
    Measured: (error/sigma)^2 2.48 / 2.39 against 8.17 / 5.34 without it, median error 4.8 / 2.2 mm against
    7.2 / 2.5."""
    from bench import month

    spec = month.CellSpec(seed, setup, False, 3.0, stops, distance, programs)
    shared = month.run_cell(spec)
    own = month.run_cell(spec, MonitorSettings(robot_accuracy_mm=0.0))

    def nees(run):
        return float(np.mean((run.error_mm / run.sigma_mm)[run.settled] ** 2))

    assert all(shared.within(d) for d in range(3))
    assert nees(shared) < 4.0 < nees(own)
    assert np.median(shared.error_mm) < np.median(own.error_mm)
    assert len(shared.moved) >= len(shared.bumped)
