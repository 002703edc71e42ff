"""What a recording determines, when its motions leave part of the answer open.

A tool that never turns (a grid of positions at one orientation), or turns
about one axis only, leaves the split between the two translations open
(`handeye.calib.model.open_translations`): eye-to-hand the marker's offset on the
flange and the camera's position, eye-in-hand the camera's position on the
flange and the static marker's position. Everything else stays determined:
the camera's rotation, its correction (depth scale, offset, focal scale),
and the camera's position given that offset.

``auto`` then solves for what is determined instead of refusing
(`motion_prior`): a known marker offset (`handeye.calib.problem.CalibrationProblem`
``marker_offset``) is held, with its stated 1-sigma, and completes the
answer; without it the flange-side translation's open part is held at zero
(the marker at the flange origin eye-to-hand, the camera there eye-in-hand),
the covariance is the one given that value, and ``undetermined`` names what
is open and the motion that closes it. The start is `held_start`: the rigid
registration of the marker points to the flange positions, which needs no
rotation (the paper's closed forms all do).

Setups (paper eq. 1, ``A_i X = Y B_i``): eye-to-hand ``X = T_flange_marker``,
``Y = T_base_cam``; eye-in-hand ``X = T_flange_cam``, ``Y = T_base_marker``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import null_space

from handeye.calib import model
from handeye.calib import transforms as tf
from handeye.calib.errors import DegenerateMotionError
from handeye.calib.problem import CalibrationProblem
from handeye.calib.result import CalibrationResult, Residuals
from handeye.calib.setup import Setup
from handeye.calib.solvers import DEGENERACY_RTOL, diagnose_motion, residuals_unchecked

#: The name of `held_start` in ``AutoDetails.start``.
HELD_START = "registration"

#: Rounds of `held_start` (registration, then both translations with the rotation fixed); it stops earlier once
#: the rotation changes by less than `HELD_START_TOL` rad.
HELD_START_ROUNDS = 50
HELD_START_TOL = 1e-12

#: The tool positions must spread across a line by this fraction of their spread along it (pure translations):
#: otherwise the camera's rotation about that line is open too.
MIN_PLANARITY = 1e-3


@dataclass(frozen=True)
class MotionPrior:
    """What the motions of a problem leave open (`motion_prior`) and how ``auto`` holds it.

    Attributes
    ----------
    open : ndarray, shape (6, k)
        Open directions of ``[t_C, t_K]`` (`handeye.calib.model.open_translations`), k = 0 when none.
    prior : handeye.calib.model.TranslationPrior or None
        What the fit holds: the known marker offset, else the open part of the flange-side translation at zero.
    undetermined : tuple of str
        Plain sentences: what stays open and the motion (or the value) that closes it; empty when nothing does.
    note : str or None
        What was held, for ``AutoDetails.notes``.
    """

    open: np.ndarray
    prior: model.TranslationPrior | None
    undetermined: tuple[str, ...]
    note: str | None

    @property
    def leaves_open(self) -> bool:
        """Whether the motions alone leave part of the translations open."""
        return self.open.shape[1] > 0


def motion_prior(problem: CalibrationProblem) -> MotionPrior:
    """What ``problem``'s motions determine, and the prior ``auto`` fits with (`MotionPrior`)."""
    M = model.split(np.eye(4), np.eye(4), problem.A, problem.setup)[2]
    open_dirs = model.open_translations(M, DEGENERACY_RTOL)
    eye_to_hand = problem.setup == Setup.EYE_TO_HAND
    if problem.marker_offset is not None:
        sigma = max(problem.marker_offset_sigma, model.HELD_SIGMA_M)
        directions = np.vstack([np.zeros((3, 3)), np.eye(3)])
        prior = model.held_prior(directions, np.concatenate([np.zeros(3), problem.marker_offset]), sigma)
        what = "marker's offset on the flange" if eye_to_hand else "marker's position in the base frame"
        held = (f"held at its 1-sigma of {problem.marker_offset_sigma * 1e3:.2f} mm"
                if problem.marker_offset_sigma > model.HELD_SIGMA_M else "held as given")
        note = (f"the {what} {_mm(problem.marker_offset)} mm was given and is {held}"
                + (": it completes what the motions leave open" if open_dirs.shape[1] else ""))
        return MotionPrior(open_dirs, prior, (), note)
    k = open_dirs.shape[1]
    if k == 0:
        return MotionPrior(open_dirs, None, (), None)
    # The flange-side translation's open part, held at zero: eye-to-hand t_K (the marker on the flange),
    # eye-in-hand t_C (the camera on the flange).
    flange = open_dirs[3:] if eye_to_hand else open_dirs[:3]
    directions = np.vstack([np.zeros((3, k)), flange]) if eye_to_hand else np.vstack([flange, np.zeros((3, k))])
    prior = model.held_prior(directions, np.zeros(6))
    sentence = _open_sentence(problem, flange, eye_to_hand)
    note = ("the motions leave part of the translations open: " + sentence.split(":")[0]
            + "; the rest is determined and reported")
    return MotionPrior(open_dirs, prior, (sentence,), note)


