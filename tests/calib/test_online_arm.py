"""OnlineCalibrator.arm: a reference calibration arms the change detector at once."""

import numpy as np
import pytest

from calib import simulate
from calib import transforms as tf
from calib.errors import CalibrationError
from calib.online import OnlineCalibrator, OnlineConfig

N_REF = 12  # the small reference session: plain priming left the detector warming up for 30 samples


def _bump(rng, mm: float) -> np.ndarray:
    axis = rng.normal(size=3)
    return tf.from_rotvec_translation(np.zeros(3), mm * 1e-3 * axis / np.linalg.norm(axis))


@pytest.mark.parametrize("seed", range(5))
def test_reference_armed_alarm_within_20_samples_of_a_10mm_shift(seed):
    rng = np.random.default_rng(seed)
    d = simulate.realistic_cell(N_REF + 20, rng)
    pts = simulate.moved_camera_points(d, N_REF, _bump(rng, 10.0))
    cal = OnlineCalibrator(OnlineConfig())             # shipped defaults: bootstrap 10, warm-up 20
    assert cal.samples_until_armed == 10 + 20 + 2
    cal.arm(d.A[:N_REF], pts[:N_REF], d.point_cov[:N_REF])
    assert cal.samples_until_armed == 2 and cal.n_samples == N_REF
    rot, t = tf.pose_error(cal.camera_transform, d.Y)
    assert t < 0.01 and cal.cov is not None
    alarms = [i for i in range(N_REF, N_REF + 20) if cal.update(d.A[i], pts[i], d.point_cov[i]).alarm]
    assert alarms, "no alarm within 20 samples of a 10 mm shift"
    assert alarms[0] - N_REF < 20


def test_armed_reference_gives_no_false_alarm_on_an_unchanged_cell():
    rng = np.random.default_rng(11)
    d = simulate.realistic_cell(N_REF + 400, rng)
    cal = OnlineCalibrator(OnlineConfig())
    cal.arm(d.A[:N_REF], d.points[:N_REF], d.point_cov[:N_REF])
    ups = [cal.update(d.A[i], d.points[i], d.point_cov[i]) for i in range(N_REF, len(d.A))]
    assert not any(u.alarm for u in ups)
    assert cal.samples_until_armed == 0


def test_arm_rejects_too_few_or_bad_reference_samples():
    rng = np.random.default_rng(12)
    d = simulate.realistic_cell(8, rng)
    cal = OnlineCalibrator(OnlineConfig())
    with pytest.raises(CalibrationError, match="at least 6"):
        cal.arm(d.A[:5], d.points[:5])
    pts = d.points.copy()
    pts[3, 1] = np.nan
    with pytest.raises(CalibrationError):
        cal.arm(d.A, pts)
    assert cal.camera_transform is None
