"""The per-sample measurement model on plain floats (`sample_model`) and its 3x3 kernels.

One sample is a few 3x3 products: as numpy arrays each costs more in call overhead than in
arithmetic, so the engine's hot path runs them on tuples of floats. `so3_exp_scalar` and
`rotation_angle_scalar` are `calib.transforms.so3_exp` and `calib.transforms.rotation_angle` for one
rotation, with the same formulas; `sample_model` is `calib.model.point_jacobians` for one sample
(tested against it)."""

from __future__ import annotations

import math

import numpy as np

from calib import model
from calib import transforms as tf
from calib.setup import Setup



I3 = np.eye(3)
#: `calib.model.ROBOT_ROTATION_PER_M` squared (the robot cofactor's lever weight).
ROBOT_RHO2 = model.ROBOT_ROTATION_PER_M ** 2


def parts(T):
    """Rotation rows and translation of a (4, 4) transform, as floats."""
    (a, b, c, x), (d, e, f, y), (g, h, i, z), _ = T.tolist()
    return ((a, b, c), (d, e, f), (g, h, i)), (x, y, z)


def transpose3(M):
    (a, b, c), (d, e, f), (g, h, i) = M
    return (a, d, g), (b, e, h), (c, f, i)


def matvec3(M, v, k: float = 1.0):
    """``k M v``."""
    (a, b, c), (d, e, f), (g, h, i) = M
    x, y, z = v
    return k * (a * x + b * y + c * z), k * (d * x + e * y + f * z), k * (g * x + h * y + i * z)


def matmul3(M, N):
    (a, b, c), (d, e, f), (g, h, i) = M
    (p, q, r), (s, t, u), (v, w, x) = N
    return ((a * p + b * s + c * v, a * q + b * t + c * w, a * r + b * u + c * x),
            (d * p + e * s + f * v, d * q + e * t + f * w, d * r + e * u + f * x),
            (g * p + h * s + i * v, g * q + h * t + i * w, g * r + h * u + i * x))


def add3(a, b, k: float = 1.0):
    """``a + k b``."""
    return a[0] + k * b[0], a[1] + k * b[1], a[2] + k * b[2]


def scale3(a, k: float):
    return k * a[0], k * a[1], k * a[2]


def cross3(a, b):
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


def so3_exp_scalar(a0: float, a1: float, a2: float):
    """`calib.transforms.so3_exp` of one rotation vector (rad), as rows of floats (same formula and series)."""
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


def rotation_angle_scalar(R1, R2) -> float:
    """`calib.transforms.rotation_angle` of ``R1 R2^T`` (rotations as rows of floats), rad."""
    (a, b, c), (d, e, f), (g, h, i) = matmul3(R1, transpose3(R2))
    return math.atan2(math.sqrt((h - f) ** 2 + (c - g) ** 2 + (d - b) ** 2) / 2.0, (a + e + i - 1.0) / 2.0)


def inv_sym3(S) -> np.ndarray:
    """Inverse of a symmetric positive definite (3, 3) matrix (cofactors, from its upper triangle)."""
    (a, b, c), (_, d, e), (_, _, f) = S.tolist()
    return sym3(inv_sym3_floats(a, b, c, d, e, f))


def inv_sym3_floats(a, b, c, d, e, f):
    """`inv_sym3` on the upper triangle ``(xx, xy, xz, yy, yz, zz)`` as floats; the inverse's, likewise."""
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
    k = 1.0 / (a * A + b * B + c * C)
    return A * k, B * k, C * k, (a * f - c * c) * k, (b * c - a * e) * k, (a * d - b * b) * k


def sym3(upper) -> np.ndarray:
    """The symmetric (3, 3) array of an upper triangle ``(xx, xy, xz, yy, yz, zz)``."""
    A, B, C, D, E, F = upper
    return np.array(((A, B, C), (B, D, E), (C, E, F)))


def is_plain(a, shape) -> bool:
    """``a`` is a float64 array of ``shape``, finite and within `calib.transforms.MAX_MAGNITUDE`: the common case,
    which the general validators would return unchanged (anything else goes to them for their checks and message)."""
    # A sum of squares within the bound's square bounds every entry; NaN and inf fail the comparison.
    return (type(a) is np.ndarray and a.dtype == np.float64 and a.shape == shape
            and float(np.vdot(a, a)) <= tf.MAX_MAGNITUDE ** 2)


def is_plain_transform(T) -> bool:
    """`is_plain` and a rigid transform within `calib.transforms.check_transform`'s tolerances."""
    if not is_plain(T, (4, 4)):
        return False
    (a, b, c, _), (d, e, f, _), (g, h, i, _), (p, q, r, w) = T.tolist()
    atol = tf.ROTATION_ATOL
    tol = max(atol, 1e-9) * 10
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    return (abs(p) <= atol and abs(q) <= atol and abs(r) <= atol and abs(w - 1.0) <= atol
            and abs(det - 1.0) <= atol * 10
            and abs(a * a + b * b + c * c - 1.0) <= tol and abs(d * d + e * e + f * f - 1.0) <= tol
            and abs(g * g + h * h + i * i - 1.0) <= tol and abs(a * d + b * e + c * f) <= tol
            and abs(a * g + b * h + c * i) <= tol and abs(d * g + e * h + f * i) <= tol)


