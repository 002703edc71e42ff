"""The engine's filter: its state as an immutable value (`FilterState`), and `predict`, `innovate` and `fuse` as
functions of it, over the one measurement model (`handeye.calib.model`; on floats, `handeye.calib.monitor.kernels.sample_floats`).

The state (`Layout`) is the camera transform ``C`` (4, 4): ``T_base_cam``
eye-to-hand (``Y`` of ``A_i X = Y B_i``), ``T_flange_cam`` eye-in-hand
(``X``), perturbed on the left by ``[rotation vector, translation]`` as in
`handeye.calib.result`, and ``u = [t_K, theta, z, b, w]``: the marker-side translation
(``T_flange_marker`` / ``T_base_marker``), the camera parameters
(`handeye.calib.model.CAMERA_PARAMS`), the robot's kinematic error shared by all
samples (P parameters, unit variance), each held stop's own error (``b``: 3
per stop, up to `STOP_SLOTS`, the marker point's offset in the camera frame) and the
camera's walk since the calibration in use (6, measured by no sample: the
drift). ``P`` is the joint covariance of ``[dC, u]``.

A stop's own error is what every visit of it repeats and no parameter of the
model explains: the arm's error beyond its kinematic model (thermal growth,
deflection under load; all of the kinematic error for a source without
joints) and the camera's at that view. Its prior is the robot's noise level of
the arming at that pose plus `handeye.calib.monitor.MonitorSettings.stop_error_mm`.
As a state it saturates what repeated visits tell: a thousand visits of four
stops determine the camera no better than four measurements with that error
allow, and the parameters they cannot separate stay near the arming's values
(within 1.9 of its sigma over a month on the month benchmark's 20 cells).
Each visit adds the arming's noise at the pose, the point's and the robot's (`noise`).

The Jacobians are taken at a fixed point, `FilterState.lin` (the first-estimates Jacobian of EKF-SLAM: Huang,
Mourikis and Roumeliotis, 2008), the predictions at the estimate. The stops cannot tell the camera transform, the
marker-side translation and the camera parameters from their own errors: each such trade is a direction no
sample informs. Jacobians re-taken at every new estimate turn those directions a little from one visit of a stop
to the next, and the filter reads information into them that no sample gave: on a still eye-in-hand cell the
estimate then walked 0.1-0.2 mm a day along them while its stated 1-sigma held still. With each stop's visits
linearised at one point those directions stay uninformed (a still cell's error then holds, within its stated
1-sigma, for weeks). The point is taken anew when no stop's error is held (`clear_slots`), and when the estimate
becomes the calibration in use (`relinearize`: a re-learn and the samples that settle it, a few dozen a move).

The fast path runs on tuples of floats (numpy's per-call cost would be most
of a sample's cost on 3-vectors); `handeye.calib.monitor.kernels.sample_floats` is
tested against `handeye.calib.model.point_jacobians`, the model ``auto`` and the
arming use.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from handeye.calib.errors import FilterDivergedError
from handeye.calib.model import NoiseLevels
from handeye.calib.monitor.kernels import inv_sym3, inv_sym3_floats, matmul3, parts, sample_floats, so3_exp_scalar, sym3

#: Stops whose own error the state holds at most (the most recently visited): the state grows by a slot per new
#: stop up to these, and a new stop beyond them takes the slot of the least recently visited one, whose error is
#: marginalised. A stop that comes back after that starts again at its prior, and its repeated error counts as news
#: once more: 16 slots let a production of 20 stops in turn take the stated 1-sigma from 1.88 to 1.19 mm over a
#: month while the error held at 1.3 mm.
STOP_SLOTS = 32
#: The camera's walk is followed in a direction where an hour of it is at least this times the noise of one visit
#: of each stop (`observed_walk`).
WALK_SNR = 0.01
#: The noise levels' scale follows the innovations with this memory (samples), the arming's level counting
#: as this many samples, within this range.
NOISE_SCALE_SAMPLES = 200
NOISE_SCALE_PRIOR = 10.0
NOISE_SCALE_RANGE = (0.25, 16.0)
#: The smallest share of the innovation covariance the noise scale is estimated from (`follow_noise`).
NOISE_SHARE_MIN = 0.2
#: A sample whose NIS is beyond this (1000 sigma) is not fused (`fuse`): its increment would carry the state far
#: outside where the model is linear (a marker point 50x too far drove the kinematic error to 1e13 sigma, and the
#: next Jacobian to a singular noise).
GROSS_NIS = 1e6


class Layout(NamedTuple):
    """Where each part of the state lies in ``P``'s rows: camera ``0:6``, marker-side translation ``6:9``, camera
    parameters ``9:12``, kinematic error ``12:model``, the stops' own errors ``model:walk`` (3 per held stop), walk
    ``walk:size``."""

    n_factor: int
    n_slots: int = 0

    @property
    def model(self) -> int:
        """Columns of the model's parameters (the stops' errors and the walk states follow)."""
        return 12 + self.n_factor

    def slot(self, k: int) -> int:
        """The first row of slot ``k``'s stop error."""
        return self.model + 3 * k

    @property
    def walk(self) -> int:
        return self.model + 3 * self.n_slots

    @property
    def size(self) -> int:
        return self.walk + 6


