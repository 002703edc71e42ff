"""Closed-form hand-eye solvers of Table I of the paper (Grossmann & Krueger).

Every solver here is a pure function of the robot poses ``A`` (``T_base_flange``)
and the camera measurements ``B`` (``T_cam_marker`` poses, or marker points in
the camera frame for the point-only YKronT'). Equation numbers refer to the
paper ``continuous-hand-eye-calibration-3d-points.tex``:

- (1) ``A_i X = Y B_i``; (2) ``(A_{i+1}^-1 A_i) X = X (B_{i+1}^-1 B_i)``;
- (4) ``R_A R_X = R_Y R_B`` (equation of rotation);
- (5) ``R_A t_X + t_A = R_Y t_B + t_Y`` (equation of translation), (6) its
  least-squares form for known rotations, (7) rearranged for simultaneous solving;
- (9) quaternion form of (4), (10) quaternion form of (7);
- (12) Kronecker form of (4), (13) Kronecker form of (7);
- (16) stacked homogeneous rotation system, (17) ``K = sum M-(R_B)^T M+(R_A)``
  decomposed by SVD, (18) orthogonal Procrustes on rotation axes;
- (19) YQuatT', (20) YKronT' (the paper's proposed translation-only solvers).

Setups. Eye-to-hand (static camera, marker on the flange):
``T_base_flange @ T_flange_marker = T_base_cam @ T_cam_marker`` so
``X = T_flange_marker``, ``Y = T_base_cam``. Eye-in-hand (camera on the flange,
static marker): ``T_base_flange @ T_flange_cam @ T_cam_marker = T_base_marker``,
i.e. ``A_i X B_i = Y`` with ``X = T_flange_cam``, ``Y = T_base_marker``; the
pose-based solvers handle it as ``A_i X = Y B_i^-1`` (eq. 1 with ``B`` inverted),
the point-only YKronT' has its own system (see `y_kron_t_prime`).

AX=XB solvers use the consecutive pairs ``(i, i+1)`` of eq. 2 and then get ``Y``
as the least-squares average of ``A_i X B_i^-1`` (rotation projected to SO(3)).

Internally quaternions are scalar-last ``(x, y, z, w)`` like the rest of handeye.
``vec`` is the column-major vectorisation used by the Kronecker identities
``vec(A X B) = (B^T kron A) vec(X)``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError, DegenerateMotionError, InsufficientDataError
from handeye.calib.setup import Setup, check_setup

#: A linear system is called degenerate when the singular value that must be
#: non-zero for a unique solution is below this fraction of the largest one
#: (for the top-vector problems of eq. 17: the square root of the relative gap
#: between the two largest values, which scales like the motion angle). Measured
#: (see docs/solvers.md): good motions of +-5 deg and more about varied axes stay
#: above ~3e-3 with realistic noise; rotations about one axis, pure translations
#: or identical poses give ~1e-16 noise-free. Every solver first checks the
#: system ``[R_A, -I]`` of eq. 6 built from the robot poses alone, so marker
#: noise cannot mask a degenerate motion set (robot rotation noise of 0.01 deg
#: on a degenerate set gives ~1e-4 there and is still caught).
DEGENERACY_RTOL = 1e-3

#: Marker points closer than this to the camera origin (m) are refused: no depth
#: camera measures there, and the viewing ray (the noise model's axis) is undefined.
MIN_MARKER_DISTANCE = 1e-3

_I3 = np.eye(3)


# ---------------------------------------------------------------- validation


def check_pose_pairs(A, B, minimum: int) -> tuple[np.ndarray, np.ndarray]:
    """Validate robot poses ``A`` (N, 4, 4) and marker poses ``B`` (N, 4, 4) with N >= ``minimum``."""
    A = tf.check_transforms(A, "A")
    B = tf.check_transforms(B, "B")
    _check_counts(len(A), len(B), minimum)
    return A, B


def check_point_pairs(A, p, minimum: int) -> tuple[np.ndarray, np.ndarray]:
    """Validate robot poses ``A`` (N, 4, 4) and marker points ``p`` (N, 3) with N >= ``minimum``."""
    A = tf.check_transforms(A, "A")
    p = tf.check_points(p, "points")
    _check_counts(len(A), len(p), minimum)
    return A, p


def check_measurements(A, B) -> tuple[np.ndarray, np.ndarray]:
    """Validate robot poses ``A`` (N, 4, 4) and marker measurements ``B`` (N, 3) or (N, 4, 4)."""
    A = tf.check_transforms(A, "A")
    B = tf.as_real_array(B, "B")
    if B.ndim == 2:
        B = tf.check_points(B, "B")
    elif B.ndim == 3:
        B = tf.check_transforms(B, "B")
    else:
        raise CalibrationError(f"B must have shape (N, 4, 4) or (N, 3), got {B.shape}")
    if len(A) != len(B):
        raise CalibrationError(f"A and B must have the same number of samples, got {len(A)} and {len(B)}")
    p = B if B.ndim == 2 else B[:, :3, 3]
    far = np.einsum("ni,ni->n", p, p) >= MIN_MARKER_DISTANCE**2
    if not far.all():
        i = int(np.argmin(far))
        raise CalibrationError(f"B[{i}]: marker point {p[i].tolist()} lies at the camera origin "
                               f"(closer than {MIN_MARKER_DISTANCE * 1e3:g} mm): not a measurement")
    return A, B


def _check_counts(n_a: int, n_b: int, minimum: int) -> None:
    if n_a != n_b:
        raise CalibrationError(f"A and B must have the same number of samples, got {n_a} and {n_b}")
    if n_a < minimum:
        raise InsufficientDataError(f"need at least {minimum} samples, got {n_a}")


# ------------------------------------------------------------ small helpers


def quat_left(q: np.ndarray) -> np.ndarray:
    """``Q+(q)`` (..., 4, 4) with ``q p = Q+(q) p`` (Hamilton product, scalar-last), eq. 8."""
    v, w = q[..., :3], q[..., 3]
    M = np.empty(q.shape[:-1] + (4, 4))
    M[..., :3, :3] = w[..., None, None] * _I3 + tf.skew(v)
    M[..., :3, 3] = v
    M[..., 3, :3] = -v
    M[..., 3, 3] = w
    return M


def quat_right(q: np.ndarray) -> np.ndarray:
    """``Q-(q)`` (..., 4, 4) with ``p q = Q-(q) p`` (Hamilton product, scalar-last), eq. 8."""
    v, w = q[..., :3], q[..., 3]
    M = np.empty(q.shape[:-1] + (4, 4))
    M[..., :3, :3] = w[..., None, None] * _I3 - tf.skew(v)
    M[..., :3, 3] = v
    M[..., 3, :3] = -v
    M[..., 3, 3] = w
    return M


def _quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (N, 4), scalar-last, of rotations (N, 3, 3)."""
    return Rotation.from_matrix(R).as_quat()


