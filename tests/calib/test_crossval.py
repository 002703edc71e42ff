"""handeye.calib.crossval.cross_validate: held-out prediction error, observed vs predicted."""

import numpy as np
import pytest

from handeye.calib.crossval import CrossValidation, cross_validate
from handeye.calib.errors import CalibrationError, InsufficientDataError
from handeye.calib.simulate import realistic_cell


def test_leave_one_out_observed_matches_predicted_on_the_plain_cell():
    rng = np.random.default_rng(7)
    d = realistic_cell(25, rng)
    cv = cross_validate("YKronT'", d.A, d.points, point_cov=d.point_cov, refine=True)
    assert isinstance(cv, CrossValidation) and cv.n_folds == 25 and cv.failed_folds == 0
    assert cv.errors.shape == (25,) and np.all(np.isfinite(cv.errors))
    # Noise is 1 mm lateral, 3 mm along the ray: held-out points are predicted to ~3.3 mm.
    assert 0.002 < cv.observed_rms < 0.005
    assert 1 / 1.5 < cv.ratio < 1.5


def test_k_fold_and_auto():
    rng = np.random.default_rng(8)
    d = realistic_cell(30, rng, robot_noise=(0.0005, 0.0005))
    cv = cross_validate("auto", d.A, d.points, folds=5, rng=np.random.default_rng(0))
    assert cv.n_folds == 5 and np.all(np.isfinite(cv.errors))
    assert 1 / 1.5 < cv.ratio < 1.5


def test_depth_bias_shows_in_the_held_out_error_of_the_plain_model():
    """A 2% depth scale error: the paper's model predicts held-out points worse than auto, which corrects it."""
    rng = np.random.default_rng(9)
    d = realistic_cell(30, rng)
    p = d.points * 1.02
    plain = cross_validate("YKronT'", d.A, p, refine=True)
    auto = cross_validate("auto", d.A, p)
    assert auto.observed_rms < 0.8 * plain.observed_rms


def test_bad_arguments_are_typed_errors():
    rng = np.random.default_rng(1)
    d = realistic_cell(10, rng)
    with pytest.raises(CalibrationError):
        cross_validate("YKronT'", d.A, d.points, folds=1)
    with pytest.raises(CalibrationError):
        cross_validate("nope", d.A, d.points)
    with pytest.raises(InsufficientDataError):
        cross_validate("YKronT'", d.A[:2], d.points[:2])