class SampleModel(NamedTuple):
    """What the measurement model needs besides the state: the setup and the arming's noise levels (the robot's
    as a variance). Its ``layout`` holds no slot: `layout_of` gives a state's own."""

    eye_to_hand: bool
    layout: Layout
    point_scale: float
    robot_var: float

    @classmethod
    def of(cls, eye_to_hand: bool, n_factor: int, noise: NoiseLevels) -> SampleModel:
        return cls(eye_to_hand, Layout(n_factor), noise.point_scale, noise.robot ** 2)


class Walk(NamedTuple):
    """The random walk of the camera transform: the covariance it adds per second of the samples' clock, over at
    most ``max_gap_s`` between two samples.

    It moves the camera transform and the walk states alike, so their
    covariance grows by ``Q dt [[I, I], [I, I]]`` over (camera, walk):
    ``flat`` are those 144 entries as indices into a contiguous ``P``'s flat
    view, ``per_s`` their increments (4 copies of ``Q``, rotation rad^2,
    translation m^2 per second). ``Q`` is the walk's rate ``q`` (6,) in the
    directions the program's stops observe (`observed_walk`): where they are
    silent the camera holds its value and its uncertainty, as the stops could
    not follow it there.
    """

    flat: np.ndarray
    per_s: np.ndarray
    q: np.ndarray
    max_gap_s: float

    @classmethod
    def of(cls, layout: Layout, q: np.ndarray, Q: np.ndarray, max_gap_s: float) -> Walk:
        """The walk of rate ``q`` (6,) per second, followed as ``Q`` (6, 6) per second."""
        idx = np.r_[np.arange(6), layout.walk + np.arange(6)]
        rows, cols = np.meshgrid(idx, idx, indexing="ij")
        return cls((rows * layout.size + cols).ravel(), np.tile(Q, (2, 2)).ravel(), q, max_gap_s)

    def variance(self, dt: float) -> np.ndarray:
        """The walk's variance (6,) of the camera transform over ``dt`` seconds (rotation, translation), in every
        direction."""
        return self.q * dt


def observed_walk(q: np.ndarray, info: np.ndarray, hour_s: float) -> np.ndarray:
    """The walk of rate ``q`` (6,) per second in the directions where the stops would follow it (6, 6): those in
    which an hour of it is at least `WALK_SNR` times the noise of one visit of each stop (``info`` (6, 6), the
    information one visit of each stop gives about the camera transform)."""
    s = np.sqrt(q * hour_s)
    w, V = np.linalg.eigh(s[:, None] * info * s[None, :])
    keep = V[:, w >= WALK_SNR]
    return (s[:, None] * keep.dot(keep.T) * s[None, :]) / hour_s


