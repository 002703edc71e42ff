"""The month simulation (`handeye.calib.simulate_month`): what it adds to the shift's is what the monitor is judged against
over a month, so each part is checked against the truth it returns."""

import dataclasses

import numpy as np
import pytest

from handeye.calib import simulate
from handeye.calib import transforms as tf
from handeye.calib.robot_error import ur_forward
from handeye.calib.setup import Setup
from handeye.calib.simulate_month import DAY_S, Month, month_stream

QUIET = simulate.RealisticProfile(depth_scale=0.0, depth_offset=0.0, focal_scale=0.0, misregistration_px=0.0)


def month_of(setup, month, seed=0, profile=QUIET):
    real = simulate.realistic_profile(30, np.random.default_rng([seed, 1]), profile, setup=setup)
    return real, month_stream(real, month, np.random.default_rng([seed, 2]), profile)


@pytest.mark.parametrize("setup", [Setup.EYE_TO_HAND, Setup.EYE_IN_HAND])
def test_each_stop_has_its_own_error_beyond_the_dh_error_at_every_visit(setup):
    month = Month(days=1.0, stops=6, stop_error_m=2e-3, thermal_mm=0.0, thermal_deg=0.0, walk_mm_per_sqrt_h=0.0,
                  bumps=())
    real, m = month_of(setup, month)
    kin = real.kinematics
    dh_only = ur_forward(m.q_stops, kin["d"], kin["a"], kin["alpha"], kin["offsets"])
    beyond = m.A_true_stops[:, :3, 3] - dh_only[:, :3, 3]
    assert 1e-3 < np.sqrt(np.mean(beyond ** 2)) < 3e-3
    # The points repeat at each stop up to the camera's noise: their mean over the day is where the stop's error puts
    # the marker, not where its nominal or DH-only pose would.
    off, off_dh = [], []
    for k in range(month.stops):
        seen = m.points[m.stop == k].mean(axis=0)
        if setup == Setup.EYE_TO_HAND:
            expected = (tf.invert(m.C[0]) @ m.A_true_stops[k] @ real.data.X)[:3, 3]
            dh_point = (tf.invert(m.C[0]) @ dh_only[k] @ real.data.X)[:3, 3]
        else:
            expected = (tf.invert(m.A_true_stops[k] @ m.C[0]) @ real.data.Y)[:3, 3]
            dh_point = (tf.invert(dh_only[k] @ m.C[0]) @ real.data.Y)[:3, 3]
        off.append(np.linalg.norm(seen - expected))
        off_dh.append(np.linalg.norm(seen - dh_point))
    # 480 visits average the point noise (3 mm along the ray) to 0.14 mm
    assert max(off) < 0.5e-3
    assert np.sqrt(np.mean(np.square(off_dh))) > 3 * np.sqrt(np.mean(np.square(off)))


@pytest.mark.parametrize("setup", [Setup.EYE_TO_HAND, Setup.EYE_IN_HAND])
def test_the_mount_breathes_daily_within_its_amplitude_and_is_bumped_on_its_days(setup):
    month = Month(days=4.0, thermal_mm=1.5, thermal_deg=0.0, walk_mm_per_sqrt_h=0.0, bumps=((2.5, 5.0, 0.0),))
    real, m = month_of(setup, month)
    if setup == Setup.EYE_TO_HAND:
        shift = m.C[:, :3, 3] - real.data.Y[:3, 3]
    else:
        shift = (tf.invert(real.data.X) @ m.C)[:, :3, 3]
    size = np.linalg.norm(shift, axis=1)
    before = m.t < 2.5 * DAY_S
    assert size[before].max() == pytest.approx(1.5e-3, rel=0.01)
    # a daily cycle: a day later the mount is back where it was
    day = int(DAY_S / month.sample_s)
    assert np.abs(shift[day:2 * day] - shift[:day]).max() < 1e-9
    assert list(m.bumped) == [int(2.5 * DAY_S / month.sample_s)]
    b = m.bumped[0]
    assert np.linalg.norm(shift[b] - shift[b - 1]) == pytest.approx(5e-3, abs=0.05e-3)


def test_the_eye_in_hand_profile_has_the_realistic_robot_and_camera_errors():
    real = simulate.realistic_profile(30, np.random.default_rng(3), setup=Setup.EYE_IN_HAND)
    d = real.data
    assert d.setup == Setup.EYE_IN_HAND
    assert real.robot_rms_m > 0.2e-3
    # the camera sees the static marker through its systematic errors: measured = camera.measure(true)
    ideal = dataclasses.replace(simulate.RealisticProfile(), depth_scale=0.0, depth_offset=0.0, focal_scale=0.0)
    again = simulate.realistic_profile(30, np.random.default_rng(3), ideal, setup=Setup.EYE_IN_HAND)
    np.testing.assert_allclose(real.camera.measure(again.data.points), real.data.points, atol=1e-9)
    assert np.all(d.B_true[:, 2, 3] > 0.3)
    np.testing.assert_allclose(d.A_true @ d.X @ d.B_true, np.broadcast_to(d.Y, d.B_true.shape), atol=1e-9)


def test_a_composed_production_runs_one_program_per_shift_each_with_its_own_stops():
    month = Month(days=3.0, stops=3, programs=4, program_h=8.0, thermal_mm=0.0, thermal_deg=0.0,
                  walk_mm_per_sqrt_h=0.0, bumps=())
    real, m = month_of(Setup.EYE_TO_HAND, month)
    assert len(m.A_stops) == len(m.q_stops) == 12
    per_shift = int(8 * 3600 / month.sample_s)
    programs = []
    for k in range(9):
        stops = m.stop[k * per_shift:(k + 1) * per_shift]
        program = stops[0] // 3
        # one program a shift, its stops in turn from the shift's start
        assert np.array_equal(stops, program * 3 + np.arange(per_shift) % 3)
        programs.append(program)
    assert len(set(programs)) > 1
    # the samples are where their stop is: the marker point follows the stop, not the sample's index
    first, again = np.flatnonzero(m.stop == m.stop[-1])[[0, -1]]
    assert np.linalg.norm(m.points[first] - m.points[again]) < 0.02


def test_a_single_program_visits_its_stops_in_turn():
    _, m = month_of(Setup.EYE_TO_HAND, Month(days=0.5, stops=5, bumps=()))
    assert np.array_equal(m.stop, np.arange(len(m.t)) % 5)