def _open_sentence(problem: CalibrationProblem, flange: np.ndarray, eye_to_hand: bool) -> str:
    """The ``undetermined`` sentence: what is open, what was reported for it, and what closes it."""
    offset = ("--marker-offset X,Y,Z (mm, flange frame)" if eye_to_hand
              else "--marker-offset X,Y,Z (the marker's position in mm, base frame)")
    if flange.shape[1] == 3:
        if eye_to_hand:
            return ("the marker's offset on the flange and the camera's position are not separated (the tool never "
                    "turned): the camera's rotation and correction are determined, its position is reported for the "
                    "marker at the flange origin and shifts by the true offset turned into the base frame; rotate "
                    f"the tool by 30 deg or more about two axes, or give {offset}")
        return ("the camera's position on the flange and the marker's position are not separated (the tool never "
                "turned): the camera's rotation and correction are determined, its position is reported at the "
                "flange origin and the marker's position shifts with the true one; rotate the tool by 30 deg or "
                f"more about two axes, or give {offset}")
    u = flange[:, 0] / np.linalg.norm(flange[:, 0])
    u = u * np.sign(u[np.argmax(np.abs(u))])
    side = "the marker's offset on the flange" if eye_to_hand else "the camera's position on the flange"
    other = "the camera's position" if eye_to_hand else "the marker's position"
    return (f"{side} along the one axis the tool turned about ({_unit(u)}, flange frame) and {other} are not "
            f"separated: reported with that component at 0; rotate the tool by 30 deg or more about a second axis, "
            f"or give {offset}")


def held_equivalent(X, Y, A, setup: str, motion: MotionPrior) -> tuple[np.ndarray, np.ndarray]:
    """``(X, Y)`` moved along ``motion``'s open directions to the values its prior holds (nearest, in its
    weights, when it holds more than is open: a given marker offset).

    The samples cannot tell the two apart (every predicted marker point is
    the same), so this is what ``auto`` should report when ``(X, Y)`` is the
    truth: the yardstick for a result that holds part of the answer.
    """
    C, K, _ = model.split(X, Y, A, setup)
    if not motion.leaves_open:
        return X, Y
    t = np.concatenate([C[:3, 3], K[:3, 3]])
    rows = motion.prior.rows
    t = t + motion.open @ np.linalg.lstsq(rows @ motion.open, -rows @ (t - motion.prior.target), rcond=None)[0]
    return model.join(tf.make_transform(C[:3, :3], t[:3]), tf.make_transform(K[:3, :3], t[3:]), setup)