class FilterState(NamedTuple):
    """The filter's estimate at time ``t`` (immutable: every function returns a new one).

    Attributes
    ----------
    C : ndarray (4, 4)
        The camera transform.
    u : ndarray (layout.size - 6,)
        ``[t_K, theta, z, b, w]``.
    P : ndarray (layout.size, layout.size)
        Covariance of ``[dC, u]``.
    t : float
        Time of the estimate, s (the samples' clock).
    walk_t : float
        How long the random walk has run, s: the clock with each gap counted at most `Walk.max_gap_s`.
    scale : float
        The noise levels' scale: the arming's levels times this are the samples' noise.
    parts : tuple
        ``C`` as floats (`handeye.calib.monitor.kernels.parts`), for the fast path.
    slots : tuple
        Per slot (at most `STOP_SLOTS`): the flange pose of the stop whose own error it holds
        (``T_base_flange[:3]`` flat, 12 floats).
    last : tuple
        Per slot: ``walk_t`` at its stop's last visit (the least recent is reused first).
    lin : tuple
        Where the Jacobians are taken (module docstring): ``(parts, model)``, the camera transform as `parts` and
        ``[t_K, theta, z]`` (ndarray).
    """

    C: np.ndarray
    u: np.ndarray
    P: np.ndarray
    t: float
    walk_t: float
    scale: float
    parts: tuple
    slots: tuple
    last: tuple
    lin: tuple


def filter_state(C, u, P, t: float, walk_t: float = 0.0, scale: float = 1.0) -> FilterState:
    """A `FilterState` (``parts`` from ``C``) holding no stop's error, linearised at it."""
    return relinearize(FilterState(C, u, P, float(t), float(walk_t), scale, parts(C), (), (), ()))


def layout_of(state: FilterState) -> Layout:
    """Where each part of ``state`` lies (its held stops included)."""
    return Layout(len(state.P) - Layout(0).size - 3 * len(state.slots), len(state.slots))


def relinearize(state: FilterState) -> FilterState:
    """The state with its Jacobians taken at its estimate from now on (`FilterState.lin`)."""
    return state._replace(lin=(state.parts, state.u[:len(state.u) - 3 * len(state.slots) - 6].copy()))


def predict(state: FilterState, t: float, walk: Walk) -> FilterState:
    """The state at ``t``: the random walk since ``state.t`` (none for a ``t`` not after it; over at most
    `Walk.max_gap_s`)."""
    P, walk_t = state.P, state.walk_t
    if t > state.t:
        P = P.copy()
        dt = min(t - state.t, walk.max_gap_s)
        # P[rows, cols] += ..., on the fresh contiguous array's flat view (a third of the indexing's cost)
        P.reshape(-1)[walk.flat] += walk.per_s * dt
        walk_t += dt
    return FilterState(state.C, state.u, P, max(float(t), state.t), walk_t, state.scale, state.parts,
                       state.slots, state.last, state.lin)


class Innovation(NamedTuple):
    """One sample against the state's prediction.

    Attributes
    ----------
    r : tuple of 3 floats
        Measured minus predicted marker point, camera frame, m (the prediction with its stop's own error).
    bias : tuple of 3 floats
        That error as the state has it, camera frame, m.
    H : ndarray (3, layout.model)
        Jacobian of the prediction w.r.t. the model's parameters (w.r.t. its stop's error: the identity).
    R : tuple of 6 floats
        Upper triangle ``(xx, xy, xz, yy, yz, zz)`` of the sample's noise covariance, m^2: what each visit adds
        (`noise`).
    PHt : ndarray (layout.size, 3)
        ``P H^T`` (the stops' errors' and the walk states' rows included).
    S_inv : tuple of 6 floats
        Upper triangle of the inverse innovation covariance ``(H P H^T + R)^-1``.
    nis : float
        ``r^T S^-1 r`` (chi-square, 3 dof, when the filter is consistent).
    share : float
        The noise's share of the innovation covariance, ``tr R / tr S``.
    """

    r: tuple
    bias: tuple
    H: np.ndarray
    R: tuple
    PHt: np.ndarray
    S_inv: tuple
    nis: float
    share: float


