"""The per-sample measurement model on plain floats (`sample_floats`) and its 3x3 kernels.

One sample is a few 3x3 products: as numpy arrays each costs more in call overhead than in
arithmetic, so the engine's hot path runs them on tuples of floats. `sample_floats` is the
reference model `handeye.calib.model.point_jacobians` (with `handeye.calib.model.robot_cofactor`) for one sample,
written out on floats (tested against it on random states); `so3_exp_scalar` is
`handeye.calib.transforms.so3_exp` for one rotation, with the same formula. `plain_transform`, `plain_point`
and `plain_cov` check a sample's arrays on the floats they read and return them."""

from __future__ import annotations

import math

import numpy as np

from handeye.calib import model
from handeye.calib import transforms as tf
from handeye.calib.setup import Setup



I3 = np.eye(3)
#: `handeye.calib.model.ROBOT_ROTATION_PER_M` squared (the robot cofactor's lever weight).
ROBOT_RHO2 = model.ROBOT_ROTATION_PER_M ** 2


def parts(T):
    """Rotation rows and translation of a (4, 4) transform, as floats."""
    (a, b, c, x), (d, e, f, y), (g, h, i, z), _ = T.tolist()
    return ((a, b, c), (d, e, f), (g, h, i)), (x, y, z)


def matmul3(M, N):
    (a, b, c), (d, e, f), (g, h, i) = M
    (p, q, r), (s, t, u), (v, w, x) = N
    return ((a * p + b * s + c * v, a * q + b * t + c * w, a * r + b * u + c * x),
            (d * p + e * s + f * v, d * q + e * t + f * w, d * r + e * u + f * x),
            (g * p + h * s + i * v, g * q + h * t + i * w, g * r + h * u + i * x))


def so3_exp_scalar(a0: float, a1: float, a2: float):
    """`handeye.calib.transforms.so3_exp` of one rotation vector (rad), as rows of floats (same formula and series)."""
    th2 = a0 * a0 + a1 * a1 + a2 * a2
    if th2 < 1e-8:
        a, b = 1.0 - th2 / 6.0 + th2 * th2 / 120.0, 0.5 - th2 / 24.0 + th2 * th2 / 720.0
    else:
        th = math.sqrt(th2)
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    # I + a [v]x + b [v]x^2, with [v]x^2 = v v^T - |v|^2 I
    return ((1.0 + b * (a0 * a0 - th2), b * a0 * a1 - a * a2, b * a0 * a2 + a * a1),
            (b * a0 * a1 + a * a2, 1.0 + b * (a1 * a1 - th2), b * a1 * a2 - a * a0),
            (b * a0 * a2 - a * a1, b * a1 * a2 + a * a0, 1.0 + b * (a2 * a2 - th2)))


def inv_sym3(S) -> np.ndarray:
    """Inverse of a symmetric positive definite (3, 3) matrix (cofactors, from its upper triangle)."""
    (a, b, c), (_, d, e), (_, _, f) = S.tolist()
    return sym3(inv_sym3_floats(a, b, c, d, e, f))


def inv_sym3_floats(a, b, c, d, e, f):
    """`inv_sym3` on the upper triangle ``(xx, xy, xz, yy, yz, zz)`` as floats; the inverse's, likewise."""
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
    k = 1.0 / (a * A + b * B + c * C)
    return A * k, B * k, C * k, (a * f - c * c) * k, (b * c - a * e) * k, (a * d - b * b) * k


def is_positive_definite3(a, b, c, d, e, f) -> bool:
    """The symmetric 3x3 matrix of the upper triangle ``(xx, xy, xz, yy, yz, zz)`` is positive definite (its
    leading principal minors are positive; NaN fails)."""
    return a > 0.0 and a * d - b * b > 0.0 and a * (d * f - e * e) - b * (b * f - c * e) + c * (b * e - c * d) > 0.0


def sym3(upper) -> np.ndarray:
    """The symmetric (3, 3) array of an upper triangle ``(xx, xy, xz, yy, yz, zz)``."""
    A, B, C, D, E, F = upper
    return np.array((A, B, C, B, D, E, C, E, F)).reshape(3, 3)


def is_plain(a, shape) -> bool:
    """``a`` is a float64 array of ``shape``, finite and within `handeye.calib.transforms.MAX_MAGNITUDE`: the common case,
    which the general validators would return unchanged (anything else goes to them for their checks and message)."""
    # A sum of squares within the bound's square bounds every entry; NaN and inf fail the comparison.
    return (type(a) is np.ndarray and a.dtype == np.float64 and a.shape == shape
            and float(np.vdot(a, a)) <= tf.MAX_MAGNITUDE ** 2)