def is_plain_cov(S) -> bool:
    """`is_plain` and symmetric within `calib.model.check_point_cov`'s tolerance."""
    if not is_plain(S, (3, 3)):
        return False
    (a, b, c), (d, e, f), (g, h, i) = S.tolist()
    tol = 1e-9 * max(abs(a), abs(b), abs(c), abs(d), abs(e), abs(f), abs(g), abs(h), abs(i), 1e-30)
    return abs(b - d) <= tol and abs(c - g) <= tol and abs(f - h) <= tol


def sample_model(C, t_K, A, theta, setup: str, factor=None, z=None):
    """One sample's predicted measured marker point, its Jacobian w.r.t. the engine's state, and its robot cofactor.

    The single-sample form of `calib.model.point_jacobians` and
    `calib.model.robot_cofactor` (the same model, tested against them), at
    the flange pose ``A Exp(factor z)`` when the state carries the robot's
    kinematic error ``z``. The arithmetic is `sample_floats`'.

    Parameters
    ----------
    C : ndarray (4, 4)
        Camera transform.
    t_K : ndarray (3,)
        Marker-side translation.
    A : ndarray (4, 4)
        ``T_base_flange`` as the robot reports it.
    theta : ndarray (3,)
        Camera parameters (`calib.model.CAMERA_PARAMS`).
    setup : Setup
    factor, z : ndarray (6, P) and (P,), optional
        The kinematic-error factor at the sample's joints and the error.

    Returns
    -------
    h : ndarray (3,)
    H : ndarray (3, 12 + P)
        W.r.t. ``[dC, tC, t_K, theta, z]``.
    cof : ndarray (3, 3)
        `calib.model.robot_cofactor` of the sample.
    """
    h, H, (xx, xy, xz, yy, yz, zz) = sample_floats(parts(C), tuple(t_K.tolist()), A[:3].ravel().tolist(),
                                                   theta.tolist(), setup == Setup.EYE_TO_HAND, factor, z)
    return np.array(h), H, np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def sample_floats(C, t_K, pose, theta, eye_to_hand: bool, factor=None, z=None):
    """`sample_model` on floats, for the engine's hot path: numpy's per-call cost would be most of its per-sample
    cost on 3-vectors and 3x3 blocks.

    ``C`` is the camera transform as `parts`, ``pose`` the flange pose's first
    three rows flat (12 floats), ``t_K`` and ``theta`` 3 floats each. Returns
    ``h`` (3 floats), ``H`` (ndarray (3, 12 + P)) and the cofactor's upper
    triangle ``(xx, xy, xz, yy, yz, zz)``.
    """
    R_C, t_C = C
    a0, a1, a2, x, a3, a4, a5, y, a6, a7, a8, z_ = pose
    R_A, t_A = ((a0, a1, a2), (a3, a4, a5), (a6, a7, a8)), (x, y, z_)
    if factor is not None:
        w0, w1, w2, w3, w4, w5 = (factor @ z).tolist()
        t_A = add3(t_A, matvec3(R_A, (w3, w4, w5)))
        R_A = matmul3(R_A, so3_exp_scalar(w0, w1, w2))
    if eye_to_hand:
        R_M, t_M = R_A, t_A
    else:
        R_M = transpose3(R_A)
        t_M = matvec3(R_M, t_A, -1.0)
    lever = matvec3(R_M, t_K)
    y = add3(lever, t_M)                                # marker center in C's parent frame
    v = add3(y, t_C, -1.0)
    Ct = transpose3(R_C)
    qx, qy, qz = matvec3(Ct, v)                             # the point without camera error
    s, d, f = theta
    g, D, dz = 1.0 + s + d / qz, 1.0 + f, d / (qz * qz)
    # The camera's Jacobian J_p = [[gD, 0, jx], [0, gD, jy], [0, 0, jz]], and J_p R_C^T.
    gD, jx, jy, jz = g * D, -D * qx * dz, -D * qy * dz, g - qz * dz
    c0, c1, c2 = Ct
    JR = (add3(scale3(c0, gD), c2, jx), add3(scale3(c1, gD), c2, jy), scale3(c2, jz))
    H_tK = matmul3(JR, R_M)
    J_theta = ((D * qx, D * qx / qz, qx * g), (D * qy, D * qy / qz, qy * g), (qz, 1.0, 0.0))
    # dq/d[dC, tC] = R_C^T [[v]x, -I]; a row r of J_p R_C^T times [v]x is r x v.
    rows = [cross3(JR[i], v) + scale3(JR[i], -1.0) + H_tK[i] + J_theta[i] for i in range(3)]
    if factor is None:
        H = np.array(rows)
    else:
        # d/dxi: [-(H_tK [t_K]x), H_tK] eye-to-hand, [J_p R_C^T [y]x, -J_p R_C^T] eye-in-hand.
        if eye_to_hand:
            X = [cross3(t_K, H_tK[i]) + H_tK[i] for i in range(3)]
        else:
            X = [cross3(JR[i], y) + scale3(JR[i], -1.0) for i in range(3)]
        H = np.empty((3, 12 + factor.shape[1]))
        H[:, :12] = rows
        H[:, 12:] = np.array(X) @ factor
    lx, ly, lz = matvec3(Ct, lever if eye_to_hand else y)
    rho2 = ROBOT_RHO2
    a = 1.0 + rho2 * (lx * lx + ly * ly + lz * lz)
    return ((qx * gD, qy * gD, qz * g), H,
            (a - rho2 * lx * lx, -rho2 * lx * ly, -rho2 * lx * lz, a - rho2 * ly * ly, -rho2 * ly * lz,
             a - rho2 * lz * lz))