def prediction(state: FilterState, pose, factor, model: SampleModel):
    """`sample_floats` for a flange pose (``T_base_flange[:3]`` flat, 12 floats) and kinematic-error factor (6, P)
    or None: ``(h, H, cofactor)``, ``h`` at the estimate, ``H`` and ``cofactor`` at `FilterState.lin`."""
    u = state.u
    k0, k1, k2, s0, s1, s2 = u[:6].tolist()
    h, _, _ = sample_floats(state.parts, (k0, k1, k2), pose, (s0, s1, s2), model.eye_to_hand, factor,
                            u[6:model.layout.model - 6])
    C, v = state.lin
    k0, k1, k2, s0, s1, s2 = v[:6].tolist()
    _, H, cof = sample_floats(C, (k0, k1, k2), pose, (s0, s1, s2), model.eye_to_hand, factor, v[6:])
    return h, H, cof


def noise(state: FilterState, shape_upper, cofactor, model: SampleModel) -> tuple:
    """Upper triangle of what each visit of a stop adds, from its point covariance shape and robot cofactor (upper
    triangles), at the arming's levels times the state's scale: the point noise and the robot's.

    The robot's counts at every visit although a stop's own error (a state) holds what its visits repeat: the
    arming's robot level cannot tell what a pose repeats from what varies between visits (repeatability, the arm
    warming, the load), nor, from a few dozen samples, the robot's noise from the camera's (the demo's cell armed
    itself from 12 samples of an exact robot at a 0.04 point scale and 0.17 mm robot). With the point noise alone
    a revisit read that split as knowledge: on that cell the re-learnt camera's stops, visited again, gave NIS
    16-29 and a false *moved* alarm. The detector compares two visits of a stop with the same allowance."""
    k, m = state.scale * model.point_scale, state.scale * model.robot_var
    a0, a1, a2, a3, a4, a5 = shape_upper
    b0, b1, b2, b3, b4, b5 = cofactor
    return k * a0 + m * b0, k * a1 + m * b1, k * a2 + m * b2, k * a3 + m * b3, k * a4 + m * b4, k * a5 + m * b5


def innovate(state: FilterState, pose, point, shape_upper, factor, model: SampleModel, slot: int) -> Innovation:
    """The `Innovation` of a sample: flange pose (``T_base_flange[:3]`` flat), measured marker point (3 floats,
    camera frame, m, uncorrected), its covariance shape's upper triangle, kinematic-error factor (6, P) or None,
    and the slot of its stop's own error (`open_slot`)."""
    h, H, cof = prediction(state, pose, factor, model)
    R = noise(state, shape_upper, cof, model)
    m, b = model.layout.model, model.layout.slot(slot)
    # H over the whole state is [H, I] on (model, the stop's error): P H^T and H P H^T from those columns.
    PHt = state.P[:, :m].dot(H.T)
    PHt += state.P[:, b:b + 3]
    (a, b_, c), (_, d, e), (_, _, f) = (H.dot(PHt[:m]) + PHt[b:b + 3]).tolist()
    S_inv = inv_sym3_floats(a + R[0], b_ + R[1], c + R[2], d + R[3], e + R[4], f + R[5])
    trace_R = R[0] + R[3] + R[5]
    (p0, p1, p2), (h0, h1, h2) = point, h
    bias = g0, g1, g2 = state.u[b - 6:b - 3].tolist()
    r0, r1, r2 = p0 - h0 - g0, p1 - h1 - g1, p2 - h2 - g2
    i0, i1, i2, i3, i4, i5 = S_inv
    nis = ((r0 * i0 + r1 * i1 + r2 * i2) * r0 + (r0 * i1 + r1 * i3 + r2 * i4) * r1
           + (r0 * i2 + r1 * i4 + r2 * i5) * r2)
    return Innovation((r0, r1, r2), tuple(bias), H, R, PHt, S_inv, nis,
                      trace_R / (a + d + f + trace_R))


