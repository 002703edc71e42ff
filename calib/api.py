"""The public entry point: ``solve(method, A, B, ...)`` and the table of methods.

Setups. Eye-to-hand (static camera, marker on the flange):
``T_base_flange @ T_flange_marker = T_base_cam @ T_cam_marker``, the paper's
``A_i X = Y B_i`` (eq. 1) with ``X = T_flange_marker``, ``Y = T_base_cam``.
Eye-in-hand (camera on the flange, static marker):
``T_base_flange @ T_flange_cam @ T_cam_marker = T_base_marker`` with
``X = T_flange_cam``, ``Y = T_base_marker``. In both ``A = T_base_flange``
and ``B = T_cam_marker`` (or the marker center in the camera frame).

Example
-------
>>> from calib import solve, METHODS
>>> est = solve("YKronT'", A, points)            # doctest: +SKIP
>>> est.T_base_cam, est.residuals.rms_translation  # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from calib import refine as rf
from calib import solvers
from calib import transforms as tf
from calib.errors import CalibrationError, InsufficientDataError
from calib.observation import Observation
from calib.result import CalibrationResult, Residuals
from calib.auto import self_check, solve_auto
from calib.robust import default_subset, robust_solve
from calib.setup import Setup, check_setup


@dataclass(frozen=True)
class MethodInfo:
    """One row of the paper's Table I.

    Attributes
    ----------
    name : str
        The paper's name, e.g. ``"YKronT'"``.
    equation : str
        ``"AX=XB"`` (relative motions, eq. 2) or ``"AX=YB"`` (eq. 1).
    representation : str
        ``"axis-angle"``, ``"quaternion"`` or ``"Kronecker"``.
    solves : str
        Which equations are used: ``"R"`` rotation (then translation by eq. 5/6),
        ``"RT"`` both simultaneously, ``"T"`` translation only.
    paper_equations : tuple of int
        Equation numbers in the paper.
    reference : str
        Who proposed it ("this paper" for the proposed YQuatT'/YKronT').
    needs : str
        ``"poses"`` (B is (N, 4, 4)) or ``"points"`` (B is (N, 3); a pose stack
        is accepted and its translations used).
    min_samples : int
        Fewest samples the method accepts.
    """

    name: str
    equation: str
    representation: str
    solves: str
    paper_equations: tuple[int, ...]
    reference: str
    needs: str
    min_samples: int
    function: Callable = dataclasses.field(repr=False, compare=False)

    @property
    def marker_rotation_known(self) -> bool:
        return self.needs == "poses"


def _table() -> dict[str, MethodInfo]:
    rows = [
        ("XAxisRX", "AX=XB", "axis-angle", "R", (2, 18, 5), "Park & Martin 1994", "poses", 3, solvers.x_axis_rx),
        ("XQuatR*", "AX=XB", "quaternion", "R", (2, 9, 17, 5), "cf. Dornaika & Horaud 1998", "poses", 3,
         solvers.x_quat_r_star),
        ("XKronR*", "AX=XB", "Kronecker", "R", (2, 12, 17, 5), "cf. Shah 2013", "poses", 3, solvers.x_kron_r_star),
        ("XKronRT", "AX=XB", "Kronecker", "RT", (2, 16, 13), "Andreff et al. 2001", "poses", 3, solvers.x_kron_rt),
        ("XKronT", "AX=XB", "Kronecker", "T", (2, 13), "this paper (Table I)", "poses", 5, solvers.x_kron_t),
        ("YAxisR", "AX=YB", "axis-angle", "R", (9, 16, 6), "Zhuang et al. 1994", "poses", 3, solvers.y_axis_r),
        ("YQuatR*", "AX=YB", "quaternion", "R", (9, 17, 6), "Dornaika & Horaud 1998", "poses", 3,
         solvers.y_quat_r_star),
        ("YKronRT", "AX=YB", "Kronecker", "RT", (16, 13, 6), "Li et al. 2010", "poses", 3, solvers.y_kron_rt),
        ("YQuatT'", "AX=YB", "quaternion", "T", (10, 19), "this paper (proposed)", "poses", 3,
         solvers.y_quat_t_prime),
        ("YKronT'", "AX=YB", "Kronecker", "T", (13, 20), "this paper (proposed)", "points", 5,
         solvers.y_kron_t_prime),
    ]
    return {r[0]: MethodInfo(*r) for r in rows}


#: Every closed-form method of the paper's Table I, keyed by its printed name.
METHODS: dict[str, MethodInfo] = _table()

#: The name of the extended-model estimator (`calib.auto`).
AUTO = "auto"
#: Fewest samples ``"auto"`` accepts (its YKronT' start needs 5).
AUTO_MIN_SAMPLES = 5

_ALIASES = {name.lower().replace("'", "").replace("*", ""): name for name in METHODS}


def resolve_method(method: str) -> MethodInfo:
    """Look up a method by its paper name, or case-insensitively without ``'`` and ``*`` (``"ykront"``)."""
    if isinstance(method, str):
        key = method.strip().lower().replace("'", "").replace("*", "")
        if key in _ALIASES:
            return METHODS[_ALIASES[key]]
    raise CalibrationError(f"unknown method {method!r}; valid: {AUTO}, {', '.join(METHODS)}")