def _is_float64(a, shape) -> bool:
    return type(a) is np.ndarray and a.dtype == np.float64 and a.shape == shape


def _within(sum_of_squares: float) -> bool:
    """`is_plain`'s magnitude test on floats: the sum of squares within the bound's square (NaN and inf fail)."""
    return sum_of_squares <= tf.MAX_MAGNITUDE ** 2


def plain_point(p):
    """``p`` as 3 floats when it `is_plain` of shape (3,), else None."""
    if not _is_float64(p, (3,)):
        return None
    x, y, z = p.tolist()
    return (x, y, z) if _within(x * x + y * y + z * z) else None


def plain_transform(T):
    """The first three rows of ``T`` flat (12 floats) when it `is_plain` and is a rigid transform within
    `handeye.calib.transforms.check_transform`'s tolerances, else None."""
    if not _is_float64(T, (4, 4)):
        return None
    (a, b, c, x), (d, e, f, y), (g, h, i, z), (p, q, r, w) = T.tolist()
    atol = tf.ROTATION_ATOL
    tol = max(atol, 1e-9) * 10
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    plain = (_within(a * a + b * b + c * c + d * d + e * e + f * f + g * g + h * h + i * i + x * x + y * y + z * z
                     + p * p + q * q + r * r + w * w)
             and abs(p) <= atol and abs(q) <= atol and abs(r) <= atol and abs(w - 1.0) <= atol
             and abs(det - 1.0) <= atol * 10
             and abs(a * a + b * b + c * c - 1.0) <= tol and abs(d * d + e * e + f * f - 1.0) <= tol
             and abs(g * g + h * h + i * i - 1.0) <= tol and abs(a * d + b * e + c * f) <= tol
             and abs(a * g + b * h + c * i) <= tol and abs(d * g + e * h + f * i) <= tol)
    return [a, b, c, x, d, e, f, y, g, h, i, z] if plain else None


def plain_cov(S):
    """The upper triangle ``(xx, xy, xz, yy, yz, zz)`` of ``S`` when it `is_plain` of shape (3, 3) and is
    symmetric within `handeye.calib.model.check_point_cov`'s tolerance, else None."""
    if not _is_float64(S, (3, 3)):
        return None
    (a, b, c), (d, e, f), (g, h, i) = S.tolist()
    tol = 1e-9 * max(abs(a), abs(b), abs(c), abs(d), abs(e), abs(f), abs(g), abs(h), abs(i), 1e-30)
    plain = (_within(a * a + b * b + c * c + d * d + e * e + f * f + g * g + h * h + i * i)
             and abs(b - d) <= tol and abs(c - g) <= tol and abs(f - h) <= tol)
    return (a, b, c, e, f, i) if plain else None