def _mat(q: np.ndarray) -> np.ndarray:
    return Rotation.from_quat(q).as_matrix()


def _unvec(v: np.ndarray) -> np.ndarray:
    return v.reshape(3, 3).T


def _kron_t(t: np.ndarray) -> np.ndarray:
    """``t^T kron I3`` (N, 3, 9) for vectors t (N, 3): ``(t^T kron I) vec(R) = R t``."""
    return (t[:, None, :, None] * _I3[None, :, None, :]).reshape(len(t), 3, 9)


def _kron_I_left(R: np.ndarray) -> np.ndarray:
    """``I3 kron R`` (N, 9, 9): ``(I kron R) vec(X) = vec(R X)``."""
    return np.einsum("jk,nrc->njrkc", _I3, R).reshape(len(R), 9, 9)


def _kron_right_I(R: np.ndarray) -> np.ndarray:
    """``R^T kron I3`` (N, 9, 9): ``(R^T kron I) vec(X) = vec(X R)``."""
    return np.einsum("nkj,rc->njrkc", R, _I3).reshape(len(R), 9, 9)


def _scaled_rotation(M: np.ndarray) -> np.ndarray:
    """Nearest rotation to a 3x3 matrix known only up to scale (and sign), e.g. a singular vector."""
    d = np.linalg.det(M)
    if abs(d) < 1e-300:
        raise DegenerateMotionError("the rotation estimate is singular: motions do not constrain the rotation")
    return tf.project_to_so3(M * (np.sign(d) / abs(d) ** (1.0 / 3.0)))