def _check_inputs(info: MethodInfo, A, B) -> tuple[np.ndarray, np.ndarray]:
    B = tf.as_real_array(B, "B")
    if info.needs == "poses" and B.ndim == 2:
        point_methods = ", ".join(m.name for m in METHODS.values() if m.needs == "points")
        raise CalibrationError(
            f"{info.name} needs marker poses B of shape (N, 4, 4), got points {np.shape(B)}; "
            f"point-only methods: {point_methods}"
        )
    A, B = solvers.check_measurements(A, B)
    _check_count(info, len(A))
    return A, B


def _check_count(info: MethodInfo, n: int) -> None:
    if n < info.min_samples:
        raise InsufficientDataError(f"{info.name} needs at least {info.min_samples} samples, got {n}")


def closed_form(method: str, A, B, *, setup: Setup = Setup.EYE_TO_HAND, validate: bool = True) -> CalibrationResult:
    """Run one closed-form method of Table I and wrap it in a CalibrationResult (no refinement, no cov).

    Parameters
    ----------
    method : str
        A name from `METHODS` (case-insensitive, ``'`` and ``*`` optional).
    A : array_like, shape (N, 4, 4)
        ``T_base_flange``.
    B : array_like, shape (N, 4, 4) or (N, 3)
        ``T_cam_marker`` poses, or marker points in the camera frame for
        YKronT' (a pose stack given to YKronT' contributes its translations).
    setup : {"eye_to_hand", "eye_in_hand"}
        Eye-to-hand: ``X = T_flange_marker``, ``Y = T_base_cam``.
        Eye-in-hand: ``X = T_flange_cam``, ``Y = T_base_marker``.
    validate : bool
        False when ``A`` and ``B`` are arrays `solvers.check_measurements`
        has passed already (as inside ``solve("auto")``): its checks cost
        ~0.25 ms at N = 1000. The sample count is checked either way.

    Returns
    -------
    CalibrationResult
        ``X``, ``Y``, per-sample residuals (eq. 4/5), ``cov`` None.
    """
    info = resolve_method(method)
    setup = check_setup(setup)
    if validate:
        A, B = _check_inputs(info, A, B)
    else:
        _check_count(info, len(A))
    return _closed_form(info, A, B, setup)


def _closed_form(info: MethodInfo, A: np.ndarray, B: np.ndarray, setup: str) -> CalibrationResult:
    if info.needs == "points":
        X, Y = solvers.y_kron_t_prime_unchecked(A, B[:, :3, 3] if B.ndim == 3 else B, setup)
    else:
        # Eye-in-hand A X B = Y is eq. 1 with B inverted: A X = Y B^-1.
        X, Y = info.function(A, B if setup == Setup.EYE_TO_HAND else tf.invert(B))
    # A and B were validated by the caller; X and Y come from a solver.
    trans, rot = solvers.residuals_unchecked(X, Y, A, B, setup, info.marker_rotation_known)
    return CalibrationResult(
        method=info.name,
        setup=setup,
        X=X,
        Y=Y,
        n_samples=len(A),
        residuals=Residuals(translation=trans, rotation=rot),
        marker_rotation_known=info.marker_rotation_known,
        info={"equation": info.equation, "paper_equations": info.paper_equations},
    )


