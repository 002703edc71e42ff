"""Rigid-transform helpers: pure functions over numpy arrays.

Convention: ``T_a_b`` (4x4, metres) is the pose of frame b in frame a, so
``p_a = T_a_b @ p_b``. Stacks are ``(N, 4, 4)``. Quaternions are scalar-last
``(x, y, z, w)`` as in ROS and scipy; rotation vectors are axis * angle in rad.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from handeye.calib.errors import CalibrationError

ROTATION_ATOL = 1e-6

_I3 = np.eye(3)
#: Positions of the rotation block in a row-major flattened 4x4 transform.
_ROTATION_ENTRIES = [0, 1, 2, 4, 5, 6, 8, 9, 10]


#: Largest magnitude (m, or m^2 for covariances) accepted in a solver input. Far beyond
#: any robot cell, and far enough below the float range that squares and products in
#: the solvers (e.g. a Gram matrix of 1e155 m coordinates) cannot overflow to inf/NaN.
MAX_MAGNITUDE = 1e6


def as_real_array(value, name: str, *, max_magnitude: float | None = MAX_MAGNITUDE) -> np.ndarray:
    """``value`` as a finite float64 array, or CalibrationError naming ``name``.

    Refuses what ``np.asarray(value, dtype=float)`` would crash on or silently
    change: None, mappings, strings, ragged nesting, complex numbers (not cast
    to their real part), booleans and object arrays holding anything but real
    numbers. NaN/inf and, with ``max_magnitude``, entries larger in magnitude
    are refused naming the first bad sample (index along the first axis).
    """
    if value is None or isinstance(value, (str, bytes, dict)):
        raise CalibrationError(f"{name} must be a numeric array, got {type(value).__name__}")
    try:
        a = np.asarray(value)
    except (ValueError, TypeError) as e:
        raise CalibrationError(f"{name} is not a rectangular numeric array ({str(e).split('.')[0]})") from None
    if a.dtype == object:
        bad = [x for x in a.ravel() if isinstance(x, (bool, np.bool_))
               or not isinstance(x, (int, float, np.integer, np.floating))][:1]
        if bad:
            bad = bad[0]
            raise CalibrationError(f"{name} must hold real numbers, got {type(bad).__name__} {bad!r:.40}")
    elif a.dtype.kind == "c":
        raise CalibrationError(f"{name} is complex; handeye takes real arrays (no imaginary part is dropped)")
    elif a.dtype.kind not in "iuf":
        raise CalibrationError(f"{name} must hold real numbers, got dtype {a.dtype}")
    a = a.astype(float)
    if a.size:
        flat = np.abs(a.reshape(len(a), -1)) if a.ndim else np.abs(a).reshape(1, 1)
        finite = np.isfinite(flat).all(axis=1)
        if not finite.all():
            raise CalibrationError(f"{name}[{int(np.argmin(finite))}] contains NaN or inf" if a.ndim
                                   else f"{name} is NaN or inf")
        if max_magnitude is not None:
            small = (flat <= max_magnitude).all(axis=1)
            if not small.all():
                i = int(np.argmin(small))
                raise CalibrationError(f"{name}[{i}] has an entry of magnitude {flat[i].max():.3g}, "
                                       f"beyond {max_magnitude:g} (metres?)" if a.ndim
                                       else f"{name} is beyond {max_magnitude:g}")
    return a


def check_transforms(T, name: str = "T", *, atol: float = ROTATION_ATOL) -> np.ndarray:
    """Validate a stack of rigid transforms.

    Parameters
    ----------
    T : array_like, shape (N, 4, 4)
    name : str
        Used in the error message.

    Returns
    -------
    T : ndarray, shape (N, 4, 4), float64

    Raises
    ------
    CalibrationError
        On a non-numeric, complex or ragged input, a wrong shape, NaN/inf, a
        translation beyond `MAX_MAGNITUDE`, a non-orthonormal or reflecting
        rotation, or a last row other than ``[0, 0, 0, 1]``; the message
        names the first bad index.
    """
    T = as_real_array(T, name)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise CalibrationError(f"{name} must have shape (N, 4, 4), got {T.shape}")
    # Entry-major layout (16, N): every check below is elementwise work on
    # contiguous rows, several times cheaper than stacked 3x3 products and
    # determinants (this runs on every solver input).
    c = np.ascontiguousarray(T.reshape(len(T), 16).T)
    finite = np.isfinite(c).all(axis=0)
    if not finite.all():
        raise CalibrationError(f"{name}[{int(np.argmin(finite))}] contains NaN or inf")
    bottom_ok = (np.abs(c[12:15]) <= atol).all(axis=0) & (np.abs(c[15] - 1.0) <= atol)
    if not bottom_ok.all():
        raise CalibrationError(f"{name}[{int(np.argmin(bottom_ok))}] last row is not [0, 0, 0, 1]")
    R = c[_ROTATION_ENTRIES].reshape(3, 3, -1)  # R[i, j, n]
    orth_err = np.abs((np.einsum("ikn,jkn->ijn", R, R) - _I3[:, :, None]).reshape(9, -1)).max(axis=0)
    det = (R[0, 0] * (R[1, 1] * R[2, 2] - R[1, 2] * R[2, 1]) - R[0, 1] * (R[1, 0] * R[2, 2] - R[1, 2] * R[2, 0])
           + R[0, 2] * (R[1, 0] * R[2, 1] - R[1, 1] * R[2, 0]))
    rot_ok = (orth_err <= max(atol, 1e-9) * 10) & (np.abs(det - 1) <= atol * 10)
    if not rot_ok.all():
        i = int(np.argmin(rot_ok))
        raise CalibrationError(
            f"{name}[{i}] rotation is not a proper rotation "
            f"(|R R^T - I| = {orth_err[i]:.2e}, det = {det[i]:.6f})"
        )
    return T


def check_transform(T, name: str = "T", *, atol: float = ROTATION_ATOL) -> np.ndarray:
    """Validate one rigid transform, shape (4, 4). See `check_transforms`."""
    T = as_real_array(T, name)
    if T.shape != (4, 4):
        raise CalibrationError(f"{name} must have shape (4, 4), got {T.shape}")
    return check_transforms(T[None], name, atol=atol)[0]


def check_points(p, name: str = "points") -> np.ndarray:
    """Validate a stack of 3D points, shape (N, 3), finite and within `MAX_MAGNITUDE` (see `as_real_array`)."""
    p = as_real_array(p, name)
    if p.ndim != 2 or p.shape[1] != 3:
        raise CalibrationError(f"{name} must have shape (N, 3), got {p.shape}")
    return p


def make_transform(R, t) -> np.ndarray:
    """Build 4x4 transform(s) from rotation(s) (..., 3, 3) and translation(s) (..., 3)."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert(T) -> np.ndarray:
    """Inverse of rigid transform(s) (..., 4, 4), exact (no general matrix inverse)."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_transform(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def transform_points(T, p) -> np.ndarray:
    """Apply transform(s) (..., 4, 4) to point(s) (..., 3)."""
    T = np.asarray(T, dtype=float)
    return np.einsum("...ij,...j->...i", T[..., :3, :3], p) + T[..., :3, 3]


def project_to_so3(M) -> np.ndarray:
    """Nearest rotation matrix (Frobenius norm) to M (..., 3, 3), via SVD."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    D = np.ones(U.shape[:-1])
    D[..., -1] = np.sign(np.linalg.det(U @ Vt))
    return (U * D[..., None, :]) @ Vt