def fuse(state: FilterState, PHt: np.ndarray, S_inv: np.ndarray, r) -> FilterState:
    """The Kalman update from ``PHt = P H^T`` (n, 3), the inverse innovation covariance (3, 3) and the innovation
    ``r`` (3,); the camera transform moves on the left (`handeye.calib.result`)."""
    # ndarray.dot: the same BLAS products as @, with less call overhead on these small arrays.
    if float(np.dot(r, S_inv.dot(r))) > GROSS_NIS:
        raise FilterDivergedError("a sample a thousand sigma or more off the estimate (a wild point) is not fused")
    K = PHt.dot(S_inv)
    P = state.P - K.dot(PHt.T)
    P += P.T
    P *= 0.5
    d = K.dot(r)
    d0, d1, d2, d3, d4, d5 = d[:6].tolist()
    if not math.isfinite(d0 + d1 + d2 + d3 + d4 + d5):
        raise FilterDivergedError("the monitoring update diverged (an increment that is not finite); sample skipped")
    R, (x, y, z) = state.parts
    r0, r1, r2 = matmul3(so3_exp_scalar(d0, d1, d2), R)
    t = (x + d3, y + d4, z + d5)
    C = np.array(r0 + t[:1] + r1 + t[1:2] + r2 + t[2:] + (0.0, 0.0, 0.0, 1.0)).reshape(4, 4)
    return FilterState(C, state.u + d[6:], P, state.t, state.walk_t, state.scale, ((r0, r1, r2), t),
                       state.slots, state.last, state.lin)


def fuse_linear(state: FilterState, r, H: np.ndarray, R: np.ndarray) -> FilterState:
    """`fuse` from an innovation ``r`` (3,), its Jacobian over the whole state ``H`` (3, n) and noise ``R`` (3, 3)
    (`linearize`)."""
    PHt = state.P.dot(H.T)
    return fuse(state, PHt, inv_sym3(H.dot(PHt) + R), r)


def linearize(state: FilterState, sample, model: SampleModel, slot: int | None):
    """Innovation ``r`` (3,), Jacobian ``H`` (3, n) over the whole state (the identity on the stop's error in
    ``slot``, zero on the other slots and the walk states; ``slot`` None: zero on every slot) and the noise
    (3, 3) of a sample (`handeye.calib.monitor.stops.Stop`) at ``state``, as arrays (`noise`)."""
    h, H_model, cof = prediction(state, sample.pose, sample.factor, model)
    H = np.zeros((3, len(state.P)))
    H[:, :model.layout.model] = H_model
    r = sample.p - np.array(h)
    if slot is not None:
        b = model.layout.slot(slot)
        H[:, b:b + 3] = np.eye(3)
        r -= state.u[b - 6:b - 3]
    return r, H, sym3(noise(state, sample.shape_upper, cof, model))


def find_slot(state: FilterState, same) -> int | None:
    """The slot holding the stop for which ``same(pose)`` is true (the most recently visited match), or None."""
    hits = [k for k, pose in enumerate(state.slots) if same(pose)]
    return max(hits, key=state.last.__getitem__) if hits else None


def visit_slot(state: FilterState, slot: int) -> FilterState:
    """The stop in ``slot`` visited now (at ``state.walk_t``)."""
    last = list(state.last)
    last[slot] = state.walk_t
    return state._replace(last=tuple(last))


def next_slot(state: FilterState) -> int:
    """The slot a new stop takes (`open_slot`): a new one while fewer than `STOP_SLOTS` are held, else the least
    recently visited."""
    n = len(state.slots)
    return n if n < STOP_SLOTS else min(range(n), key=state.last.__getitem__)