def solve(
    method: str,
    A,
    B,
    *,
    setup: Setup = Setup.EYE_TO_HAND,
    refine: bool = False,
    robust: bool = False,
    point_cov=None,
    rng: np.random.Generator | None = None,
    camera_correction: str | None = None,
    robot_shared_error=None,
) -> CalibrationResult:
    """Hand-eye calibration ``A_i X = Y B_i`` (paper eq. 1) with a method of Table I, or ``"auto"``.

    Pipeline: validate -> closed form (or ``calib.robust.robust_solve`` around
    it) -> ``calib.refine.refine`` on the inliers if asked -> covariance of
    the camera transform, of the estimator actually returned (see Returns).

    Parameters
    ----------
    method : str
        ``"auto"`` (`calib.auto.solve_auto`: every measurement the data
        carry, the best closed-form start, robust, refined with the extended
        model of `calib.model`: robot error, camera depth/focal correction,
        estimated noise levels; ``refine`` and ``robust`` do not apply), or a
        paper method: ``XAxisRX``, ``XQuatR*``, ``XKronR*``, ``XKronRT``, ``XKronT``,
        ``YAxisR``, ``YQuatR*``, ``YKronRT``, ``YQuatT'``, ``YKronT'``; also
        case-insensitive without ``'``/``*`` (``"ykront"``). See `METHODS`.
    A : array_like, shape (N, 4, 4)
        ``T_base_flange`` (m).
    B : array_like, shape (N, 4, 4) or (N, 3)
        ``T_cam_marker`` (m), or the marker center in the camera frame (m)
        for the point-only YKronT'.
    setup : {"eye_to_hand", "eye_in_hand"}
        Eye-to-hand: ``X = T_flange_marker``, ``Y = T_base_cam``.
        Eye-in-hand: ``X = T_flange_cam``, ``Y = T_base_marker``.
    refine : bool
        Maximum-likelihood refinement of the closed form (calib.refine).
    robust : bool
        Outlier rejection (calib.robust); ``result.inliers`` is then set.
    point_cov : array_like, shape (3, 3) or (N, 3, 3), optional
        Covariance of the marker points (m^2), used by refine/robust/cov.
    rng : numpy.random.Generator, optional
        For the robust sampler; ``default_rng(0)`` if not given, so results
        are reproducible.
    camera_correction : {"auto", "none", "depth", "depth+focal"}, optional
        Method ``"auto"`` only (default "auto"): which camera parameters to
        estimate (`calib.auto.solve_auto`).
    robot_shared_error : array_like, shape (N, 6, P), optional
        Method ``"auto"`` only: the robot error all samples share (e.g. its
        kinematic error), as a factor of the flange-pose error; it joins the
        covariance (`calib.auto.solve_auto`).

    Returns
    -------
    CalibrationResult
        ``X``, ``Y`` (4x4), residuals per sample, ``cov`` (6x6, camera
        transform, rotation vector rad then translation m) and
        ``info["cov_kind"]``: "fisher" (refined: inverse Fisher information,
        `calib.refine.covariance`), "delta-analytic" (closed-form YKronT':
        first-order covariance of the estimator, `calib.refine.kron_t_prime_covariance`),
        "delta-numerical" (other closed forms up to `DELTA_METHOD_MAX_SAMPLES`
        samples, `calib.refine.delta_method_covariance`) or
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
        The motions do not determine every unknown (the message says what to add).
    """
    if isinstance(method, str) and method.strip().lower() == AUTO:
        setup = check_setup(setup)
        A, B = solvers.check_measurements(A, B)
        if len(A) < AUTO_MIN_SAMPLES:
            raise InsufficientDataError(f"auto needs at least {AUTO_MIN_SAMPLES} samples, got {len(A)}")
        return solve_auto(A, B, setup=setup, point_cov=point_cov, rng=rng,
                          camera_correction="auto" if camera_correction is None else camera_correction,
                          robot_shared_error=robot_shared_error)
    if camera_correction is not None:
        raise CalibrationError(f"camera_correction applies to method 'auto' only, not {method!r}")
    if robot_shared_error is not None:
        raise CalibrationError(f"robot_shared_error applies to method 'auto' only, not {method!r}")
    info = resolve_method(method)
    setup = check_setup(setup)
    A, B = _check_inputs(info, A, B)
    cov_p = rf.check_point_cov(point_cov, len(A))

    def solve_fn(A_sub, B_sub):
        return _closed_form(info, A_sub, B_sub, setup)

    if robust:
        # A subset must be solvable: XKronT needs 5 poses where the default subset has 4.
        subset = max(info.min_samples, default_subset(points=B.ndim == 2))
        result = robust_solve(solve_fn, A, B, setup=setup, point_cov=cov_p, min_samples=subset,
                              rng=rng if rng is not None else np.random.default_rng(0))
    else:
        result = solve_fn(A, B)
    inl = result.inliers if result.inliers is not None else np.ones(len(A), dtype=bool)
    A_in, B_in = A[inl], B[inl]
    cov_in = None if cov_p is None else cov_p[inl]
    if refine:
        refined = rf.refine(result, A_in, B_in, point_cov=cov_in)
        result = dataclasses.replace(refined, inliers=result.inliers)
    cov, kind = _covariance(info, result, A_in, B_in, setup, cov_in, refined=refine)
    extra = {"cov_kind": kind}
    try:
        extra["self_check"] = self_check(result.X, result.Y, A_in, B_in, setup=setup, point_cov=cov_in,
                                         use_rotation=result.marker_rotation_known,
                                         marker_rotation_known=result.marker_rotation_known)
    except CalibrationError:
        pass  # the model's information is singular for these samples: no self-check, the result stands
    return dataclasses.replace(result, cov=cov, info={**result.info, **extra})