def sample_floats(C, t_K, pose, theta, eye_to_hand: bool, factor=None, z=None):
    """One sample's predicted measured marker point, its Jacobian w.r.t. the engine's state, and its robot
    cofactor: `handeye.calib.model.point_jacobians` and `handeye.calib.model.robot_cofactor` for one sample, on floats.

    At the flange pose ``A Exp(factor z)`` when the state carries the
    robot's kinematic error ``z``. Eye-to-hand ``C = T_base_cam`` and the
    marker-side translation ``t_K`` is ``T_flange_marker``'s; eye-in-hand
    ``C = T_flange_cam`` and ``t_K`` is ``T_base_marker``'s.

    Parameters
    ----------
    C : tuple
        The camera transform as `parts`.
    t_K : 3 floats
    pose : 12 floats
        ``T_base_flange[:3]`` flat, as the robot reports it.
    theta : 3 floats
        Camera parameters (`handeye.calib.model.CAMERA_PARAMS`).
    eye_to_hand : bool
    factor, z : ndarray (6, P) and (P,), optional
        The kinematic-error factor at the sample's joints and the error.

    Returns
    -------
    h : 3 floats
    H : ndarray (3, 12 + P)
        W.r.t. ``[dC, tC, t_K, theta, z]``.
    cofactor : 6 floats
        Upper triangle ``(xx, xy, xz, yy, yz, zz)`` of `handeye.calib.model.robot_cofactor`.

    Notes
    -----
    Longer than the project's 80 lines on purpose: the engine calls it for every sample of a months-long
    run, and split into helpers it would pay a Python call per step and build the same intermediates twice;
    tests hold it to the vectorised model (tests/calib/test_monitor_engine.py).
    """
    # Written out on floats (no helper calls): the same products and sums as the 3x3 kernels above.
    (c0, c1, c2), (c3, c4, c5), (c6, c7, c8) = C[0]
    a0, a1, a2, x, a3, a4, a5, y, a6, a7, a8, z_ = pose
    if factor is not None:
        w0, w1, w2, w3, w4, w5 = factor.dot(z).tolist()
        x, y, z_ = x + (a0 * w3 + a1 * w4 + a2 * w5), y + (a3 * w3 + a4 * w4 + a5 * w5), z_ + (a6 * w3 + a7 * w4
                                                                                             + a8 * w5)
        (a0, a1, a2), (a3, a4, a5), (a6, a7, a8) = matmul3(((a0, a1, a2), (a3, a4, a5), (a6, a7, a8)),
                                                           so3_exp_scalar(w0, w1, w2))
    if eye_to_hand:
        R_M, (mx, my, mz) = ((a0, a1, a2), (a3, a4, a5), (a6, a7, a8)), (x, y, z_)
    else:
        R_M = (a0, a3, a6), (a1, a4, a7), (a2, a5, a8)
        mx, my, mz = -(a0 * x + a3 * y + a6 * z_), -(a1 * x + a4 * y + a7 * z_), -(a2 * x + a5 * y + a8 * z_)
    (m0, m1, m2), (m3, m4, m5), (m6, m7, m8) = R_M
    kx, ky, kz = t_K
    lever = (m0 * kx + m1 * ky + m2 * kz, m3 * kx + m4 * ky + m5 * kz, m6 * kx + m7 * ky + m8 * kz)
    y = (lever[0] + mx, lever[1] + my, lever[2] + mz)       # marker center in C's parent frame
    tx, ty, tz = C[1]
    vx, vy, vz = y[0] - tx, y[1] - ty, y[2] - tz
    # The point without camera error: R_C^T v.
    qx, qy, qz = c0 * vx + c3 * vy + c6 * vz, c1 * vx + c4 * vy + c7 * vz, c2 * vx + c5 * vy + c8 * vz
    s, d, f = theta
    g, D, dz = 1.0 + s + d / qz, 1.0 + f, d / (qz * qz)
    # The camera's Jacobian J_p = [[gD, 0, jx], [0, gD, jy], [0, 0, jz]], and J_p R_C^T.
    gD, jx, jy, jz = g * D, -D * qx * dz, -D * qy * dz, g - qz * dz
    JR = ((gD * c0 + jx * c2, gD * c3 + jx * c5, gD * c6 + jx * c8),
          (gD * c1 + jy * c2, gD * c4 + jy * c5, gD * c7 + jy * c8), (jz * c2, jz * c5, jz * c8))
    H_tK = matmul3(JR, R_M)
    J_theta = ((D * qx, D * qx / qz, qx * g), (D * qy, D * qy / qz, qy * g), (qz, 1.0, 0.0))
    # dq/d[dC, tC] = R_C^T [[v]x, -I]; a row r of J_p R_C^T times [v]x is r x v.
    rows = [(j1 * vz - j2 * vy, j2 * vx - j0 * vz, j0 * vy - j1 * vx, -j0, -j1, -j2) + k + J
            for (j0, j1, j2), k, J in zip(JR, H_tK, J_theta)]
    if factor is None:
        H = np.array(rows)
    else:
        # d/dxi: [-(H_tK [t_K]x), H_tK] eye-to-hand, [J_p R_C^T [y]x, -J_p R_C^T] eye-in-hand (the crosses
        # t_K x row and row x y written out).
        if eye_to_hand:
            X = [(ky * k2 - kz * k1, kz * k0 - kx * k2, kx * k1 - ky * k0, k0, k1, k2) for k0, k1, k2 in H_tK]
        else:
            y0, y1, y2 = y
            X = [(j1 * y2 - j2 * y1, j2 * y0 - j0 * y2, j0 * y1 - j1 * y0, -j0, -j1, -j2) for j0, j1, j2 in JR]
        H = np.empty((3, 12 + factor.shape[1]))
        H[:, :12] = rows
        H[:, 12:] = np.array(X).dot(factor)           # ndarray.dot: @'s product, less call overhead
    lx, ly, lz = lever if eye_to_hand else y
    lx, ly, lz = c0 * lx + c3 * ly + c6 * lz, c1 * lx + c4 * ly + c7 * lz, c2 * lx + c5 * ly + c8 * lz
    rho2 = ROBOT_RHO2
    a = 1.0 + rho2 * (lx * lx + ly * ly + lz * lz)
    return ((qx * gD, qy * gD, qz * g), H,
            (a - rho2 * lx * lx, -rho2 * lx * ly, -rho2 * lx * lz, a - rho2 * ly * ly, -rho2 * ly * lz,
             a - rho2 * lz * lz))
