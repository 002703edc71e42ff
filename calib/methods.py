"""The paper's Table I as named rows, and `closed_form`: one closed-form method on a `CalibrationProblem`.

Setups (paper eq. 1, ``A_i X = Y B_i``): eye-to-hand ``X = T_flange_marker``,
``Y = T_base_cam``; eye-in-hand ``X = T_flange_cam``, ``Y = T_base_marker``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable

from handeye.calib import solvers
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError, InsufficientDataError
from handeye.calib.problem import CalibrationProblem, as_problem
from handeye.calib.result import CalibrationResult, Residuals
from handeye.calib.setup import Setup


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
    function : callable
        The solver of `handeye.calib.solvers`, ``function(A, B) -> (X, Y)`` (eye-to-hand form).
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


def _row(name, equation, representation, solves, paper_equations, reference, needs, min_samples, function):
    return MethodInfo(name=name, equation=equation, representation=representation, solves=solves,
                      paper_equations=paper_equations, reference=reference, needs=needs, min_samples=min_samples,
                      function=function)


#: Every closed-form method of the paper's Table I, keyed by its printed name.
METHODS: dict[str, MethodInfo] = {row.name: row for row in (
    _row("XAxisRX", "AX=XB", "axis-angle", "R", (2, 18, 5), "Park & Martin 1994", "poses", 3, solvers.x_axis_rx),
    _row("XQuatR*", "AX=XB", "quaternion", "R", (2, 9, 17, 5), "cf. Dornaika & Horaud 1998", "poses", 3,
         solvers.x_quat_r_star),
    _row("XKronR*", "AX=XB", "Kronecker", "R", (2, 12, 17, 5), "cf. Shah 2013", "poses", 3, solvers.x_kron_r_star),
    _row("XKronRT", "AX=XB", "Kronecker", "RT", (2, 16, 13), "Andreff et al. 2001", "poses", 3, solvers.x_kron_rt),
    _row("XKronT", "AX=XB", "Kronecker", "T", (2, 13), "this paper (Table I)", "poses", 5, solvers.x_kron_t),
    _row("YAxisR", "AX=YB", "axis-angle", "R", (9, 16, 6), "Zhuang et al. 1994", "poses", 3, solvers.y_axis_r),
    _row("YQuatR*", "AX=YB", "quaternion", "R", (9, 17, 6), "Dornaika & Horaud 1998", "poses", 3,
         solvers.y_quat_r_star),
    _row("YKronRT", "AX=YB", "Kronecker", "RT", (16, 13, 6), "Li et al. 2010", "poses", 3, solvers.y_kron_rt),
    _row("YQuatT'", "AX=YB", "quaternion", "T", (10, 19), "this paper (proposed)", "poses", 3,
         solvers.y_quat_t_prime),
    _row("YKronT'", "AX=YB", "Kronecker", "T", (13, 20), "this paper (proposed)", "points", 5,
         solvers.y_kron_t_prime),
)}

#: The name of the extended-model estimator (`handeye.calib.auto`).
AUTO = "auto"
#: Fewest samples ``"auto"`` accepts (its YKronT' start needs 5).
AUTO_MIN_SAMPLES = 5

_ALIASES = {name.lower().replace("'", "").replace("*", ""): name for name in METHODS}


def is_auto(method) -> bool:
    """Whether ``method`` names the extended-model estimator ``"auto"``."""
    return isinstance(method, str) and method.strip().lower() == AUTO


def resolve_method(method: str) -> MethodInfo:
    """Look up a method by its paper name, or case-insensitively without ``'`` and ``*`` (``"ykront"``)."""
    if isinstance(method, str):
        key = method.strip().lower().replace("'", "").replace("*", "")
        if key in _ALIASES:
            return METHODS[_ALIASES[key]]
    raise CalibrationError(f"unknown method {method!r}; valid: {AUTO}, {', '.join(METHODS)}")


def check_applicable(info: MethodInfo, problem: CalibrationProblem) -> None:
    """Raise if ``problem`` cannot be solved by the method ``info``: poses required but points given, or too few samples."""
    if info.needs == "poses" and not problem.has_poses:
        point_methods = ", ".join(m.name for m in METHODS.values() if m.needs == "points")
        raise CalibrationError(
            f"{info.name} needs marker poses B of shape (N, 4, 4), got points {problem.B.shape}; "
            f"point-only methods: {point_methods}"
        )
    if problem.n < info.min_samples:
        raise InsufficientDataError(f"{info.name} needs at least {info.min_samples} samples, got {problem.n}")


def closed_form(method, problem, B=None, *, setup: Setup | None = None) -> CalibrationResult:
    """Run one closed-form method of Table I and wrap it in a CalibrationResult (no refinement, no cov).

    Parameters
    ----------
    method : str or MethodInfo
        A name from `METHODS` (case-insensitive, ``'`` and ``*`` optional).
    problem : CalibrationProblem
        The samples; or, in the array form, ``A`` (N, 4, 4) ``T_base_flange``
        followed by ``B`` (N, 4, 4) ``T_cam_marker`` or (N, 3) marker points and
        ``setup`` (a pose stack given to YKronT' contributes its translations).
    setup : {"eye_to_hand", "eye_in_hand"}, optional
        Array form only. Eye-to-hand: ``X = T_flange_marker``, ``Y = T_base_cam``.
        Eye-in-hand: ``X = T_flange_cam``, ``Y = T_base_marker``.

    Returns
    -------
    CalibrationResult
        ``X``, ``Y``, per-sample residuals (eq. 4/5), ``cov`` None.
    """
    info = method if isinstance(method, MethodInfo) else resolve_method(method)
    problem = as_problem(problem, B, setup=setup)
    check_applicable(info, problem)
    A, B, setup = problem.A, problem.B, problem.setup
    if info.needs == "points":
        X, Y = solvers.y_kron_t_prime_unchecked(A, problem.points, setup)
    else:
        # Eye-in-hand A X B = Y is eq. 1 with B inverted: A X = Y B^-1.
        X, Y = info.function(A, B if setup == Setup.EYE_TO_HAND else tf.invert(B))
    trans, rot = solvers.residuals_unchecked(X, Y, A, B, setup, info.marker_rotation_known)
    return CalibrationResult(
        method=info.name,
        setup=setup,
        X=X,
        Y=Y,
        n_samples=problem.n,
        residuals=Residuals(translation=trans, rotation=rot),
        marker_rotation_known=info.marker_rotation_known,
    )