#: Above this many samples a closed form from poses gets the ML (Fisher)
#: covariance instead of the numerical delta method, whose 6N re-solves would
#: cost seconds; it is then over-confident (``info["cov_kind"]`` says so).
DELTA_METHOD_MAX_SAMPLES = 100


def _covariance(info: MethodInfo, result: CalibrationResult, A, B, setup, point_cov, *, refined: bool):
    """Covariance of the camera transform of ``result`` and how it was obtained (``info["cov_kind"]``).

    An ML estimate gets the inverse Fisher information ("fisher"). A closed
    form is less efficient, so it gets the first-order covariance of the
    estimator itself: analytic for YKronT' ("delta-analytic"), numerical for
    the pose-based methods up to `DELTA_METHOD_MAX_SAMPLES` ("delta-numerical"),
    else the Fisher one, labelled "fisher-optimistic".
    """
    if refined:
        return rf.covariance(result.X, result.Y, A, B, setup=setup, point_cov=point_cov), "fisher"
    if info.needs == "points":
        return rf.kron_t_prime_covariance(result.X, result.Y, A, B, setup=setup, point_cov=point_cov), "delta-analytic"
    if len(A) <= DELTA_METHOD_MAX_SAMPLES:
        def estimator(A_sub, B_sub):
            return info.function(A_sub, B_sub if setup == Setup.EYE_TO_HAND else tf.invert(B_sub))

        cov = rf.delta_method_covariance(estimator, result.X, result.Y, A, B, setup=setup, point_cov=point_cov)
        return cov, "delta-numerical"
    return rf.covariance(result.X, result.Y, A, B, setup=setup, point_cov=point_cov), "fisher-optimistic"


