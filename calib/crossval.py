"""Cross-validation of a calibration method: held-out prediction error of the marker point.

Each fold is solved without its samples; the held-out samples' marker points
are predicted from their robot poses (``p_i = C^-1 M_i t_K``, paper eq. 5 in
the camera frame, with the camera correction of an ``"auto"`` result applied)
and compared to the measured ones. The predicted error of a held-out point is
``sqrt(trace(Sigma_i + J_i Cov J_i^T))``: its measurement noise (the noise
levels of `handeye.calib.model`, estimated on the training samples) plus the
uncertainty of the calibration itself (inverse information of the model at the
training estimate). Observed and predicted agree for an honest model.

Setups: eye-to-hand ``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand
``X = T_flange_cam``, ``Y = T_base_marker`` (``A_i X = Y B_i``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from handeye.calib import model
from handeye.calib.api import solve
from handeye.calib.diagnostics import estimate_noise
from handeye.calib.errors import CalibrationError, InsufficientDataError
from handeye.calib.methods import is_auto, resolve_method
from handeye.calib.problem import CalibrationProblem, as_problem


@dataclass(frozen=True)
class CrossValidation:
    """Held-out prediction error of one method on one data set.

    Attributes
    ----------
    method : str
    n_folds : int
        Number of folds (N for leave-one-out).
    observed_rms : float
        RMS held-out prediction error of the marker point, m.
    predicted_rms : float
        RMS the model predicts for it, m.
    errors : ndarray, shape (N,)
        Held-out prediction error per sample, m (NaN where the fold failed).
    predicted : ndarray, shape (N,)
        Predicted RMS error per sample, m.
    failed_folds : int
        Folds whose training set could not be solved.
    """

    method: str
    n_folds: int
    observed_rms: float
    predicted_rms: float
    errors: np.ndarray
    predicted: np.ndarray
    failed_folds: int = 0

    @property
    def ratio(self) -> float:
        """Observed / predicted held-out RMS (1 for an honest model)."""
        return self.observed_rms / self.predicted_rms if self.predicted_rms > 0 else float("inf")


def fold_indices(n: int, folds: int | None, rng: np.random.Generator | None = None) -> list[np.ndarray]:
    """Held-out index sets of `cross_validate`: one per sample (None), else ``folds`` random parts of ``n``."""
    if folds is None or folds >= n:
        return [np.array([i]) for i in range(n)]
    if not isinstance(folds, (int, np.integer)) or folds < 2:
        raise CalibrationError(f"folds must be None (leave-one-out) or an integer >= 2, got {folds!r}")
    order = (rng if rng is not None else np.random.default_rng(0)).permutation(n)
    return [np.sort(part) for part in np.array_split(order, folds)]


def _prediction(result, train: CalibrationProblem, A_test):
    """Predicted points of the held-out samples and their predicted RMS error."""
    setup, A_train, B_train = train.setup, train.A, train.B
    theta = result.camera_correction.as_array()
    auto = result.auto
    C, K, M_test = model.split(result.X, result.Y, A_test, setup)
    pred = model.predict_points(C, K[:3, 3], M_test, theta)
    # Noise model at the training estimate: camera shape + robot error at the estimated levels.
    shape_train, _ = model.point_shape(B_train, train.point_cov)
    M_train = model.split(result.X, result.Y, A_train, setup)[2]
    use_rot = (B_train.ndim == 3 and result.marker_rotation_known
               and (auto is None or "orientations" in auto.measurements))
    if auto is None:
        # A paper method: the noise levels of the data at its estimate.
        levels = estimate_noise(result.X, result.Y, train, marker_rotation_known=result.marker_rotation_known)
    else:
        levels = auto.noise
    if levels.rotation is None:
        use_rot = False
    free = ([auto.camera_correction[name].estimated for name in model.CAMERA_PARAMS] if auto is not None
            else [False] * 3)
    cof_train = model.robot_cofactor(C, K, M_train, setup)
    Bp = B_train if use_rot else (B_train if B_train.ndim == 2 else B_train[:, :3, 3])
    prob = model.Linearization(M_train, Bp, model.whitener(levels.point_cov(shape_train, cof_train)),
                         sigma_rot=levels.rotation, free=free)
    cov = np.linalg.pinv(model.information(prob, C, K, theta))
    test = model.Linearization(M_test, np.zeros((len(A_test), 3)), np.broadcast_to(np.eye(3), (len(A_test), 3, 3)),
                         sigma_rot=levels.rotation, free=free)
    J = test.raw(C, K, theta)[2]
    if prob.rotations:
        # The training problem has the marker rotation in its parameters; the point does not depend on it.
        J = np.concatenate([J[:, :, :6], np.zeros((len(J), 3, 3)), J[:, :, 6:]], axis=2)
    return pred, J, cov, levels


def cross_validate(method: str, problem, B=None, *, folds: int | None = None, rng: np.random.Generator | None = None,
                   refine: bool = False, robust: bool = False, camera_correction: str | None = None,
                   **arrays) -> CrossValidation:
    """Held-out prediction error of the marker point for ``calib.solve(method, ...)``.

    Parameters
    ----------
    method : str
        ``"auto"`` or a paper method name (`handeye.calib.api.METHODS`).
    problem : CalibrationProblem
        The samples; or the array form of `calib.solve` (``A``, ``B`` and
        ``setup``, ``point_cov``, ``robot_shared_error``).
    folds : int, optional
        Number of folds; None (default) = leave-one-out.
    rng : numpy.random.Generator, optional
        Assigns samples to folds (k-fold) and is passed to the solver.
    refine, robust, camera_correction
        Passed to `calib.solve` for each fold.

    Returns
    -------
    CrossValidation
        ``observed_rms`` and ``predicted_rms`` (m) and the per-sample errors.

    Raises
    ------
    CalibrationError, InsufficientDataError
        Bad input, or no fold could be solved.
    """
    if not is_auto(method):
        resolve_method(method)
    problem = as_problem(problem, B, **arrays)
    setup, A, B, point_cov = problem.setup, problem.A, problem.B, problem.point_cov
    n = problem.n
    if n < 3:
        raise InsufficientDataError(f"cross-validation needs at least 3 samples, got {n}")
    errors = np.full(n, np.nan)
    predicted = np.full(n, np.nan)
    parts = fold_indices(n, folds, rng)
    failed = 0
    p_all = B if B.ndim == 2 else B[:, :3, 3]
    for test in parts:
        train = problem.subset(np.setdiff1d(np.arange(n), test))
        try:
            res = solve(method, train, refine=refine, robust=robust, rng=rng, camera_correction=camera_correction)
            pred, J, cov, levels = _prediction(res, train, A[test])
        except CalibrationError:
            failed += 1
            continue
        shape_test = model.point_shape(p_all[test], None if point_cov is None else point_cov[test])[0]
        C, K, M_test = model.split(res.X, res.Y, A[test], setup)
        noise_cov = levels.point_cov(shape_test, model.robot_cofactor(C, K, M_test, setup))
        total = noise_cov + J @ cov @ np.swapaxes(J, 1, 2)
        errors[test] = np.linalg.norm(p_all[test] - pred, axis=1)
        predicted[test] = np.sqrt(np.trace(total, axis1=1, axis2=2))
    ok = np.isfinite(errors)
    if not ok.any():
        raise InsufficientDataError(f"no fold of {method!r} could be solved")
    name = method if isinstance(method, str) else str(method)
    return CrossValidation(
        method=name,
        n_folds=len(parts),
        observed_rms=float(np.sqrt(np.mean(errors[ok] ** 2))),
        predicted_rms=float(np.sqrt(np.mean(predicted[ok] ** 2))),
        errors=errors,
        predicted=predicted,
        failed_folds=failed,
    )
