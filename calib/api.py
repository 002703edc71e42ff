"""The public entry point: ``solve(method, problem)`` (or its array form ``solve(method, A, B, ...)``) and
``solve_observations``; the table of methods (`handeye.calib.methods`) is re-exported here.

Setups. Eye-to-hand (static camera, marker on the flange):
``T_base_flange @ T_flange_marker = T_base_cam @ T_cam_marker``, the paper's
``A_i X = Y B_i`` (eq. 1) with ``X = T_flange_marker``, ``Y = T_base_cam``.
Eye-in-hand (camera on the flange, static marker):
``T_base_flange @ T_flange_cam @ T_cam_marker = T_base_marker`` with
``X = T_flange_cam``, ``Y = T_base_marker``. In both ``A = T_base_flange``
and ``B = T_cam_marker`` (or the marker center in the camera frame).

Example
-------
>>> from calib import CalibrationProblem, solve
>>> est = solve("YKronT'", A, points)            # doctest: +SKIP
>>> est.T_base_cam, est.residuals.rms_translation  # doctest: +SKIP
>>> problem = CalibrationProblem.from_arrays(A, B, point_cov=cov)  # doctest: +SKIP
>>> solve("auto", problem).auto.camera_correction  # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from handeye.calib import refine as rf
from handeye.calib import transforms as tf
from handeye.calib.auto import solve_auto
from handeye.calib.diagnostics import self_check
from handeye.calib.errors import CalibrationError, InsufficientDataError
from handeye.calib.methods import AUTO, AUTO_MIN_SAMPLES, METHODS, MethodInfo, check_applicable, closed_form, is_auto, \
    resolve_method
from handeye.calib.observation import Observation
from handeye.calib.problem import CalibrationProblem, as_problem, observations_to_arrays
from handeye.calib.result import CalibrationResult
from handeye.calib.robust import default_subset, robust_solve
from handeye.calib.setup import Setup

__all__ = ["AUTO", "METHODS", "MethodInfo", "CalibrationProblem", "closed_form", "observations_problem",
           "observations_to_arrays", "resolve_method", "solve", "solve_observations"]


def solve(method: str, problem, B=None, *, refine: bool = False, robust: bool = False,
          rng: np.random.Generator | None = None, camera_correction: str | None = None, **arrays) -> CalibrationResult:
    """Hand-eye calibration ``A_i X = Y B_i`` (paper eq. 1) with a method of Table I, or ``"auto"``.

    Pipeline: closed form (or ``handeye.calib.robust.robust_solve`` around it) ->
    ``handeye.calib.refine.refine`` on the inliers if asked -> covariance of the camera
    transform, of the estimator actually returned (see Returns).

    Parameters
    ----------
    method : str
        ``"auto"`` (`handeye.calib.auto.solve_auto`: every measurement the data
        carry, the best closed-form start, robust, refined with the extended
        model of `handeye.calib.model`: robot error, camera depth/focal correction,
        estimated noise levels; ``refine`` and ``robust`` do not apply), or a
        paper method: ``XAxisRX``, ``XQuatR*``, ``XKronR*``, ``XKronRT``, ``XKronT``,
        ``YAxisR``, ``YQuatR*``, ``YKronRT``, ``YQuatT'``, ``YKronT'``; also
        case-insensitive without ``'``/``*`` (``"ykront"``). See `METHODS`.
    problem : CalibrationProblem
        The validated samples (`handeye.calib.problem`). Array form: ``A`` (N, 4, 4)
        ``T_base_flange`` (m) here, ``B`` (N, 4, 4) ``T_cam_marker`` or (N, 3)
        marker centres in the camera frame (m) next, and the keywords of
        `CalibrationProblem.from_arrays` (``setup``, ``point_cov``,
        ``robot_shared_error``, ``marker_offset``, ``marker_offset_sigma``;
        the last three ``"auto"`` only). Eye-to-hand: ``X = T_flange_marker``,
        ``Y = T_base_cam``; eye-in-hand: ``X = T_flange_cam``, ``Y = T_base_marker``.
    refine : bool
        Maximum-likelihood refinement of the closed form (handeye.calib.refine).
    robust : bool
        Outlier rejection (handeye.calib.robust); ``result.inliers`` is then set.
    rng : numpy.random.Generator, optional
        For the robust sampler; ``default_rng(0)`` if not given, so results
        are reproducible.
    camera_correction : {"auto", "none", "depth", "depth+focal"}, optional
        Method ``"auto"`` only (default "auto"): which camera parameters to
        estimate (`handeye.calib.auto.solve_auto`). Likewise the problem's
        ``robot_shared_error`` applies to ``"auto"`` only.

    Returns
    -------
    CalibrationResult
        ``X``, ``Y`` (4x4), residuals per sample, ``cov`` (6x6, camera
        transform, rotation vector rad then translation m), ``self_check``
        and ``cov_kind``: "fisher" (refined: inverse Fisher information,
        `handeye.calib.refine.covariance`), "delta-analytic" (closed-form YKronT':
        first-order covariance of the estimator, `handeye.calib.refine.kron_t_prime_covariance`),
        "delta-numerical" (other closed forms up to `DELTA_METHOD_MAX_SAMPLES`
        samples, `handeye.calib.refine.delta_method_covariance`) or
        "fisher-optimistic" (other closed forms above that: the ML
        covariance, smaller than the closed form's true error).

    Raises
    ------
    CalibrationError
        Unknown method or setup, bad shapes, NaN/inf, non-rigid transforms,
        mismatched N, poses required but points given.
    InsufficientDataError
        Fewer samples than the method's minimum.
    DegenerateMotionError
        The motions do not determine every unknown (the message says what to
        add). ``"auto"`` raises it only when they determine too little to
        answer at all; when they leave just the split between the two
        translations open (a tool that never turns, or turns about one axis),
        it reports what they determine, given the open part held, and names
        the rest in ``result.undetermined`` (`handeye.calib.auto.determined`).
    """
    problem = as_problem(problem, B, **arrays)
    if is_auto(method):
        if problem.n < AUTO_MIN_SAMPLES:
            raise InsufficientDataError(f"auto needs at least {AUTO_MIN_SAMPLES} samples, got {problem.n}")
        return solve_auto(problem, rng=rng, camera_correction="auto" if camera_correction is None else camera_correction)
    if camera_correction is not None:
        raise CalibrationError(f"camera_correction applies to method 'auto' only, not {method!r}")
    if problem.robot_shared_error is not None:
        raise CalibrationError(f"robot_shared_error applies to method 'auto' only, not {method!r}")
    if problem.marker_offset is not None:
        raise CalibrationError(f"marker_offset applies to method 'auto' only, not {method!r}")
    return _solve_paper_method(resolve_method(method), problem, refine=refine, robust=robust, rng=rng)


def _solve_paper_method(info: MethodInfo, problem: CalibrationProblem, *, refine: bool, robust: bool,
                        rng: np.random.Generator | None) -> CalibrationResult:
    """`solve` with a method of Table I: closed form (robust around it if asked), refinement, covariance, self-check."""
    check_applicable(info, problem)
    if robust:
        # A subset must be solvable: XKronT needs 5 poses where the default subset has 4.
        subset = max(info.min_samples, default_subset(points=not problem.has_poses))
        result = robust_solve(lambda sub: closed_form(info, sub), problem, min_samples=subset,
                              rng=rng if rng is not None else np.random.default_rng(0))
    else:
        result = closed_form(info, problem)
    inliers = problem if result.inliers is None else problem.subset(result.inliers)
    if refine:
        refined = rf.refine(result, inliers)
        result = dataclasses.replace(refined, inliers=result.inliers)
    cov, kind = _covariance(info, result, inliers, refined=refine)
    try:
        check = self_check(result.X, result.Y, inliers, use_rotation=result.marker_rotation_known,
                           marker_rotation_known=result.marker_rotation_known)
    except CalibrationError:
        check = None  # the model's information is singular for these samples: no self-check, the result stands
    return dataclasses.replace(result, cov=cov, cov_kind=kind, self_check=check)


#: Above this many samples a closed form from poses gets the ML (Fisher)
#: covariance instead of the numerical delta method, whose 6N re-solves would
#: cost seconds; it is then over-confident (``cov_kind`` says so).
DELTA_METHOD_MAX_SAMPLES = 100


def _covariance(info: MethodInfo, result: CalibrationResult, problem: CalibrationProblem, *, refined: bool):
    """Covariance of the camera transform of ``result`` and how it was obtained (``cov_kind``).

    An ML estimate gets the inverse Fisher information ("fisher"). A closed
    form is less efficient, so it gets the first-order covariance of the
    estimator itself: analytic for YKronT' ("delta-analytic"), numerical for
    the pose-based methods up to `DELTA_METHOD_MAX_SAMPLES` ("delta-numerical"),
    else the Fisher one, labelled "fisher-optimistic".
    """
    if refined:
        return rf.covariance(result.X, result.Y, problem), "fisher"
    if info.needs == "points":
        return rf.kron_t_prime_covariance(result.X, result.Y, problem), "delta-analytic"
    if problem.n <= DELTA_METHOD_MAX_SAMPLES:
        def estimator(A_sub, B_sub):
            return info.function(A_sub, B_sub if problem.setup == Setup.EYE_TO_HAND else tf.invert(B_sub))

        return rf.delta_method_covariance(estimator, result.X, result.Y, problem), "delta-numerical"
    return rf.covariance(result.X, result.Y, problem), "fisher-optimistic"


def solve_observations(method: str, observations: Sequence[Observation], setup: Setup, *, refine: bool = False,
                       robust: bool = False, rng: np.random.Generator | None = None,
                       robot_shared_error=None, marker_offset=None, marker_offset_sigma=0.0) -> CalibrationResult:
    """Solve ``A_i X = Y B_i`` (paper eq. 1) for a list of samples with a named solver.

    Point methods (YKronT') get the depth-lifted marker centres ``point_cam``
    with their covariances; the others the marker poses ``T_cam_marker``
    (``METHODS[...].needs``). Samples lacking that measurement are left out.
    ``"auto"`` gets every measurement the samples carry
    (`CalibrationProblem.from_observations`); ``refine``/``robust`` do not
    apply, it always does both. ``robot_shared_error`` (``"auto"`` only):
    (N, 6, P), one row per observation. ``marker_offset`` (3,), m, and
    ``marker_offset_sigma``, m (``"auto"`` only): the known marker-side
    translation (`CalibrationProblem`).
    """
    problem = observations_problem(method, observations, setup, robot_shared_error=robot_shared_error,
                                   marker_offset=marker_offset, marker_offset_sigma=marker_offset_sigma)
    return solve(method, problem, refine=refine, robust=robust, rng=rng)


def observations_problem(method: str, observations: Sequence[Observation], setup: Setup, *,
                         robot_shared_error=None, marker_offset=None, marker_offset_sigma=0.0) -> CalibrationProblem:
    """The `CalibrationProblem` `solve_observations` solves with ``method``: the measurements it uses
    (``"auto"``: all the samples carry; a paper method: its ``needs``), samples lacking them left out, and the
    known marker offset (``"auto"`` only)."""
    measurements = "all" if is_auto(method) else resolve_method(method).needs
    return CalibrationProblem.from_observations(observations, setup, measurements=measurements,
                                                robot_shared_error=robot_shared_error, marker_offset=marker_offset,
                                                marker_offset_sigma=marker_offset_sigma)