def _relative_motions(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive relative motions of eq. 2: ``A_{i+1}^-1 A_i`` and ``B_{i+1}^-1 B_i`` (N-1, 4, 4)."""
    return tf.invert(A[1:]) @ A[:-1], tf.invert(B[1:]) @ B[:-1]


def _lstsq(M: np.ndarray, b: np.ndarray, what: str, A_robot: np.ndarray) -> np.ndarray:
    """Least squares ``M x = b``; raise DegenerateMotionError unless M has full column rank.

    Solved through the normal equations (at most 24 unknowns): one BLAS
    product and a small eigen-decomposition, which also gives the singular
    values of M (square roots of the eigenvalues) for the degeneracy test.
    """
    w, V = np.linalg.eigh(M.T @ M)
    s = np.sqrt(np.clip(w[::-1], 0.0, None))
    _check_singular_values(s, -1, what, A_robot)
    return V @ ((V.T @ (M.T @ b)) / w)


def _check_singular_values(s: np.ndarray, index: int, what: str, A_robot: np.ndarray) -> float:
    # An all-zero system (e.g. relative motions of identical poses) has no meaningful ratio.
    ratio = float(s[index] / s[0]) if s[0] > 1e-9 else 0.0
    if not ratio >= DEGENERACY_RTOL:
        raise DegenerateMotionError(
            f"{diagnose_motion(A_robot)} (relative singular value {ratio:.1e} < {DEGENERACY_RTOL:g} in {what})"
        )
    return ratio


def _check_gap(top: float, second: float, what: str, A_robot: np.ndarray) -> None:
    """Eigen/singular-value gap test for the top-vector problems of eq. 17."""
    # The gap grows like 1 - cos(angle / 2), i.e. quadratically: compare its square root.
    gap = np.sqrt(max(top - second, 0.0) / top) if top > 1e-9 else 0.0
    if not gap >= DEGENERACY_RTOL:
        raise DegenerateMotionError(
            f"{diagnose_motion(A_robot)} (sqrt of the relative gap of the two largest values "
            f"{gap:.1e} < {DEGENERACY_RTOL:g} in {what})"
        )


def diagnose_motion(A: np.ndarray) -> str:
    """Say what the robot motions ``A`` (N, 4, 4) lack, in words a user can act on.

    Looks at the flange rotations relative to the first sample: none, all about
    one axis, or identical poses. Used to phrase DegenerateMotionError messages;
    the decision itself is made from the conditioning of the solver's system.
    """
    R_rel = np.swapaxes(A[:1, :3, :3], 1, 2) @ A[:, :3, :3]
    rv = Rotation.from_matrix(R_rel).as_rotvec()
    angles = np.linalg.norm(rv, axis=1)
    spread_t = float(np.ptp(A[:, :3, 3], axis=0).max())
    if angles.max() < np.deg2rad(0.5):
        if spread_t < 1e-4:
            return (f"no motion: all {len(A)} robot poses are identical; move the flange "
                    "(rotate about at least two non-parallel axes and translate)")
        return ("no rotation: pure translations cannot determine the rotation and the "
                "flange-side translation; rotate the flange about at least two non-parallel axes")
    _, s, Vt = np.linalg.svd(rv, full_matrices=False)
    if s[1] < np.sin(np.deg2rad(1.0)) * s[0]:
        axis = Vt[0] * np.sign(Vt[0][np.argmax(np.abs(Vt[0]))])
        signed = np.rad2deg(rv @ axis)
        half_range = (signed.max() - signed.min()) / 2.0
        return (f"all rotations are about one axis (+-{half_range:.1f} deg about flange axis "
                f"[{axis[0]:.2f}, {axis[1]:.2f}, {axis[2]:.2f}]): rotate about at least two non-parallel axes")
    return ("the motions are too small or too similar to determine all unknowns: "
            "vary the flange orientation about several axes and its position")


def _align_signs(qa: np.ndarray, qb: np.ndarray, same_angle: bool) -> tuple[np.ndarray, np.ndarray]:
    """First-pass quaternion signs (double cover, paper sec. V) so that ``a_i x = y b_i`` holds with + for all i.

    AX=XB: ``a`` and ``b`` have the same rotation angle, so scalar parts >= 0
    on both sides agree (except near 180 deg, fixed by `_resign`). AX=YB: align
    every ``a_i`` with ``a_0`` and every ``b_i`` with ``b_0``; since
    ``q -> q x`` and ``q -> y q`` are isometries of R^4,
    ``a_i . a_0 = s_i s_0 (b_i . b_0)`` for ``a_i x = s_i y b_i``, so the signs
    agree on exact data; noise can break this only for samples rotated about
    180 deg from the first, which `_resign` repairs with the first estimate.
    """
    if same_angle:
        return qa * np.where(qa[:, 3:] < 0, -1.0, 1.0), qb * np.where(qb[:, 3:] < 0, -1.0, 1.0)
    return qa * np.where(qa @ qa[0] < 0, -1.0, 1.0)[:, None], qb * np.where(qb @ qb[0] < 0, -1.0, 1.0)[:, None]


def _resign(qa: np.ndarray, qb: np.ndarray, qx: np.ndarray, qy: np.ndarray) -> tuple[np.ndarray, bool]:
    """Flip ``b_i`` where ``(a_i x) . (y b_i) < 0`` for a first estimate (x, y); return new b and whether any flipped."""
    lhs = np.einsum("nij,j->ni", quat_left(qa), qx)
    rhs = np.einsum("nij,j->ni", quat_right(qb), qy)
    flip = np.einsum("ni,ni->n", lhs, rhs) < 0
    return qb * np.where(flip, -1.0, 1.0)[:, None], bool(flip.any())


# ----------------------------------------------------- translation back-ends


def _translation_xy(R_X, R_Y, A, B) -> tuple[np.ndarray, np.ndarray]:
    """``t_X, t_Y`` from eq. 6: ``[R_A, -I][t_X; t_Y] = R_Y t_B - t_A`` (3N x 6 least squares)."""
    b = np.einsum("ij,nj->ni", R_Y, B[:, :3, 3]) - A[:, :3, 3]
    x = _lstsq(_robot_translation_system(A), b.reshape(-1), "eq. 6 (translations)", A)
    return x[:3], x[3:]


def _robot_translation_system(A: np.ndarray) -> np.ndarray:
    """``[R_A, -I]`` (3N x 6) of eq. 6: rank 6 iff the flange rotates about two non-parallel axes."""
    n = len(A)
    M = np.empty((n, 3, 6))
    M[:, :, :3] = A[:, :3, :3]
    M[:, :, 3:] = -_I3
    return M.reshape(3 * n, 6)


def _check_robot_excitation(A: np.ndarray) -> None:
    """Degeneracy test on the robot poses alone (eq. 6), for solvers whose own system mixes in marker noise."""
    M = _robot_translation_system(A)
    s = np.sqrt(np.clip(np.linalg.eigvalsh(M.T @ M)[::-1], 0.0, None))
    _check_singular_values(s, -1, "eq. 6 (robot rotations)", A)


def _translation_x_axxb(R_X, A_rel, B_rel, A_robot) -> np.ndarray:
    """``t_X`` of AX=XB from eq. 5 with Y = X: ``(I - R_A) t_X = t_A - R_X t_B`` (relative motions)."""
    m = len(A_rel)
    M = (_I3 - A_rel[:, :3, :3]).reshape(3 * m, 3)
    b = (A_rel[:, :3, 3] - B_rel[:, :3, 3] @ R_X.T).reshape(-1)
    return _lstsq(M, b, "eq. 5 of AX=XB (translation of X)", A_robot)


def _complete_y(X: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``Y`` as the least-squares average of ``A_i X B_i^-1``: chordal-mean rotation, mean translation."""
    R_Y = tf.project_to_so3((A[:, :3, :3] @ X[:3, :3] @ np.swapaxes(B[:, :3, :3], 1, 2)).sum(axis=0))
    t_Y = np.mean(A[:, :3, :3] @ X[:3, 3] + A[:, :3, 3] - B[:, :3, 3] @ R_Y.T, axis=0)
    return tf.make_transform(R_Y, t_Y)


def _complete_x(Y: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``X`` as the least-squares average of ``A_i^-1 Y B_i`` (eq. 5 with ``R_Y, t_Y`` fixed)."""
    R_At = np.swapaxes(A[:, :3, :3], 1, 2)
    R_X = tf.project_to_so3((R_At @ (Y[:3, :3] @ B[:, :3, :3])).sum(axis=0))
    t_X = np.mean(np.einsum("nij,nj->ni", R_At, B[:, :3, 3] @ Y[:3, :3].T + Y[:3, 3] - A[:, :3, 3]), axis=0)
    return tf.make_transform(R_X, t_X)


def _finish_axxb(R_X, A, B, A_rel, B_rel) -> tuple[np.ndarray, np.ndarray]:
    t_X = _translation_x_axxb(R_X, A_rel, B_rel, A)
    X = tf.make_transform(R_X, t_X)
    return X, _complete_y(X, A, B)


# ------------------------------------------------------------ AX=XB solvers


def x_axis_rx(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """XAxisRX (Park & Martin 1994): Procrustes on rotation axes, eq. 18, AX=XB.

    For each consecutive pair (eq. 2) ``R_A = R_X R_B R_X^T`` so the rotation
    vectors satisfy ``r_A = R_X r_B``; ``R_X`` is the orthogonal Procrustes
    solution (SVD of ``sum r_A r_B^T``). ``t_X`` from eq. 5 on the pairs, then
    ``Y`` averaged from ``A_i X B_i^-1``. Eye-to-hand form ``A_i X = Y B_i``.

    Parameters
    ----------
    A, B : ndarray, shape (N, 4, 4)
        ``T_base_flange`` and ``T_cam_marker`` (eye-to-hand), N >= 3.

    Returns
    -------
    X, Y : ndarray, shape (4, 4)
    """
    A, B = check_pose_pairs(A, B, 3)
    _check_robot_excitation(A)
    A_rel, B_rel = _relative_motions(A, B)
    ra = Rotation.from_matrix(A_rel[:, :3, :3]).as_rotvec()
    rb = Rotation.from_matrix(B_rel[:, :3, :3]).as_rotvec()

    def procrustes(rb):
        U, s, Vt = np.linalg.svd(ra.T @ rb)
        # Rank 2 suffices (the third axis follows from orthogonality), so test the 2nd value.
        _check_singular_values(s, 1, "eq. 18 (Procrustes on rotation axes)", A)
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
        return U @ D @ Vt

    R_X = procrustes(rb)
    # Near 180 deg noise can make the log map pick the opposite axis on one
    # side; where the equivalent vector -(2 pi - angle) axis fits the first
    # estimate better, use it (it never does for rotations far from 180 deg).
    ang = np.linalg.norm(rb, axis=1, keepdims=True)
    rb_alt = rb * (1.0 - 2.0 * np.pi / np.maximum(ang, 1e-12))
    flip = np.linalg.norm(ra - rb_alt @ R_X.T, axis=1) < np.linalg.norm(ra - rb @ R_X.T, axis=1)
    if flip.any():
        rb[flip] = rb_alt[flip]
        R_X = procrustes(rb)
    return _finish_axxb(R_X, A, B, A_rel, B_rel)


def x_quat_r_star(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """XQuatR* (cf. Dornaika & Horaud 1998): quaternion form of eq. 17 for AX=XB.

    Eq. 9 gives ``Q-(b)^T Q+(a) x = x`` per relative motion (eq. 2), so ``x``
    maximises ``x^T K x`` with ``K = sum Q-(b)^T Q+(a)``: the eigenvector of
    the largest eigenvalue of ``(K + K^T) / 2`` (eq. 17 with the AX=XB
    constraint ``y = x``). ``t_X`` from eq. 5, ``Y`` by averaging. Eye-to-hand
    form; N >= 3 poses (N, 4, 4) each.
    """
    A, B = check_pose_pairs(A, B, 3)
    _check_robot_excitation(A)
    A_rel, B_rel = _relative_motions(A, B)
    qa, qb = _align_signs(_quat(A_rel[:, :3, :3]), _quat(B_rel[:, :3, :3]), same_angle=True)

    def top(qb):
        K = np.tensordot(quat_right(qb), quat_left(qa), axes=([0, 1], [0, 1]))
        w, V = np.linalg.eigh((K + K.T) / 2.0)
        _check_gap(w[-1], w[-2], "eq. 17 (quaternion K)", A)
        return V[:, -1]

    qx = top(qb)
    qb, changed = _resign(qa, qb, qx, qx)
    if changed:
        qx = top(qb)
    return _finish_axxb(_mat(qx), A, B, A_rel, B_rel)


def x_kron_r_star(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """XKronR* (cf. Shah 2013): Kronecker form of eq. 17 for AX=XB.

    Eq. 12 per relative motion: ``(R_B kron R_A) vec(R_X) = vec(R_X)``; ``vec(R_X)``
    is the top eigenvector of the symmetric part of ``K = sum R_B kron R_A``,
    rescaled to det 1 and projected to SO(3). ``t_X`` from eq. 5, ``Y`` by
    averaging. Eye-to-hand form; N >= 3 poses.
    """
    A, B = check_pose_pairs(A, B, 3)
    _check_robot_excitation(A)
    A_rel, B_rel = _relative_motions(A, B)
    m = len(A_rel)
    K = (B_rel[:, :3, :3].reshape(m, 9).T @ A_rel[:, :3, :3].reshape(m, 9)).reshape(3, 3, 3, 3)
    K = K.transpose(0, 2, 1, 3).reshape(9, 9)
    w, V = np.linalg.eigh((K + K.T) / 2.0)
    _check_gap(w[-1], w[-2], "eq. 17 (Kronecker K)", A)
    return _finish_axxb(_scaled_rotation(_unvec(V[:, -1])), A, B, A_rel, B_rel)


def x_kron_rt(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """XKronRT (Andreff et al. 2001): rotation and translation stacked, eq. 16 + eq. 13, AX=XB.

    Per relative motion (eq. 2) the 12 x 12 block rows
    ``[I kron R_A - R_B^T kron I, 0; t_B^T kron I, I - R_A] [vec(R_X); t_X] = [0; t_A]``
    are solved together by least squares; ``R_X`` is reorthonormalised and
    ``t_X`` re-solved from eq. 5 with it, ``Y`` by averaging. Eye-to-hand
    form; N >= 3 poses.
    """
    A, B = check_pose_pairs(A, B, 3)
    _check_robot_excitation(A)
    A_rel, B_rel = _relative_motions(A, B)
    m = len(A_rel)
    M = np.zeros((m, 12, 12))
    M[:, :9, :9] = _kron_I_left(A_rel[:, :3, :3]) - _kron_right_I(B_rel[:, :3, :3])
    M[:, 9:, :9] = _kron_t(B_rel[:, :3, 3])
    M[:, 9:, 9:] = _I3 - A_rel[:, :3, :3]
    b = np.zeros((m, 12))
    b[:, 9:] = A_rel[:, :3, 3]
    x = _lstsq(M.reshape(12 * m, 12), b.reshape(-1), "eq. 16 + 13 (Andreff)", A)
    return _finish_axxb(tf.project_to_so3(_unvec(x[:9])), A, B, A_rel, B_rel)


def x_kron_t(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """XKronT: the equation of translation alone, eq. 13 with Y = X, AX=XB.

    Per relative motion (eq. 2): ``(t_B^T kron I) vec(R_X) + (I - R_A) t_X = t_A``,
    a 3(N-1) x 12 least-squares system; ``R_X`` reorthonormalised, ``t_X``
    re-solved with it, ``Y`` by averaging. Note that the relative translation
    ``t_B = R_{B,i+1}^T (t_{B,i} - t_{B,i+1})`` needs the marker rotations,
    so unlike YKronT' this method needs marker poses. Eye-to-hand form;
    N >= 5 poses (12 unknowns, 3 rows per pair).
    """
    A, B = check_pose_pairs(A, B, 5)
    _check_robot_excitation(A)
    A_rel, B_rel = _relative_motions(A, B)
    m = len(A_rel)
    M = np.empty((m, 3, 12))
    M[:, :, :9] = _kron_t(B_rel[:, :3, 3])
    M[:, :, 9:] = _I3 - A_rel[:, :3, :3]
    x = _lstsq(M.reshape(3 * m, 12), A_rel[:, :3, 3].reshape(-1), "eq. 13 of AX=XB", A)
    return _finish_axxb(tf.project_to_so3(_unvec(x[:9])), A, B, A_rel, B_rel)


# ------------------------------------------------------------ AX=YB solvers


#: Pre-rotations tried by YAxisR: the identity and the half-turns about x, y, z
#: as quaternions (scalar-last). Right-multiplying a quaternion by one of them
#: permutes its components (up to sign), so one of the four gives a scalar
#: part of at least 1/2 in magnitude.
_HALF_TURNS = np.array([[0.0, 0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])


def _zhuang_system(qa: np.ndarray, qb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Zhuang's reduced eq. 9 (see `y_axis_r`): ``M [x_v / y_0; y_v / y_0] = rhs``.

    ``qa``, ``qb`` (..., N, 4) with broadcastable leading axes (several frame
    choices at once); returns M (..., 3N, 6) and rhs (..., 3N).
    """
    av, a0, bv, b0 = qa[..., :3], qa[..., 3, None, None], qb[..., :3], qb[..., 3, None, None]
    lead = np.broadcast_shapes(qa.shape[:-1], qb.shape[:-1])
    M = np.empty(lead + (3, 6))
    M[..., :3] = a0**2 * _I3 + av[..., :, None] * av[..., None, :] + a0 * tf.skew(av)
    M[..., 3:] = a0 * tf.skew(bv) - a0 * b0 * _I3 - av[..., :, None] * bv[..., None, :]
    rhs = a0[..., 0] * bv - b0[..., 0] * av
    return M.reshape(lead[:-1] + (3 * lead[-1], 6)), np.broadcast_to(rhs, lead + (3,)).reshape(lead[:-1] + (-1,))


def _zhuang_solve(qa: np.ndarray, qb: np.ndarray, A_robot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit quaternions ``x``, ``y`` from Zhuang's reduced eq. 9 for sign-aligned ``a_i``, ``b_i`` (N, 4)."""
    M, rhs = _zhuang_system(qa, qb)
    sol = _lstsq(M, rhs, "Zhuang's reduced eq. 9", A_robot)
    xv, yv = sol[:3], sol[3:]
    a0 = qa[:, 3]
    # x_0 / y_0 from the scalar rows a_0 x_0 = b_0 y_0 - b_v.y_v + a_v.x_v (least squares).
    x0 = np.dot(a0, qb[:, 3] - qb[:, :3] @ yv + qa[:, :3] @ xv) / np.dot(a0, a0)
    qx, qy = np.append(xv, x0), np.append(yv, 1.0)
    return qx / np.linalg.norm(qx), qy / np.linalg.norm(qy)


#: YAxisR picks its pre-rotations on at most this many samples (evenly spaced):
#: the choice needs only the rough conditioning, and 16 systems over all of N
#: samples would cost more than the solve itself.
ZHUANG_FRAME_SAMPLES = 64


def _zhuang_frames(qa: np.ndarray, qb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flange and camera pre-rotations ``d``, ``c`` (from `_HALF_TURNS`) giving the best-conditioned reduced system.

    Zhuang's system is singular when ``y_0 = 0`` (it then has the non-zero
    null vector ``[x_v; y_v]``) and loses rows where ``a_0 = 0``; both show as
    a small least singular value relative to the largest, so the pair that
    maximises that ratio keeps ``y'_0`` and the ``a'_0`` away from zero.
    """
    keep = np.unique(np.linspace(0, len(qa) - 1, min(len(qa), ZHUANG_FRAME_SAMPLES)).astype(int))
    qa, qb = qa[keep], qb[keep]
    # All 16 systems at once: axis 0 indexes d, axis 1 indexes c.
    qa_d = np.einsum("nj,dij->dni", qa, quat_right(_HALF_TURNS))[:, None]
    qb_c = np.einsum("nj,cij->cni", qb, quat_left(_HALF_TURNS))[None]
    M, _ = _zhuang_system(qa_d, qb_c)
    w = np.linalg.eigvalsh(np.swapaxes(M, -1, -2) @ M)
    ratio = w[..., 0] / np.maximum(w[..., -1], 1e-300)  # an all-zero system rates 0
    d, c = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    return _HALF_TURNS[d], _HALF_TURNS[c]


def y_axis_r(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """YAxisR (Zhuang, Roth & Sudhakar 1994): eq. 9 reduced to a 6-unknown linear system, AX=YB.

    With ``a = (a_v, a_0)``, ``b``, ``x``, ``y`` unit quaternions (eq. 9,
    ``a x = y b``), the scalar row gives ``a_0 x_0 = b_0 y_0 - b_v.y_v + a_v.x_v``;
    inserting ``a_0`` times it into the vector rows and dividing by ``y_0``
    (Zhuang's scalar-into-imaginary reduction) gives, per sample,
    ``(a_0^2 I + a_v a_v^T + a_0 [a_v]x) x' + (a_0 [b_v]x - a_0 b_0 I - a_v b_v^T) y'
    = a_0 b_v - b_0 a_v`` with ``x' = x_v / y_0``, ``y' = y_v / y_0``;
    ``x_0 / y_0`` follows from the scalar rows by least squares.

    The reduction is singular for ``y_0 = 0`` (``R_Y`` a half-turn) and drops
    rows where ``a_0 = 0`` (robot half-turns); with noise it degrades well
    before (mean rotation error ~60 deg on the paper's experiment 1 without
    the fix below). As Zhuang et al. suggest for ``y_0 = 0``, the data are
    first expressed in rotated flange and camera frames,
    ``a'_i = a_i d``, ``b'_i = c b_i`` so that ``a'_i x' = y' b'_i`` with
    ``x' = d* x``, ``y' = y c*``; ``d`` and ``c`` are chosen among the identity
    and the half-turns about x, y, z (16 pairs) to make the reduced system
    best conditioned (see `_zhuang_frames`), which keeps ``|y'_0|`` and the
    ``|a'_0|`` well away from 0. The solution is
    rotated back: ``x = d x'``, ``y = y' c``. Translations from eq. 6.
    Eye-to-hand form; N >= 3 poses.

    Parameters
    ----------
    A, B : ndarray, shape (N, 4, 4)
        ``T_base_flange`` and ``T_cam_marker`` (eye-to-hand), N >= 3.

    Returns
    -------
    X, Y : ndarray, shape (4, 4)
    """
    A, B = check_pose_pairs(A, B, 3)
    _check_robot_excitation(A)
    R_X, R_Y = zhuang_rotations(A, B)
    t_X, t_Y = _translation_xy(R_X, R_Y, A, B)
    return tf.make_transform(R_X, t_X), tf.make_transform(R_Y, t_Y)


def zhuang_rotations(A: np.ndarray, B: np.ndarray, *, pre_rotate: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """``R_X``, ``R_Y`` of YAxisR (see `y_axis_r`) for pose pairs `check_pose_pairs` has passed.

    Parameters
    ----------
    A, B : ndarray, shape (N, 4, 4)
        ``T_base_flange`` and ``T_cam_marker`` (eye-to-hand).
    pre_rotate : bool
        Solve in the best-conditioned rotated frames (`_zhuang_frames`), as `y_axis_r` does. False
        solves Zhuang's reduction in the given frames, singular when ``y_0 = 0``: the variant that
        `bench.yaxisr` compares against.

    Returns
    -------
    R_X, R_Y : ndarray, shape (3, 3)
    """
    qa, qb = _align_signs(_quat(A[:, :3, :3]), _quat(B[:, :3, :3]), same_angle=False)
    d = c = _HALF_TURNS[0]
    if pre_rotate:
        # A fixed rotation is an isometry of R^4, so the sign alignment carries over.
        d, c = _zhuang_frames(qa, qb)
        qa, qb = qa @ quat_right(d).T, qb @ quat_left(c).T
    qx, qy = _zhuang_solve(qa, qb, A)
    qb, changed = _resign(qa, qb, qx, qy)
    if changed:
        qx, qy = _zhuang_solve(qa, qb, A)
    return _mat(quat_left(d) @ qx), _mat(quat_right(c) @ qy)


def y_quat_r_star(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """YQuatR* (Dornaika & Horaud 1998): eq. 17 with quaternions, AX=YB.

    ``K = sum Q-(b)^T Q+(a)`` (4 x 4); ``x`` is its right and ``y`` its left
    singular vector of the largest singular value (``K x = N y`` noise-free).
    Translations from eq. 6. Eye-to-hand form; N >= 3 poses.
    """
    A, B = check_pose_pairs(A, B, 3)
    _check_robot_excitation(A)
    qa, qb = _align_signs(_quat(A[:, :3, :3]), _quat(B[:, :3, :3]), same_angle=False)

    def top(qb):
        K = np.tensordot(quat_right(qb), quat_left(qa), axes=([0, 1], [0, 1]))
        U, s, Vt = np.linalg.svd(K)
        _check_gap(s[0], s[1], "eq. 17 (quaternion K)", A)
        return Vt[0], U[:, 0]

    qx, qy = top(qb)
    qb, changed = _resign(qa, qb, qx, qy)
    if changed:
        qx, qy = top(qb)
    R_X, R_Y = _mat(qx), _mat(qy)
    t_X, t_Y = _translation_xy(R_X, R_Y, A, B)
    return tf.make_transform(R_X, t_X), tf.make_transform(R_Y, t_Y)


def y_kron_rt(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """YKronRT (Li, Wang & Wu 2010): eq. 16 stacked with eq. 13, AX=YB.

    Per sample the 12 x 24 block rows
    ``[I kron R_A, -R_B^T kron I, 0, 0; 0, t_B^T kron I, -R_A, I]
    [vec(R_X); vec(R_Y); t_X; t_Y] = [0; t_A]`` are solved by least squares;
    both rotations are reorthonormalised and the translations re-solved from
    eq. 6 with ``R_Y`` fixed. Eye-to-hand form; N >= 3 poses.
    """
    A, B = check_pose_pairs(A, B, 3)
    _check_robot_excitation(A)
    n = len(A)
    M = np.zeros((n, 12, 24))
    M[:, :9, :9] = _kron_I_left(A[:, :3, :3])
    M[:, :9, 9:18] = -_kron_right_I(B[:, :3, :3])
    M[:, 9:, 9:18] = _kron_t(B[:, :3, 3])
    M[:, 9:, 18:21] = -A[:, :3, :3]
    M[:, 9:, 21:] = _I3
    b = np.zeros((n, 12))
    b[:, 9:] = A[:, :3, 3]
    x = _lstsq(M.reshape(12 * n, 24), b.reshape(-1), "eq. 16 + 13 (Li)", A)
    R_X, R_Y = tf.project_to_so3(_unvec(x[:9])), tf.project_to_so3(_unvec(x[9:18]))
    t_X, t_Y = _translation_xy(R_X, R_Y, A, B)
    return tf.make_transform(R_X, t_X), tf.make_transform(R_Y, t_Y)


def y_quat_t_prime(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """YQuatT' (proposed, eq. 19): the equation of translation in quaternions, AX=YB.

    Per sample ``[Q-(t_B) - Q+(t_A), I, -Q-(b)^T Q+(a)] [y; t_Y y; t_X x] = 0``
    (4 rows, 12 unknowns; ``t`` are pure quaternions). The null space has
    dimension 2 because the scalar parts of ``t_Y y y*`` and ``t_X x x*`` may
    grow by the same constant; as in Daniilidis (1999) the solution
    ``l1 v1 + l2 v2`` of the two smallest right singular vectors is fixed by
    ``u . y = 0`` (``t_Y`` pure, with ``u = t_Y y``) and ``|y| = 1``; of the
    two roots the one with the larger ``|y|`` is taken (the other has y = 0).
    ``t_Y = vec(u y*)``. The paper does not solve for ``x``; X is completed as
    the average of ``A_i^-1 Y B_i``. Eye-to-hand form; N >= 3 poses.
    """
    A, B = check_pose_pairs(A, B, 3)
    _check_robot_excitation(A)
    n = len(A)
    qa, qb = _align_signs(_quat(A[:, :3, :3]), _quat(B[:, :3, :3]), same_angle=False)
    tA = np.concatenate([A[:, :3, 3], np.zeros((n, 1))], axis=1)
    tB = np.concatenate([B[:, :3, 3], np.zeros((n, 1))], axis=1)
    left = quat_right(tB) - quat_left(tA)

    def solve_y(qb):
        M = np.empty((n, 4, 12))
        M[:, :, :4] = left
        M[:, :, 4:8] = np.eye(4)
        M[:, :, 8:] = -np.swapaxes(quat_right(qb), 1, 2) @ quat_left(qa)
        # Right singular vectors from the 12 x 12 Gram matrix (eigenvalues = squared singular values).
        M = M.reshape(4 * n, 12)
        w, V = np.linalg.eigh(M.T @ M)
        _check_singular_values(np.sqrt(np.clip(w[::-1], 0.0, None)), 9, "eq. 19 (nullity must be 2)", A)
        v1, v2 = V[:, 0], V[:, 1]
        y1, y2, u1, u2 = v1[:4], v2[:4], v1[4:8], v2[4:8]
        # Quadratic form in (l1, l2) of u . y; its zero set is two lines.
        Q = np.array([[u1 @ y1, (u1 @ y2 + u2 @ y1) / 2.0], [(u1 @ y2 + u2 @ y1) / 2.0, u2 @ y2]])
        ev, E = np.linalg.eigh(Q)
        if ev[0] < 0 < ev[1]:
            c = np.sqrt(ev[1]), np.sqrt(-ev[0])
            cands = [E[:, 0] * c[0] + E[:, 1] * c[1], E[:, 0] * c[0] - E[:, 1] * c[1]]
        else:
            # Noise made the form definite: take the direction where it is closest to zero.
            cands = [E[:, int(np.argmin(np.abs(ev)))]]
        best = max(cands, key=lambda l: np.linalg.norm((l[0] * y1 + l[1] * y2)) / np.linalg.norm(l))
        w = best[0] * v1 + best[1] * v2
        w /= np.linalg.norm(w[:4])
        qy, u = w[:4], w[4:8]
        t_Y = (quat_right(np.array([-qy[0], -qy[1], -qy[2], qy[3]])) @ u)[:3]
        return qy, t_Y

    qy, t_Y = solve_y(qb)
    Y = tf.make_transform(_mat(qy), t_Y)
    X = _complete_x(Y, A, B)
    qb, changed = _resign(qa, qb, _quat(X[None, :3, :3])[0], qy)
    if changed:
        qy, t_Y = solve_y(qb)
        Y = tf.make_transform(_mat(qy), t_Y)
        X = _complete_x(Y, A, B)
    return X, Y


def y_kron_t_prime(A: np.ndarray, p: np.ndarray, setup: Setup = Setup.EYE_TO_HAND) -> tuple[np.ndarray, np.ndarray]:
    """YKronT' (proposed, eq. 20): the equation of translation alone, marker points only.

    Eye-to-hand (``X = T_flange_marker``, ``Y = T_base_cam``, ``p`` = marker
    center in the camera frame = ``t_B``), eq. 20:
    ``[(p^T kron I)  I  -R_A] [vec(R_Y); t_Y; t_X] = t_A``, 3N x 15.
    Returns the full ``Y`` and ``t_X``; ``R_X`` is unknown (identity).

    Eye-in-hand (``X = T_flange_cam``, ``Y = T_base_marker``, ``p`` = marker
    center in the camera frame), derived here: the marker center in the base
    frame is fixed, ``t_Y = A_i X p_i``, i.e.
    ``R_A (R_X p + t_X) + t_A = t_Y``. With
    ``R_A R_X p = vec(R_A R_X p) = (p^T kron R_A) vec(R_X)`` this is linear:
    ``[(p^T kron R_A)  R_A  -I] [vec(R_X); t_X; t_Y] = -t_A``, 3N x 15.
    Returns the full ``X`` (the camera on the flange) and ``t_Y``; the marker
    rotation ``R_Y`` is unknown (identity).

    In both cases the system is built vectorised and solved by least squares
    (normal equations, 15 unknowns), the 3x3 block is reorthonormalised (SVD projection) and the two
    translations are re-solved with it fixed (the paper's second step).

    Parameters
    ----------
    A : ndarray, shape (N, 4, 4)
        ``T_base_flange``.
    p : ndarray, shape (N, 3)
        Marker center in the camera frame, m. N >= 5.
    setup : {"eye_to_hand", "eye_in_hand"}

    Returns
    -------
    X, Y : ndarray, shape (4, 4)
    """
    setup = check_setup(setup)
    A, p = check_point_pairs(A, p, 5)
    return y_kron_t_prime_unchecked(A, p, setup)


def y_kron_t_prime_unchecked(A: np.ndarray, p: np.ndarray, setup: str) -> tuple[np.ndarray, np.ndarray]:
    """`y_kron_t_prime` for inputs validated already (a `handeye.calib.problem.CalibrationProblem`'s)."""
    n = len(A)
    R_A, t_A = A[:, :3, :3], A[:, :3, 3]
    M = np.empty((n, 3, 15))
    if setup == Setup.EYE_TO_HAND:
        M[:, :, :9] = _kron_t(p)
        M[:, :, 9:12] = _I3
        M[:, :, 12:] = -R_A
        rhs = t_A
    else:
        # (p^T kron R_A)[:, 3j:3j+3] = p_j R_A
        M[:, :, :9] = (R_A[:, :, None, :] * p[:, None, :, None]).reshape(n, 3, 9)
        M[:, :, 9:12] = R_A
        M[:, :, 12:] = -_I3
        rhs = -t_A
    x = _lstsq(M.reshape(3 * n, 15), rhs.reshape(-1), "eq. 20 (YKronT')", A)
    R = tf.project_to_so3(_unvec(x[:9]))
    # Re-solve [I, -R_A][t_1; t_2] = c with the rotation fixed (a 3N x 6 system).
    T2 = np.empty((n, 3, 6))
    if setup == Setup.EYE_TO_HAND:
        T2[:, :, :3] = _I3
        T2[:, :, 3:] = -R_A
        c = t_A - p @ R.T
    else:
        T2[:, :, :3] = R_A
        T2[:, :, 3:] = -_I3
        c = -t_A - np.einsum("nij,nj->ni", R_A, p @ R.T)
    t = _lstsq(T2.reshape(3 * n, 6), c.reshape(-1), "eq. 20 translations", A)
    if setup == Setup.EYE_TO_HAND:
        return tf.make_transform(_I3, t[3:]), tf.make_transform(R, t[:3])
    return tf.make_transform(R, t[:3]), tf.make_transform(_I3, t[3:])


# --------------------------------------------------------------- residuals


def residuals(X, Y, A, B, setup: str, *, rotation: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Per-sample residuals of eq. 1 at (X, Y).

    Translation (eq. 5), m: eye-to-hand ``|R_A t_X + t_A - R_Y t_B - t_Y|``,
    eye-in-hand ``|R_A (R_X t_B + t_X) + t_A - t_Y|``; both equal the distance
    between the measured marker point and the one predicted from (X, Y) (a
    rotation does not change the norm). Rotation (eq. 4), rad: the angle of
    ``R_A R_X (R_Y R_B)^T`` (eye-to-hand) or ``R_A R_X R_B R_Y^T``
    (eye-in-hand); None if ``B`` holds points or ``rotation`` is False.

    Parameters
    ----------
    X, Y : ndarray, shape (4, 4)
    A : ndarray, shape (N, 4, 4)
    B : ndarray, shape (N, 4, 4) or (N, 3)
    setup : {"eye_to_hand", "eye_in_hand"}
    rotation : bool
        False for results whose marker-side rotation is unknown.

    Returns
    -------
    translation : ndarray, shape (N,)
    rotation : ndarray, shape (N,), or None
    """
    setup = check_setup(setup)
    X = tf.check_transform(X, "X")
    Y = tf.check_transform(Y, "Y")
    A, B = check_measurements(A, B)
    return residuals_unchecked(X, Y, A, B, setup, rotation)


def residuals_unchecked(X, Y, A, B, setup: str, rotation: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """`residuals` for inputs validated already, vectorised without stacked 3x3 products (they dominate at large N)."""
    n = len(A)
    poses = B.ndim == 3
    p = B[:, :3, 3] if poses else B
    if setup == Setup.EYE_TO_HAND:
        # [R_A | t_A] [t_X; 1] as one matrix-vector product over the (4N, 4) stack.
        r = (A.reshape(4 * n, 4) @ np.append(X[:3, 3], 1.0)).reshape(n, 4)[:, :3] - p @ Y[:3, :3].T - Y[:3, 3]
    else:
        q = p @ X[:3, :3].T + X[:3, 3]
        r = np.einsum("nij,nj->ni", A[:, :3, :3], q) + A[:, :3, 3] - Y[:3, 3]
    trans = np.sqrt(np.einsum("ni,ni->n", r, r))
    if not (poses and rotation):
        return trans, None
    # The angle is invariant under conjugation, so use R_Y^T dR R_Y = P R_B^T (eye-to-hand) or
    # P R_B (eye-in-hand) with P = R_Y^T R_A R_X, in the (3, 3, N) layout of cheap einsums.
    R_A = np.ascontiguousarray(A[:, :3, :3].transpose(1, 2, 0))
    R_B = np.ascontiguousarray(B[:, :3, :3].transpose(1, 2, 0))
    P = np.einsum("iln,lj->ijn", np.einsum("ki,kln->iln", Y[:3, :3], R_A), X[:3, :3])
    dR = np.einsum("ikn,jkn->ijn" if setup == Setup.EYE_TO_HAND else "ikn,kjn->ijn", P, R_B)
    return trans, tf.rotation_angle(dR.transpose(2, 0, 1))