def observations_to_arrays(
    observations: Sequence[Observation], kind: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """Turn observations into the ``(A, B, point_cov)`` that `solve` takes.

    Parameters
    ----------
    observations : sequence of Observation
    kind : {"points", "poses"}
        ``"points"``: B is the marker center ``point_cam`` (N, 3) for YKronT';
        ``"poses"``: B is ``T_cam_marker`` (N, 4, 4). Observations lacking
        the measurement are skipped.

    Returns
    -------
    A : ndarray, shape (M, 4, 4)
    B : ndarray, shape (M, 3) or (M, 4, 4)
    point_cov : ndarray, shape (M, 3, 3), or None
        Point covariances (m^2) if every kept observation has one. For poses
        it is the translation block of ``pose_cov`` mapped through the
        left-multiplied perturbation: ``J pose_cov J^T``, ``J = [-[t]x, I]``.
    kept : ndarray of int, shape (M,)
        Positions in ``observations`` that were used.
    """
    if kind not in ("points", "poses"):
        raise CalibrationError(f"kind must be 'points' or 'poses', got {kind!r}")
    attr = "point_cam" if kind == "points" else "T_cam_marker"
    kept = [i for i, o in enumerate(observations) if getattr(o, attr) is not None]
    if not kept:
        raise InsufficientDataError(f"no observation has a {attr} measurement")
    A = np.stack([np.asarray(observations[i].T_base_flange, dtype=float) for i in kept])
    B = np.stack([np.asarray(getattr(observations[i], attr), dtype=float) for i in kept])
    covs = []
    for i in kept:
        o = observations[i]
        if kind == "points":
            covs.append(None if o.point_cov is None else np.asarray(o.point_cov, dtype=float))
        elif o.pose_cov is not None:
            J = np.hstack([-tf.skew(np.asarray(o.T_cam_marker, dtype=float)[:3, 3]), np.eye(3)])
            covs.append(J @ np.asarray(o.pose_cov, dtype=float) @ J.T)
        else:
            covs.append(None)
    point_cov = None if any(c is None for c in covs) else np.stack(covs)
    return A, B, point_cov, np.asarray(kept, dtype=int)


def solve_observations(method: str, observations: Sequence[Observation], setup: Setup, *, refine: bool = False,
                       robust: bool = False, rng: np.random.Generator | None = None,
                       robot_shared_error=None) -> CalibrationResult:
    """Solve ``A_i X = Y B_i`` (paper eq. 1) for a list of samples with a named solver.

    Point methods (YKronT') get the depth-lifted marker centers ``point_cam``
    with their covariances; the others the marker poses ``T_cam_marker``
    (``METHODS[...].needs``). Samples lacking that measurement are left out.
    ``"auto"`` gets the marker centers (``point_cam``, with ``point_cov``)
    and, when every sample has a pose, the poses' orientations (the center
    takes the place of the pose's origin); ``refine``/``robust`` do not apply,
    it always does both. ``robot_shared_error`` (``"auto"`` only): (N, 6, P),
    one row per observation (`solve`).
    """
    if isinstance(method, str) and method.strip().lower() == AUTO:
        # Every measurement the samples carry: the marker centers (depth-lifted when the extractor
        # gives them) and, when every sample has a pose, its orientation. A center replaces the pose's
        # origin: both are fixed on the marker, so the marker frame just moves to the center.
        has_pose = all(o.T_cam_marker is not None for o in observations)
        has_point = all(o.point_cam is not None for o in observations)
        A, B, point_cov, kept = observations_to_arrays(observations, "poses" if has_pose else "points")
        if has_pose and has_point:
            _, centers, point_cov, _ = observations_to_arrays(observations, "points")
            B = B.copy()
            B[:, :3, 3] = centers
        if robot_shared_error is not None:
            factor = tf.as_real_array(robot_shared_error, "robot_shared_error")
            if factor.ndim == 0 or len(factor) != len(observations):
                raise CalibrationError(f"robot_shared_error must have one row per observation ({len(observations)}), "
                                       f"got shape {factor.shape}")
            robot_shared_error = factor[kept]
        return solve(AUTO, A, B, setup=setup, point_cov=point_cov, rng=rng, robot_shared_error=robot_shared_error)
    info = resolve_method(method)
    A, B, point_cov, _ = observations_to_arrays(observations, info.needs)
    return solve(info.name, A, B, setup=setup, refine=refine, robust=robust, point_cov=point_cov, rng=rng,
                 robot_shared_error=robot_shared_error)