def skew(v) -> np.ndarray:
    """Cross-product matrices (..., 3, 3) of vectors (..., 3): ``skew(a) @ b == cross(a, b)``."""
    v = np.asarray(v, dtype=float)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def so3_exp(v) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3), rad (SO(3) exponential map).

    Rodrigues' formula, with the Taylor series of its coefficients below 1e-4 rad (written out
    rather than through scipy's Rotation, whose per-call overhead would dominate the solvers' inner loops).
    """
    v = np.asarray(v, dtype=float)
    th2 = np.sum(v * v, axis=-1)
    th = np.sqrt(th2)
    small = th < 1e-4
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0 + th2 * th2 / 120.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th2 / 24.0 + th2 * th2 / 720.0, (1.0 - np.cos(ths)) / ths**2)
    S = skew(v)
    return _I3 + a[..., None, None] * S + b[..., None, None] * (S @ S)


def so3_log(R) -> np.ndarray:
    """Rotation vectors (..., 3), rad, of rotation matrices (..., 3, 3) (SO(3) logarithm, angle in [0, pi]).

    Through the unit quaternion (Markley's choice of the largest of w, x, y, z
    for precision at every angle, as scipy's Rotation.from_matrix, without its
    per-call overhead), then ``2 atan2(|v|, w) v / |v|``.
    """
    R = np.asarray(R, dtype=float)
    r = R.reshape(-1, 3, 3)
    d0, d1, d2 = r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]
    tr = d0 + d1 + d2
    s01, s02, s12 = r[:, 0, 1] + r[:, 1, 0], r[:, 0, 2] + r[:, 2, 0], r[:, 1, 2] + r[:, 2, 1]
    a10, a02, a21 = r[:, 1, 0] - r[:, 0, 1], r[:, 0, 2] - r[:, 2, 0], r[:, 2, 1] - r[:, 1, 2]
    # Candidate quaternions (x, y, z, w) up to scale, one per choice; the largest diagonal term picks.
    q = np.stack([
        np.stack([1.0 + 2.0 * d0 - tr, s01, s02, a21], axis=-1),
        np.stack([s01, 1.0 + 2.0 * d1 - tr, s12, a02], axis=-1),
        np.stack([s02, s12, 1.0 + 2.0 * d2 - tr, a10], axis=-1),
        np.stack([a21, a02, a10, 1.0 + tr], axis=-1),
    ])
    choice = np.argmax(np.stack([d0, d1, d2, tr]), axis=0)
    q = q[choice, np.arange(len(r))]
    q *= np.where(q[:, 3:4] < 0.0, -1.0, 1.0)
    v, w = q[:, :3], q[:, 3]
    n = np.linalg.norm(v, axis=1)
    # angle / sin(angle / 2) on the unnormalised quaternion: 2 atan2(|v|, w) / |v|, -> 2 / w at 0.
    ns = np.where(n > 0.0, n, 1.0)
    scale = np.where(n > 1e-7 * w, 2.0 * np.arctan2(n, w) / ns, 2.0 / np.where(w > 0, w, 1.0))
    return (v * scale[:, None]).reshape(R.shape[:-2] + (3,))


def from_rotvec_translation(rotvec, t) -> np.ndarray:
    """Transform(s) from rotation vector(s) (..., 3) in rad and translation(s) (..., 3) in m."""
    return make_transform(so3_exp(rotvec), t)


def to_rotvec_translation(T) -> tuple[np.ndarray, np.ndarray]:
    """Rotation vector(s) (..., 3) in rad and translation(s) (..., 3) in m of transform(s)."""
    T = np.asarray(T, dtype=float)
    rv = Rotation.from_matrix(T[..., :3, :3].reshape(-1, 3, 3)).as_rotvec()
    return rv.reshape(T.shape[:-2] + (3,)), T[..., :3, 3].copy()


def from_ur_pose(pose) -> np.ndarray:
    """Transform(s) from UR pose vector(s) ``[x, y, z, rx, ry, rz]`` (m, rotation vector in rad)."""
    pose = np.asarray(pose, dtype=float)
    return from_rotvec_translation(pose[..., 3:6], pose[..., 0:3])


def to_ur_pose(T) -> np.ndarray:
    """UR pose vector(s) ``[x, y, z, rx, ry, rz]`` of transform(s) (..., 4, 4)."""
    rv, t = to_rotvec_translation(T)
    return np.concatenate([t, rv], axis=-1)


def from_xyz_quat(xyz, quat_xyzw) -> np.ndarray:
    """Transform(s) from translation(s) (..., 3) and scalar-last quaternion(s) (..., 4)."""
    q = np.asarray(quat_xyzw, dtype=float)
    R = Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(q.shape[:-1] + (3, 3))
    return make_transform(R, xyz)


def to_xyz_quat(T) -> tuple[np.ndarray, np.ndarray]:
    """Translation(s) (..., 3) and scalar-last unit quaternion(s) (..., 4), w >= 0."""
    T = np.asarray(T, dtype=float)
    q = Rotation.from_matrix(T[..., :3, :3].reshape(-1, 3, 3)).as_quat()
    q *= np.where(q[:, 3:4] < 0, -1.0, 1.0)
    return T[..., :3, 3].copy(), q.reshape(T.shape[:-2] + (4,))


def rotation_angle(R) -> np.ndarray:
    """Rotation angle(s) in rad of rotation matrix (matrices) (..., 3, 3)."""
    R = np.asarray(R, dtype=float)
    c = (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1.0) / 2.0
    # atan2 of sine and cosine keeps precision at small angles, where arccos loses half the digits.
    s = np.sqrt((R[..., 2, 1] - R[..., 1, 2]) ** 2 + (R[..., 0, 2] - R[..., 2, 0]) ** 2
                + (R[..., 1, 0] - R[..., 0, 1]) ** 2) / 2.0
    return np.arctan2(s, c)


def pose_error(T_est, T_true) -> tuple[np.ndarray, np.ndarray]:
    """Rotation error (rad) and translation error (m) between transform(s) (..., 4, 4)."""
    T_est = np.asarray(T_est, dtype=float)
    T_true = np.asarray(T_true, dtype=float)
    dR = np.swapaxes(T_true[..., :3, :3], -1, -2) @ T_est[..., :3, :3]
    return rotation_angle(dR), np.linalg.norm(T_est[..., :3, 3] - T_true[..., :3, 3], axis=-1)


def random_rotations(n: int, max_angle: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` rotations (n, 3, 3) about uniform random axes, angles uniform in [0, max_angle] rad."""
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = rng.uniform(0.0, max_angle, size=n)
    return Rotation.from_rotvec(axes * angles[:, None]).as_matrix()


def register_points(p, q) -> np.ndarray:
    """The rigid transform (4, 4) ``T`` that best maps points ``p`` onto ``q`` (N, 3) in least squares,
    ``q_i ~ R p_i + t`` (Kabsch, by scipy's ``Rotation.align_vectors``); N >= 3, not all on one line."""
    p = check_points(p, "p")
    q = check_points(q, "q")
    if p.shape != q.shape or len(p) < 3:
        raise CalibrationError(f"register_points needs two point sets of one shape (N >= 3, 3), got {p.shape} and "
                               f"{q.shape}")
    pc, qc = p.mean(axis=0), q.mean(axis=0)
    R = Rotation.align_vectors(q - qc, p - pc)[0].as_matrix()
    return make_transform(R, qc - R @ pc)