def held_start(problem: CalibrationProblem, motion: MotionPrior) -> CalibrationResult:
    """A start for motions that leave the translations partly open (``motion``): registration, the prior held.

    Rounds of (1) the rigid registration (Kabsch) of the marker points
    ``p_i`` to the marker centres in C's parent frame ``R_Mi t_K + t_Mi``
    (`handeye.calib.model`), which gives ``C``, and (2) the paper's eq. 6 with
    ``R_C`` fixed, ``[-I, R_Mi] [t_C; t_K] = R_C p_i - t_Mi``, solved with the
    prior's rows held exactly at their target. Pure translations need one
    round; rotations about one axis converge in a few. The marker-side
    rotation is unknown (identity), as for YKronT'.

    Raises
    ------
    DegenerateMotionError
        The tool positions do not determine the camera's rotation either
        (all on one line, or all the same, and the tool never turned).
    """
    A, p, setup, prior = problem.A, problem.points, problem.setup, motion.prior
    M = model.split(np.eye(4), np.eye(4), A, setup)[2]
    R_M, t_M = M[:, :3, :3], M[:, :3, 3]
    if motion.open.shape[1] == 3:
        _check_spread(A, t_M)
    H = prior.rows
    t_p = np.linalg.lstsq(H, H @ prior.target, rcond=None)[0]
    Z = null_space(H)
    S = np.concatenate([np.broadcast_to(-np.eye(3), R_M.shape), R_M], axis=2).reshape(-1, 6)
    SZ = S @ Z
    t = t_p
    R_C = None
    for _ in range(HELD_START_ROUNDS):
        y = np.einsum("nij,j->ni", R_M, t[3:]) + t_M
        p0, y0 = p - p.mean(axis=0), y - y.mean(axis=0)
        R_new = tf.project_to_so3(y0.T @ p0)
        b = (p @ R_new.T - t_M).reshape(-1) - S @ t_p
        t = t_p + Z @ np.linalg.lstsq(SZ, b, rcond=None)[0]
        done = R_C is not None and tf.rotation_angle(R_new.T @ R_C) < HELD_START_TOL
        R_C = R_new
        if done:
            break
    C = tf.make_transform(R_C, t[:3])
    K = tf.make_transform(np.eye(3), t[3:])
    X, Y = model.join(C, K, setup)
    trans, _ = residuals_unchecked(X, Y, A, problem.B, setup, False)
    return CalibrationResult(method=HELD_START, setup=setup, X=X, Y=Y, n_samples=problem.n,
                             residuals=Residuals(translation=trans), marker_rotation_known=False)


def _check_spread(A: np.ndarray, t_M: np.ndarray) -> None:
    """Raise unless the flange positions ``t_M`` (N, 3; of the robot poses ``A``) spread over a plane at least
    (see `held_start`)."""
    s = np.linalg.svd(t_M - t_M.mean(axis=0), compute_uv=False)
    if s[0] < 1e-4 * np.sqrt(len(t_M)):
        raise DegenerateMotionError(diagnose_motion(A))
    if s[1] < MIN_PLANARITY * s[0]:
        raise DegenerateMotionError("all tool positions lie on one line and the tool never turned about two axes: "
                                    "the camera's rotation about that line is not determined; move the tool over a "
                                    "plane or a volume, or rotate it about two axes")


def determined_note(result: CalibrationResult, motion: MotionPrior, cov_K) -> str | None:
    """What the recording determines despite what is open, with its 1-sigma (None when nothing is open).

    ``cov_K`` (3, 3): the covariance of the marker-side translation (the
    side not held eye-in-hand), m^2.
    """
    if not motion.undetermined:
        return None
    s_rot, s_t = result.sigma
    corr = result.auto.camera_correction if result.auto is not None else {}
    parts = [f"{name.replace('_', ' ')} {_camera_value(name, c.value, c.sigma)}"
             for name, c in corr.items() if c.estimated]
    if result.setup == Setup.EYE_TO_HAND:
        where = f"its position to {s_t * 1e3:.2f} mm given the marker's offset"
    else:
        s_K = float(np.sqrt(max(np.linalg.eigvalsh(cov_K).max(), 0.0)))
        where = f"the marker's position to {s_K * 1e3:.2f} mm given the camera's position on the flange"
    return (f"determined: the camera's rotation to {np.rad2deg(s_rot):.3f} deg (1-sigma)"
            + (f", its {', '.join(parts)}" if parts else "") + f"; {where}")


def _camera_value(name: str, value: float, sigma: float) -> str:
    if name == "depth_offset":
        return f"{value * 1e3:+.2f} ± {sigma * 1e3:.2f} mm"
    return f"{value * 100:+.2f} ± {sigma * 100:.2f} %"


def _mm(v) -> str:
    return "(" + ", ".join(f"{x * 1e3:.1f}" for x in v) + ")"


def _unit(u) -> str:
    return "[" + ", ".join(f"{x:.2f}" for x in np.round(u, 2) + 0.0) + "]"     # + 0.0: no "-0.00"
