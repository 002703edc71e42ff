"""Frame flips of symmetric targets: detect and undo them consistently across samples.

A chessboard or circle grid that looks the same after a half turn about its
normal gives PnP two valid frames; detectors pick one per image, so some
samples carry ``B_i F`` instead of ``B_i`` (``B = T_cam_marker``, ``F`` the
symmetry of the board in its own frame). Every pose-based solver then sees
samples that disagree by the board's size (hundreds of mm).

`resolve_flips` fits the majority (least median of squares over small subsets
with the closed-form YQuatT', paper eq. 19), computes each sample's
discrepancy ``F_i = X^-1 A_i^-1 Y B_i`` (eye-to-hand; eye-in-hand:
``F_i = Y^-1 A_i X B_i``), and accepts as flips only those that are a
symmetry of a planar target: a rotation of 90, 180 or 270 deg about the
marker's z axis (the board normal) within `ANGLE_TOL`, with an in-plane
translation. Samples with the same flip share one averaged ``F``; each is
turned back with ``B_i F^-1``. Anything else is left for the outlier test.
"""

from __future__ import annotations

import numpy as np

from handeye.calib import solvers
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError
from handeye.calib.setup import Setup

#: Tolerance on the flip's angle and on its axis being the board normal, rad.
ANGLE_TOL = np.deg2rad(15.0)
#: Largest out-of-plane translation of a flip, m (a symmetry keeps the board in its plane).
PLANE_TOL = 0.02
#: Rotation discrepancy above which a sample counts as a flip candidate, rad.
CANDIDATE_ANGLE = np.deg2rad(60.0)
_TRIALS = 60
_SUBSET = 4


def _discrepancy(X, Y, A, B, setup):
    """``F_i`` (N, 4, 4) with ``B_i = (predicted B_i) F_i``."""
    if setup == Setup.EYE_TO_HAND:
        pred = tf.invert(Y) @ A @ X
    else:
        pred = tf.invert(A @ X) @ Y
    return tf.invert(pred) @ B


def _fit(A, B, setup):
    Bs = B if setup == Setup.EYE_TO_HAND else tf.invert(B)
    return solvers.y_quat_t_prime(A, Bs)


def _is_symmetry(F) -> tuple[bool, float]:
    """Whether ``F`` is a quarter or half turn about the marker z axis with in-plane translation."""
    rv = tf.so3_log(F[:3, :3])
    angle = float(np.linalg.norm(rv))
    if angle < CANDIDATE_ANGLE:
        return False, angle
    axis = rv / angle
    nearest = min((np.pi / 2, np.pi), key=lambda a: abs(a - angle))
    ok = abs(angle - nearest) < ANGLE_TOL and abs(axis[2]) > np.cos(ANGLE_TOL) and abs(F[2, 3]) < PLANE_TOL
    return ok, angle


def resolve_flips(A, B, *, setup: str, rng: np.random.Generator | None = None):
    """Turn back marker poses flipped by a symmetry of the target.

    Parameters
    ----------
    A : ndarray, shape (N, 4, 4)
        ``T_base_flange``.
    B : ndarray, shape (N, 4, 4)
        ``T_cam_marker``.
    setup : {"eye_to_hand", "eye_in_hand"}
    rng : numpy.random.Generator, optional
        Subsets of the majority search; ``default_rng(0)`` if not given.

    Returns
    -------
    B : ndarray, shape (N, 4, 4)
        With flipped samples turned back (a copy if any changed).
    report : dict
        ``n_flipped``, ``flipped`` (indices), ``angle_deg`` (of the flip)
        and ``F`` (the averaged flip, 4x4, marker frame).
    """
    n = len(A)
    report = {"n_flipped": 0, "flipped": [], "angle_deg": 0.0, "F": None}
    if n < 2 * _SUBSET:
        return B, report
    try:
        X, Y = _fit(A, B, setup)
    except CalibrationError:
        return B, report
    F = _discrepancy(X, Y, A, B, setup)
    angles = tf.rotation_angle(F[:, :3, :3])
    if not np.any(angles > CANDIDATE_ANGLE):
        return B, report
    # Flips corrupted the fit on all samples: find the majority by least median of squares.
    rng = rng if rng is not None else np.random.default_rng(0)
    best, best_med = None, np.inf
    for _ in range(_TRIALS):
        idx = rng.choice(n, size=_SUBSET, replace=False)
        try:
            Xh, Yh = _fit(A[idx], B[idx], setup)
        except CalibrationError:
            continue
        Fh = _discrepancy(Xh, Yh, A, B, setup)
        med = float(np.median(tf.rotation_angle(Fh[:, :3, :3]) ** 2 + np.sum(Fh[:, :3, 3] ** 2, axis=1) / 0.01))
        if med < best_med:
            best, best_med = (Xh, Yh), med
    if best is None:
        return B, report
    X, Y = best
    # Refit on the majority (samples with a small discrepancy) for a clean reference.
    F = _discrepancy(X, Y, A, B, setup)
    good = tf.rotation_angle(F[:, :3, :3]) < CANDIDATE_ANGLE
    if good.sum() >= _SUBSET:
        try:
            X, Y = _fit(A[good], B[good], setup)
            F = _discrepancy(X, Y, A, B, setup)
        except CalibrationError:
            pass
    candidates = [i for i in range(n) if _is_symmetry(F[i])[0]]
    if not candidates:
        return B, report
    # Group the candidates by their flip (quarter turns differ), average each group.
    B = B.copy()
    flipped, angle = [], 0.0
    remaining = list(candidates)
    while remaining:
        ref = F[remaining[0]]
        group = [i for i in remaining if tf.rotation_angle(ref[:3, :3].T @ F[i, :3, :3]) < ANGLE_TOL]
        remaining = [i for i in remaining if i not in group]
        R_mean = tf.project_to_so3(F[group, :3, :3].sum(axis=0))
        F_mean = tf.make_transform(R_mean, F[group, :3, 3].mean(axis=0))
        B[group] = B[group] @ tf.invert(F_mean)
        flipped += group
        angle = float(np.rad2deg(tf.rotation_angle(R_mean)))
        report["F"] = F_mean
    report.update(n_flipped=len(flipped), flipped=sorted(flipped), angle_deg=angle)
    return B, report