def open_slot(state: FilterState, pose, prior: np.ndarray, shared=None) -> tuple[FilterState, int]:
    """A slot for a new stop at flange ``pose`` (12 floats): a new slot (3 rows before the walk's) while fewer than
    `STOP_SLOTS` are held, else the least recently visited one (its stop's error marginalised: its rows and
    columns dropped). Returns the state and the slot (`next_slot`).

    The new stop's error is ``b = G b_held + w``, ``w`` of covariance ``prior`` (3, 3) independent of the rest:
    ``shared`` is ``(G, held)``, ``G`` (3, 3 m) the regression of its prior on the prior of the errors of the
    ``m`` held stops in slots ``held`` (not `next_slot`'s), or None (``b = w``). So the state takes ``u_b = G
    u_held``, ``P_b. = G P_held.`` and ``P_bb = G P_held,held G^T + prior``.
    """
    layout, slots, last = layout_of(state), list(state.slots), list(state.last)
    k = next_slot(state)
    if k == len(slots):
        b = layout.walk
        u = np.insert(state.u, [b - 6] * 3, 0.0)
        P = np.insert(np.insert(state.P, [b] * 3, 0.0, axis=0), [b] * 3, 0.0, axis=1)
        slots.append(None)
        last.append(0.0)
    else:
        b = layout.slot(k)
        u, P = state.u.copy(), state.P.copy()
        u[b - 6:b - 3] = 0.0
        P[b:b + 3] = 0.0
        P[:, b:b + 3] = 0.0
    if shared is None:
        P[b:b + 3, b:b + 3] = prior
    else:
        G, held = shared
        rows = np.concatenate([layout.slot(j) + np.arange(3) for j in held])
        u[b - 6:b - 3] = G.dot(u[rows - 6])
        cross = G.dot(P[rows])
        P[b:b + 3] = cross
        P[:, b:b + 3] = cross.T
        P[b:b + 3, b:b + 3] = G.dot(cross[:, rows].T) + prior
    slots[k] = tuple(pose)
    return visit_slot(state._replace(u=u, P=P, slots=tuple(slots), last=tuple(last)), k), k


def clear_slots(state: FilterState) -> FilterState:
    """No stop's error held (their rows and columns dropped): after the camera transform is started afresh, the
    stops' errors learnt against the old one would carry its error over as knowledge. The Jacobians are taken at
    the estimate from here (no stop's visits to keep on one point)."""
    layout = layout_of(state)
    held = np.arange(layout.model, layout.walk)
    u, P = np.delete(state.u, held - 6), np.delete(np.delete(state.P, held, axis=0), held, axis=1)
    return relinearize(state._replace(u=u, P=P, slots=(), last=()))


def restart_walk(state: FilterState) -> FilterState:
    """The calibration in use is the estimate again: no walk since it (the walk states and their covariance
    zero)."""
    if not state.u[-6:].any() and not state.P[-6:].any():
        return state
    u, P = state.u.copy(), state.P.copy()
    u[-6:] = 0.0
    P[-6:] = 0.0
    P[:, -6:] = 0.0
    return state._replace(u=u, P=P)


class NoiseTrack(NamedTuple):
    """A weighted running mean of the noise scale the innovations show (`follow_noise`), with the arming's level
    worth `NOISE_SCALE_PRIOR` samples whose noise is all of their innovation, and a memory of
    `NOISE_SCALE_SAMPLES`."""

    total: float = 0.0
    n: float = 0.0


def follow_noise(state: FilterState, track: NoiseTrack, nis: float, share: float) -> tuple[FilterState, NoiseTrack]:
    """The noise scale after a sample of normalised innovation square ``nis`` whose noise was ``share`` of its
    innovation covariance (`Innovation`): the arming levels come from a few dozen samples, so their scale follows
    the innovations.

    Only the noise scales: with ``S = A + s R`` and ``E[nis] = 3`` at the true
    scale, one sample's estimate of it is ``s (1 + (nis / 3 - 1) / share)``
    (moments of the trace), whose variance grows as ``1 / share^2``: each
    counts with weight ``share^2``. A sample the state's covariance dominates
    (a stop's first visit, a re-learnt camera's first samples) says little of
    the noise; counted in full, their NIS under 3 took the scale of the demo's
    re-learnt cell from 1 to 0.28 in six samples, and the next revisits of its
    stops read NIS 12-24 and a false moved alarm. The covariance stays what
    the data and the arming gave: scaling it with the noise would let any
    excess of the innovations feed back on itself.
    """
    keep = 1.0 - 1.0 / NOISE_SCALE_SAMPLES
    weight = share * share
    level = state.scale * (1.0 + (nis / 3.0 - 1.0) / max(share, NOISE_SHARE_MIN))
    track = NoiseTrack(keep * track.total + weight * level, keep * track.n + weight)
    scale = min(max((NOISE_SCALE_PRIOR + track.total) / (NOISE_SCALE_PRIOR + track.n), NOISE_SCALE_RANGE[0]),
                NOISE_SCALE_RANGE[1])
    return state._replace(scale=scale), track


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
