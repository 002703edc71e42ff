"""The engine's filter: its state as an immutable value (`FilterState`), and `predict`, `innovate` and `fuse` as
functions of it, over the one measurement model (`calib.model`; on floats, `calib.monitor.kernels.sample_floats`).

The state (`Layout`) is the camera transform ``C`` (4, 4): ``T_base_cam``
eye-to-hand (``Y`` of ``A_i X = Y B_i``), ``T_flange_cam`` eye-in-hand
(``X``), perturbed on the left by ``[rotation vector, translation]`` as in
`calib.result`, and ``u = [t_K, theta, z, w]``: the marker-side translation
(``T_flange_marker`` / ``T_base_marker``), the camera parameters
(`calib.model.CAMERA_PARAMS`), the robot's kinematic error shared by all
samples (P parameters, unit variance) and the camera's walk since the
calibration in use (6, measured by no sample: the drift). ``P`` is the joint
covariance of ``[dC, u]``.

The fast path runs on tuples of floats (numpy's per-call cost would be most
of a sample's cost on 3-vectors); `calib.monitor.kernels.sample_floats` is
tested against `calib.model.point_jacobians`, the model ``auto`` and the
arming use.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from calib.model import NoiseLevels
from calib.monitor.kernels import inv_sym3, inv_sym3_floats, matmul3, parts, sample_floats, so3_exp_scalar

#: The noise levels' scale follows the innovations with this memory (samples), the arming's level counting
#: as this many samples, within this range.
NOISE_SCALE_SAMPLES = 200
NOISE_SCALE_PRIOR = 10.0
NOISE_SCALE_RANGE = (0.25, 16.0)


class Layout(NamedTuple):
    """Where each part of the state lies in ``P``'s rows: camera ``0:6``, marker-side translation ``6:9``, camera
    parameters ``9:12``, kinematic error ``12:model``, walk ``model:size``."""

    n_factor: int

    @property
    def model(self) -> int:
        """Columns of the measurement model (the walk states do not enter it)."""
        return 12 + self.n_factor

    @property
    def size(self) -> int:
        return self.model + 6


class SampleModel(NamedTuple):
    """What the measurement model needs besides the state: the setup and the arming's noise levels (the robot's
    as a variance)."""

    eye_to_hand: bool
    layout: Layout
    point_scale: float
    robot_var: float

    @classmethod
    def of(cls, eye_to_hand: bool, n_factor: int, noise: NoiseLevels) -> SampleModel:
        return cls(eye_to_hand, Layout(n_factor), noise.point_scale, noise.robot ** 2)


class Walk(NamedTuple):
    """The random walk of the camera transform: the variances it adds per second of the samples' clock, over
    at most ``max_gap_s`` between two samples.

    It moves the camera transform and the walk states alike, so their
    covariance grows by ``q dt [[I, I], [I, I]]`` over (camera, walk):
    ``rows`` and ``cols`` are those 24 entries of ``P`` (``flat``: the same
    as indices into a contiguous ``P``'s flat view), ``per_s`` their
    increments (4 copies of the diagonal ``q``: rotation rad^2, translation
    m^2 per second).
    """

    rows: np.ndarray
    cols: np.ndarray
    flat: np.ndarray
    per_s: np.ndarray
    max_gap_s: float

    @classmethod
    def of(cls, layout: Layout, rotation_rad_per_sqrt_h: float, translation_m_per_sqrt_h: float,
           hour_s: float, max_gap_h: float) -> Walk:
        sr, st = rotation_rad_per_sqrt_h, translation_m_per_sqrt_h
        q = np.array([sr * sr] * 3 + [st * st] * 3) / hour_s
        camera, walk = np.arange(6), layout.model + np.arange(6)
        rows, cols = np.r_[camera, walk, camera, walk], np.r_[camera, walk, walk, camera]
        return cls(rows, cols, rows * layout.size + cols, np.tile(q, 4), max_gap_h * hour_s)

    def variance(self, dt: float) -> np.ndarray:
        """The walk's variance (6,) of the camera transform over ``dt`` seconds (rotation, translation)."""
        return self.per_s[:6] * dt


class FilterState(NamedTuple):
    """The filter's estimate at time ``t`` (immutable: every function returns a new one).

    Attributes
    ----------
    C : ndarray (4, 4)
        The camera transform.
    u : ndarray (layout.size - 6,)
        ``[t_K, theta, z, w]``.
    P : ndarray (layout.size, layout.size)
        Covariance of ``[dC, u]``.
    t : float
        Time of the estimate, s (the samples' clock).
    walk_t : float
        How long the random walk has run, s: the clock with each gap counted at most `Walk.max_gap_s`.
    scale : float
        The noise levels' scale: the arming's levels times this are the samples' noise.
    pending : float
        The change of ``scale`` not yet applied to ``P`` (`predict` applies it): the covariance is the
        inverse information at the noise level of its data, and follows that level from the next sample on.
    parts : tuple
        ``C`` as floats (`calib.monitor.kernels.parts`), for the fast path.
    """

    C: np.ndarray
    u: np.ndarray
    P: np.ndarray
    t: float
    walk_t: float
    scale: float
    pending: float
    parts: tuple


def filter_state(C, u, P, t: float, walk_t: float = 0.0, scale: float = 1.0, pending: float = 1.0) -> FilterState:
    """A `FilterState` (``parts`` from ``C``)."""
    return FilterState(C, u, P, float(t), float(walk_t), scale, pending, parts(C))


def predict(state: FilterState, t: float, walk: Walk) -> FilterState:
    """The state at ``t``: the noise scale's pending change applied to ``P``, then the random walk since ``state.t``
    (none for a ``t`` not after it; over at most `Walk.max_gap_s`)."""
    P, walk_t = state.P, state.walk_t
    if state.pending != 1.0:
        P = P * state.pending
    if t > state.t:
        if P is state.P:
            P = P.copy()
        dt = min(t - state.t, walk.max_gap_s)
        # P[rows, cols] += ..., on the fresh contiguous array's flat view (a third of the indexing's cost)
        P.reshape(-1)[walk.flat] += walk.per_s * dt
        walk_t += dt
    return FilterState(state.C, state.u, P, max(float(t), state.t), walk_t, state.scale, 1.0, state.parts)


class Innovation(NamedTuple):
    """One sample against the state's prediction.

    Attributes
    ----------
    r : tuple of 3 floats
        Measured minus predicted marker point, camera frame, m.
    H : ndarray (3, layout.model)
        Jacobian of the prediction w.r.t. the model's states.
    R : tuple of 6 floats
        Upper triangle ``(xx, xy, xz, yy, yz, zz)`` of the sample's noise covariance, m^2.
    PHt : ndarray (layout.size, 3)
        ``P H^T`` (the walk states' rows included).
    S_inv : tuple of 6 floats
        Upper triangle of the inverse innovation covariance ``(H P H^T + R)^-1``.
    nis : float
        ``r^T S^-1 r`` (chi-square, 3 dof, when the filter is consistent).
    """

    r: tuple
    H: np.ndarray
    R: tuple
    PHt: np.ndarray
    S_inv: tuple
    nis: float


def prediction(state: FilterState, pose, factor, model: SampleModel):
    """`sample_floats` at the state for a flange pose (``T_base_flange[:3]`` flat, 12 floats) and kinematic-error
    factor (6, P) or None: ``(h, H, cofactor)``."""
    u = state.u
    k0, k1, k2, s0, s1, s2 = u[:6].tolist()
    return sample_floats(state.parts, (k0, k1, k2), pose, (s0, s1, s2), model.eye_to_hand, factor,
                         u[6:model.layout.model - 6])


def noise(state: FilterState, shape_upper, cofactor, model: SampleModel) -> tuple:
    """Upper triangle of a sample's noise covariance: its point covariance shape and robot cofactor (upper
    triangles) at the arming's levels times the state's scale."""
    k, m = state.scale * model.point_scale, state.scale * model.robot_var
    a0, a1, a2, a3, a4, a5 = shape_upper
    b0, b1, b2, b3, b4, b5 = cofactor
    return k * a0 + m * b0, k * a1 + m * b1, k * a2 + m * b2, k * a3 + m * b3, k * a4 + m * b4, k * a5 + m * b5


def innovate(state: FilterState, pose, point, shape_upper, factor, model: SampleModel) -> Innovation:
    """The `Innovation` of a sample: flange pose (``T_base_flange[:3]`` flat), measured marker point (3 floats,
    camera frame, m, uncorrected), its covariance shape's upper triangle and kinematic-error factor (6, P) or
    None."""
    h, H, cof = prediction(state, pose, factor, model)
    R = noise(state, shape_upper, cof, model)
    m = model.layout.model
    PHt = state.P[:, :m].dot(H.T)
    (a, b, c), (_, d, e), (_, _, f) = H.dot(PHt[:m]).tolist()
    S_inv = inv_sym3_floats(a + R[0], b + R[1], c + R[2], d + R[3], e + R[4], f + R[5])
    (p0, p1, p2), (h0, h1, h2) = point, h
    r0, r1, r2 = p0 - h0, p1 - h1, p2 - h2
    i0, i1, i2, i3, i4, i5 = S_inv
    nis = ((r0 * i0 + r1 * i1 + r2 * i2) * r0 + (r0 * i1 + r1 * i3 + r2 * i4) * r1
           + (r0 * i2 + r1 * i4 + r2 * i5) * r2)
    return Innovation((r0, r1, r2), H, R, PHt, S_inv, nis)


def fuse(state: FilterState, PHt: np.ndarray, S_inv: np.ndarray, r) -> FilterState:
    """The Kalman update from ``PHt = P H^T`` (n, 3), the inverse innovation covariance (3, 3) and the innovation
    ``r`` (3,); the camera transform moves on the left (`calib.result`)."""
    # ndarray.dot: the same BLAS products as @, with less call overhead on these small arrays.
    K = PHt.dot(S_inv)
    P = state.P - K.dot(PHt.T)
    P += P.T
    P *= 0.5
    d = K.dot(r)
    d0, d1, d2, d3, d4, d5 = d[:6].tolist()
    R, (x, y, z) = state.parts
    r0, r1, r2 = matmul3(so3_exp_scalar(d0, d1, d2), R)
    t = (x + d3, y + d4, z + d5)
    C = np.array(r0 + t[:1] + r1 + t[1:2] + r2 + t[2:] + (0.0, 0.0, 0.0, 1.0)).reshape(4, 4)
    return FilterState(C, state.u + d[6:], P, state.t, state.walk_t, state.scale, state.pending, ((r0, r1, r2), t))


def fuse_linear(state: FilterState, r, H: np.ndarray, R: np.ndarray) -> FilterState:
    """`fuse` from an innovation ``r`` (3,), its Jacobian over the whole state ``H`` (3, n) and noise ``R`` (3, 3)."""
    PHt = state.P.dot(H.T)
    return fuse(state, PHt, inv_sym3(H.dot(PHt) + R), r)


def linearize(state: FilterState, sample, model: SampleModel):
    """Innovation ``r`` (3,), Jacobian ``H`` (3, n) over the whole state (zero on the walk states) and noise ``R``
    (3, 3) of a sample (`calib.monitor.stops.Stop`) at ``state``, as arrays."""
    h, H_model, cof = prediction(state, sample.pose, sample.factor, model)
    H = np.zeros((3, model.layout.size))
    H[:, :model.layout.model] = H_model
    a, b, c, d, e, f = noise(state, sample.shape_upper, cof, model)
    return sample.p - np.array(h), H, np.array([[a, b, c], [b, d, e], [c, e, f]])


def restart_walk(state: FilterState, layout: Layout) -> FilterState:
    """The calibration in use is the estimate again: no walk since it (the walk states and their covariance
    zero)."""
    m = layout.model
    if not state.u[m - 6:].any() and not state.P[m:].any():
        return state
    u, P = state.u.copy(), state.P.copy()
    u[m - 6:] = 0.0
    P[m:] = 0.0
    P[:, m:] = 0.0
    return state._replace(u=u, P=P)


class NoiseTrack(NamedTuple):
    """A running mean of the innovations' NIS at unit scale, with the arming's level worth `NOISE_SCALE_PRIOR`
    samples and a memory of `NOISE_SCALE_SAMPLES`."""

    total: float = 0.0
    n: float = 0.0


def follow_noise(state: FilterState, track: NoiseTrack, nis: float) -> tuple[FilterState, NoiseTrack]:
    """The noise scale after a sample of normalised innovation square ``nis`` (at the state's scale): the arming
    levels come from a few dozen samples, so their scale follows the innovations. The covariance follows from
    the next sample on (``pending``)."""
    keep = 1.0 - 1.0 / NOISE_SCALE_SAMPLES
    track = NoiseTrack(keep * track.total + nis * state.scale / 3.0, keep * track.n + 1.0)
    scale = min(max((NOISE_SCALE_PRIOR + track.total) / (NOISE_SCALE_PRIOR + track.n), NOISE_SCALE_RANGE[0]),
                NOISE_SCALE_RANGE[1])
    return FilterState(state.C, state.u, state.P, state.t, state.walk_t, scale, state.pending * scale / state.scale,
                       state.parts), track


def is_sound(state: FilterState, tol: float = 1e-9) -> bool:
    """The state is finite and its covariance symmetric positive semi-definite (within ``tol`` of its scale)."""
    P = state.P
    if not (np.isfinite(state.C).all() and np.isfinite(state.u).all() and np.isfinite(P).all()):
        return False
    if not math.isfinite(state.scale) or state.scale <= 0:
        return False
    size = max(float(np.abs(P).max()), 1e-300)
    if np.abs(P - P.T).max() > tol * size:
        return False
    return float(np.linalg.eigvalsh(0.5 * (P + P.T)).min()) >= -tol * size
