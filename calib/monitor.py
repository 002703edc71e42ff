"""Continuous calibration for a production shift: one engine, armed from a calibration result.

The paper's promise is that a single marker point per robot stop keeps the
calibration alive while the robot works. `MonitorEngine` does that with the
measurement model of ``solve("auto")`` (`calib.model`): it starts from the
camera correction, the marker mount, the noise levels and the covariance of
the result it is armed from (and the robot's kinematic error shared by all
samples, when they carry its factor), and follows the camera transform.

Setups (paper eq. 1, ``A_i X = Y B_i``): eye-to-hand the followed camera
transform is ``Y = T_base_cam`` and the marker mount ``X =
T_flange_marker``; eye-in-hand it is ``X = T_flange_cam`` and the
base-marker pose ``Y = T_base_marker``.

Per sample (fixed work and memory, independent of the shift's length):

1. **Predict.** The camera transform is a random walk (rates
   `MonitorSettings.walk_mm_per_sqrt_h`, ``walk_deg_per_sqrt_h``), so the
   estimate follows a slowly drifting mount instead of alarming on it.
2. **Verify.** The marker point is predicted before it is fused; the error of
   that prediction in C's parent frame is the running verification (``verify_mm``).
3. **Detect.** A windowed GLR test of "the camera jumped by some 6-dof delta"
   on the innovations (`calib.change.ChangeDetector`) raises the *moved*
   alarm; at a stop visited `MIN_BASELINE` times before it tests the marker
   point's change from the stop's earlier visits instead, allowing for the
   random walk since them.
4. **Update.** A Kalman update of the state ``[camera transform, marker-side
   translation, camera parameters, kinematic error]`` from the arming
   calibration's joint covariance (`arm_reference`). What repeated stops
   share (the robot's error at those poses, the camera model) is state, not
   white noise, so a program that returns to the same few stops cannot make
   the estimate over-confident. The noise levels' scale follows the
   innovations.
5. **Drift.** The live estimate's distance from the calibration in use
   (the arming one, or the last re-learnt one), over the workspace the
   arming samples covered, and its rate (exponentially weighted regression
   over ``rate_window_h``). The *drifting* alarm fires when that distance
   reaches ``tolerance_mm`` or will within ``horizon_h`` at the current rate.

After a *moved* alarm the engine re-learns the camera transform from the
stops that follow, and re-arms; it never asks for robot motion. At stops
visited before the move, the change of their marker points measures the move
itself, the rest of the state held; otherwise 6 or more samples are
registered (the marker mount places the marker points in C's parent frame:
three stops not on one line determine the camera) and the filter runs over
them from there, the camera transform started afresh, the rest at its
arming covariance. Until the stops determine it, `MonitorUpdate.message`
says what is missing and which stop would fix it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Annotated, NamedTuple

import numpy as np
from pydantic import Field
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from calib import model
from calib import transforms as tf
from calib.auto import CONSIDER_SIGMA
from calib.errors import CalibrationError
from calib.noise import default_point_cov
from calib.change import ChangeDetector, DetectorConfig
from calib.params import NonNegativeFloat, Params, PositiveFloat
from calib.problem import CalibrationProblem
from calib.result import CalibrationResult, CameraParameter, Residuals
from calib.setup import Setup

#: Visits of a stop before the detector compares its marker point with the stop's earlier ones.
MIN_BASELINE = 3
#: A stop's typical marker point is the running mean of at most this many of its last visits.
BASELINE_VISITS = 12
#: Stops whose typical marker point is kept (the most recently visited).
MAX_STOPS = 64
#: Per-sample false-alarm rate of the *moved* test: against each stop's earlier visits, the
#: statistic of a still camera stays far below its threshold over whole shifts (bench --shift).
DETECTOR_FALSE_ALARM_RATE = 1e-5
#: Seconds per hour: rates are per hour at the edges, times are seconds inside.
HOUR_S = 3600.0
#: Prior 1-sigma of the camera transform when a registration after a move starts the filter again
#: (translation m, rotation rad): wide against the registration's own error, narrow for linearity.
RELEARN_PRIOR = (0.01, np.deg2rad(1.0))
#: A re-learn registration is accepted when its residuals' chi-square is below this quantile;
#: above it, the oldest sample of the set is taken as one from before the move and dropped.
RELEARN_QUANTILE = 0.999
#: The noise levels' scale follows the innovations with this memory (samples), the arming's level counting
#: as this many samples, within this range; an innovation beyond the gate (chi-square 3 dof, 1e-5) does
#: not move it (a move, an outlier).
NOISE_SCALE_SAMPLES = 200
NOISE_SCALE_PRIOR = 10.0
NOISE_SCALE_RANGE = (0.25, 16.0)
NIS_GATE = float(chi2.ppf(1.0 - 1e-5, 3))
#: Prior 1-sigma of a bump (translation m, rotation rad) in the estimate of the move from the stops.
JUMP_PRIOR = (0.01, np.deg2rad(1.0))
#: Fewest samples a re-learn registers the camera from (without stops visited before the move): three
#: stops determine it, more average the point noise and let the consistency test find the move.
REGISTRATION_SAMPLES = 6
#: Workspace points kept from the arming samples (the drift and accuracy figures are RMS over them).
WORKSPACE_POINTS = 200
#: A rate needs this much of its regression window covered before it is reported.
RATE_MIN_SPAN = 0.25

_I3 = np.eye(3)


class MonitorSettings(Params):
    """Settings of `MonitorEngine` (``[monitor]`` of the app's config).

    Attributes
    ----------
    walk_mm_per_sqrt_h, walk_deg_per_sqrt_h : float
        Random walk of the camera transform: 1-sigma of its change after one
        hour (it grows with the square root of time). Sized for a thermally
        drifting mount: a few tenths of a mm per hour of steady drift is
        followed within a few dozen samples.
    tolerance_mm : float
        How far the camera may move from the calibration in use, over the
        workspace, mm, before a plant must act: reaching it is a *drifting*
        alarm. The predicted error of that calibration (the drift with its own
        1-sigma) is reported beside it.
    horizon_h : float
        A *drifting* alarm also fires when the current drift rate reaches the
        tolerance within this many hours.
    rate_window_h : float
        Time constant of the drift-rate regression, h.
    stop_translation_m, stop_rotation_deg : float
        Two samples closer than both are the same stop: only distinct stops
        widen the set a re-learn registers (repeated stops are fused, and
        tested, like any other).
    relearn_samples : int
        Samples held for a re-learn (the newest).
    min_spread_m : float
        The stops' spread across their best-fit line below which a re-learn
        counts them as collinear.
    detector : DetectorConfig
        The *moved* test (GLR windows, false-alarm rate per sample).
    """

    walk_mm_per_sqrt_h: NonNegativeFloat = 0.5
    walk_deg_per_sqrt_h: NonNegativeFloat = 0.02
    tolerance_mm: PositiveFloat = 2.0
    horizon_h: NonNegativeFloat = 2.0
    rate_window_h: PositiveFloat = 1.0
    stop_translation_m: NonNegativeFloat = 0.03
    stop_rotation_deg: NonNegativeFloat = 5.0
    relearn_samples: Annotated[int, Field(strict=True, ge=3)] = 40
    min_spread_m: PositiveFloat = 0.02
    detector: DetectorConfig = Field(default_factory=lambda: DetectorConfig(false_alarm_rate=DETECTOR_FALSE_ALARM_RATE))


class MonitorUpdate(NamedTuple):
    """What one `MonitorEngine.update` saw and did (a NamedTuple: cheap at every sample).

    Attributes
    ----------
    index : int
        Samples given to the engine so far (this one included).
    t : float
        The sample's time, s.
    state : str
        ``"armed"``, ``"relearning"`` (after a move, until the stops determine
        the camera), ``"settling"`` (the detector's window after a re-learn:
        the calibration in use follows the estimate as the stops refine it,
        the *moved* test waits) or
        ``"warming"`` (the detector's first samples after arming).
    alarm : str
        ``""``, ``"drifting"`` or ``"moved"``: raised at this sample.
    level : str
        ``""``, ``"drifting"`` or ``"moved"``: the standing condition (moved
        holds until the re-learn, drifting while it lasts).
    camera_transform : ndarray (4, 4)
        Live ``T_base_cam`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand).
    cov : ndarray (6, 6)
        Its covariance (`calib.result` convention), consider terms included.
    innovation : ndarray (3,)
        Measured minus predicted marker point in the camera frame, m, before fusing.
    nis : float
        Its normalised square (chi-square, 3 dof, when consistent).
    verify_mm : float
        The prediction error in C's parent frame, mm: a verification on a pose
        the estimate had not seen.
    statistic : float
        The GLR statistic (0 while the detector does not run).
    drift_mm, drift_deg : float
        Live estimate against the calibration in use: RMS over the workspace, mm,
        and rotation angle, deg.
    drift_rate_mm_h, drift_rate_deg_h : float or None
        Rates of that drift (None until the regression covers enough time).
    error_mm : float
        Predicted error of the calibration in use over the workspace, mm
        (drift and its own 1-sigma).
    hours_to_tolerance : float or None
        At the current rate (None: not heading there).
    sigma_mm : float
        Live 1-sigma over the workspace, mm (camera correction included).
    message : str
        Plain words for an alarm, a re-learn, or why a re-learn is not possible yet.
    """

    index: int
    t: float
    state: str
    alarm: str
    level: str
    camera_transform: np.ndarray
    cov: np.ndarray
    innovation: np.ndarray
    nis: float
    verify_mm: float
    statistic: float
    drift_mm: float
    drift_deg: float
    drift_rate_mm_h: float | None
    drift_rate_deg_h: float | None
    error_mm: float
    hours_to_tolerance: float | None
    sigma_mm: float
    message: str


@dataclass
class Reference:
    """The calibration in use, as the engine holds it: the arming one, then each re-learnt one.

    Attributes
    ----------
    setup : Setup
    C : ndarray (4, 4)
        Its camera transform (``T_base_cam`` / ``T_flange_cam``).
    K : ndarray (4, 4)
        Marker-side transform (``T_flange_marker`` / ``T_base_marker``) of the arming result.
    theta : ndarray (3,)
        Its camera correction (`calib.model.CAMERA_PARAMS`).
    noise : NoiseLevels
        Noise levels of the arming result.
    workspace : ndarray (W, 3)
        True camera-frame marker points of the arming samples: where the drift and accuracy are measured.
    sigma_mm : float
        Its own 1-sigma over the workspace, mm.
    result : CalibrationResult
        The arming result.
    """

    setup: Setup
    C: np.ndarray
    K: np.ndarray
    theta: np.ndarray
    noise: model.NoiseLevels
    workspace: np.ndarray
    sigma_mm: float
    result: CalibrationResult


@dataclass
class _Stop:
    """A sample: flange pose, measured point, its covariance shape, kinematic-error factor, time; ``pose`` is
    ``A[:3]`` flat as floats (the stop lookup's key) and ``stop`` the lookup's memo (`_Stops.lookup`)."""

    A: np.ndarray
    p: np.ndarray
    shape: np.ndarray
    factor: np.ndarray | None
    t: float
    pose: list
    stop: tuple | None = None


@dataclass
class _Visit:
    """A sample in the detector's window and the filter state before it was fused."""

    sample: _Stop
    state: tuple


class _Stops:
    """Production stops' typical measured marker points (camera frame): the running mean of each stop's last
    `BASELINE_VISITS` visits, for the `MAX_STOPS` most recently visited stops.

    Two flange poses are the same stop when closer than ``translation_m`` and
    ``rotation_rad``; a sample's stop is the least recently visited match.
    A lookup is memoised on the sample while the set of stops is unchanged
    and the match unique (a sample is looked up when tested, and again when
    it leaves the detector's window and joins its stop).
    """

    def __init__(self, translation_m: float, rotation_rad: float):
        self.poses: list[list] = []                     # per stop: its first flange pose, A[:3] flat
        self.mean: list[np.ndarray] = []
        self.n: list[float] = []
        self.t: list[float] = []                        # per stop: the mean time of the visits in its mean
        self.last: list[int] = []
        self.generation = 0                             # changes whenever a stop is added or dropped
        self._visits = 0
        self._t2 = translation_m * translation_m
        # trace(R1^T R2) = 1 + 2 cos(angle): under the angle <=> above this trace
        self._trace = 1.0 + 2.0 * math.cos(rotation_rad)

    @property
    def count(self) -> int:
        return len(self.poses)

    def lookup(self, s: _Stop) -> int | None:
        """The index of ``s``'s stop, or None."""
        if s.stop is not None and s.stop[0] == self.generation:
            return s.stop[1]
        a0, a1, a2, x, a3, a4, a5, y, a6, a7, a8, z = s.pose
        hits = []
        for i, (b0, b1, b2, bx, b3, b4, b5, by, b6, b7, b8, bz) in enumerate(self.poses):
            dx, dy, dz = bx - x, by - y, bz - z
            if (dx * dx + dy * dy + dz * dz < self._t2
                    and a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3 + a4 * b4 + a5 * b5 + a6 * b6 + a7 * b7 + a8 * b8
                    > self._trace):
                hits.append(i)
        if len(hits) > 1:
            return min(hits, key=self.last.__getitem__)
        i = hits[0] if hits else None
        s.stop = (self.generation, i)
        return i

    def add(self, s: _Stop) -> None:
        """Fold a visit's marker point into its stop's mean (a new stop replaces the least recently visited one
        when `MAX_STOPS` are held)."""
        i = self.lookup(s)
        if i is None:
            if len(self.poses) == MAX_STOPS:
                j = self.last.index(min(self.last))
                for held in (self.poses, self.mean, self.n, self.t, self.last):
                    del held[j]
            i = len(self.poses)
            self.poses.append(s.pose)
            self.mean.append(np.zeros(3))
            self.n.append(0.0)
            self.t.append(0.0)
            self.last.append(0)
            self.generation += 1
        n = self.n[i] = min(self.n[i] + 1.0, BASELINE_VISITS)
        self.mean[i] = self.mean[i] + (s.p - self.mean[i]) / n
        self.t[i] += (s.t - self.t[i]) / n
        self._visits += 1
        self.last[i] = self._visits

    def clear(self) -> None:
        self.poses, self.mean, self.n, self.t, self.last = [], [], [], [], []
        self.generation += 1


class _Rate:
    """Exponentially weighted least-squares slope of a vector (a sequence of floats) against time (running sums: O(1))."""

    def __init__(self, tau_s: float):
        self.tau_s = tau_s
        self.reset()

    def add(self, t: float, y) -> None:
        if self.t0 is None:
            self.t0 = t
            self.y0, self.y1 = [0.0] * len(y), [0.0] * len(y)
        decay = math.exp(-(t - self.t_last) / self.tau_s) if self.s0 else 1.0
        x = (t - self.t0) / HOUR_S
        self.s0, self.s1, self.s2 = self.s0 * decay + 1.0, self.s1 * decay + x, self.s2 * decay + x * x
        self.y0 = [a * decay + b for a, b in zip(self.y0, y)]
        self.y1 = [a * decay + x * b for a, b in zip(self.y1, y)]
        self.t_last = t

    def slope(self) -> list | None:
        """Per hour, or None before the regression spans `RATE_MIN_SPAN` of its window."""
        if self.t0 is None or self.t_last - self.t0 < RATE_MIN_SPAN * self.tau_s:
            return None
        s0, s1 = self.s0, self.s1
        den = s0 * self.s2 - s1 * s1
        if den <= 0:
            return None
        return [(s0 * b - s1 * a) / den for a, b in zip(self.y0, self.y1)]

    def reset(self) -> None:
        self.t0, self.t_last = None, 0.0
        self.s0 = self.s1 = self.s2 = 0.0


def arm_reference(result: CalibrationResult, problem: CalibrationProblem, *,
                  consider_theta=None) -> tuple[Reference, np.ndarray]:
    """The calibration in use and the covariance of the engine's state, from a result and its samples.

    The state is ``[dC, tC, t_K, theta, z]``: the camera transform (left
    perturbation, `calib.result`), the marker-side translation, the camera
    parameters (`calib.model.CAMERA_PARAMS`) and, with the problem's
    ``robot_shared_error``, the P kinematic-error parameters all samples share (unit variance). Its
    covariance is the inverse information of ``auto``'s extended model at the
    result (`calib.model.point_jacobians`, the result's noise levels), camera
    parameters that ``auto`` left at nominal held to their typical error
    (``consider_theta``, default `calib.auto.CONSIDER_SIGMA`), and the
    estimate's sensitivity to ``z`` as their cross covariance.

    Parameters
    ----------
    result : CalibrationResult
        Of either setup; its camera correction and noise levels (``auto``) are
        used when present (``solve("auto")``), else none and unit scale; the
        levels are widened by the square of its self-check's held-out ratio
        (observed / predicted) when that exceeds 1.
    problem : CalibrationProblem
        The samples it was solved from: flange poses, marker centres in the
        camera frame as measured, their covariance shapes (default:
        `calib.noise`'s depth model) and, when set, the kinematic-error factor
        at their joints (``robot_shared_error``, (N, 6, P)).

    Returns
    -------
    reference : Reference
    cov : ndarray (12 + P, 12 + P)

    Raises
    ------
    CalibrationError
        Malformed samples, or samples that do not determine the camera.
    """
    setup = Setup(result.setup)
    if problem.setup != setup:
        raise CalibrationError(f"the result is {setup}, its samples {problem.setup}")
    A, p, point_cov, robot_factor = problem.A, problem.points, problem.point_cov, problem.robot_shared_error
    C, K, M = model.split(result.X, result.Y, A, setup)
    theta = result.camera_correction.as_array()
    levels = result.auto.noise if result.auto is not None else model.NoiseLevels()
    # Held-out samples predicted worse than the model expects (auto's self-check): the noise levels were
    # fitted too closely, so they are widened by that ratio (never narrowed).
    ratio = result.self_check.loo_ratio if result.self_check is not None else 1.0
    widen = max(1.0, float(ratio or 1.0)) ** 2
    noise = model.NoiseLevels(levels.point_scale * widen, levels.robot * math.sqrt(widen))
    correction = result.auto.camera_correction if result.auto is not None else {}
    consider = CONSIDER_SIGMA if consider_theta is None else consider_theta
    held = np.array([0.0 if name in correction and correction[name].estimated else consider[name] ** -2
                     for name in model.CAMERA_PARAMS])
    shape, _ = model.point_shape(p, point_cov)
    cov = _state_covariance(C, K, M, theta, setup, noise, shape, held, robot_factor)
    cov = 0.5 * (cov + cov.T)
    q = model.CameraCorrection(*theta).correct(p)
    ref = Reference(setup, C.copy(), K.copy(), theta, noise, q[::max(1, len(q) // WORKSPACE_POINTS)], 0.0, result)
    ref.sigma_mm = workspace_sigma(C, theta, ref.workspace, cov) * 1e3
    return ref, cov


def _state_covariance(C, K, M, theta, setup, noise, shape, held, robot_factor) -> np.ndarray:
    """`arm_reference`'s state covariance: the inverse information of the samples (``M`` (N, 4, 4), point
    covariance shapes ``shape`` (N, 3, 3), ``noise``) about ``[dC, tC, t_K, theta]``, ``held`` (3,) added to
    the camera parameters' information, then the kinematic error's block from ``robot_factor`` (N, 6, P)."""
    _, H_C, H_tK, H_th, H_xi = model.point_jacobians(C, K, M, theta, setup)
    W = np.linalg.inv(noise.point_cov(shape, model.robot_cofactor(C, K, M, setup)))
    J = np.concatenate([H_C, H_tK, H_th], axis=2)                     # (N, 3, 12)
    N = np.einsum("nki,nkl,nlj->ij", J, W, J)
    N[9:12, 9:12] += np.diag(held)
    try:
        cov = np.linalg.inv(N)
    except np.linalg.LinAlgError:
        raise CalibrationError("the reference samples do not determine the camera transform") from None
    if robot_factor is not None:
        F = robot_factor                     # validated with the problem it came in
        # The estimate's error from a shared error z ~ N(0, I): -N^-1 J^T W H_z z.
        G = -cov @ np.einsum("nki,nkl,nlj->ij", J, W, H_xi @ F)
        cov = np.block([[cov + G @ G.T, G], [G.T, np.eye(F.shape[2])]])
    return cov


def workspace_sigma(C, theta, points, cov) -> float:
    """RMS 1-sigma (m) over camera-frame ``points`` (W, 3) of where ``C`` and ``theta`` put them.

    A measured point ``m`` goes to ``C correct_theta(m)``; ``cov`` is the
    state covariance of `arm_reference` (its first 12 rows and columns are used).
    """
    J = np.zeros((len(points), 3, 12))
    J[:, :, :3] = -tf.skew(points @ C[:3, :3].T)
    J[:, :, 3:6] = _I3
    J[:, :, 9:12] = -C[:3, :3] @ model.measure(points, np.asarray(theta, dtype=float))[2]
    var = np.einsum("wij,jk,wik->w", J, cov[:12, :12], J)
    return float(np.sqrt(max(np.mean(var), 0.0)))


def workspace_distance(C1, C2, points) -> float:
    """RMS distance (m) between where two camera transforms put camera-frame ``points`` (W, 3)."""
    d = points @ (C1[:3, :3] - C2[:3, :3]).T + (C1[:3, 3] - C2[:3, 3])
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


class WorkspaceMoments:
    """`workspace_distance` and `workspace_sigma` over fixed camera-frame points (W, 3), at a cost independent of W.

    Both are RMS figures over the points of something the points enter
    linearly: a point's displacement ``dR p + dt`` between two camera
    transforms, and the Jacobian of where ``C`` and ``theta`` put it, which is
    ``R_C G(p; theta) B`` with ``B = diag(R_C^T, R_C^T, I, I)`` and ``G``
    linear in ``[1, focal_scale, depth_scale, depth_offset]`` with per-point
    terms. So the mean and second moments of the points (and of those terms)
    give them exactly, with a few small products per sample.
    """

    def __init__(self, points):
        points = np.asarray(points, dtype=float)
        n = len(points)
        mean = points.mean(axis=0)
        c = points - mean
        w, V = np.linalg.eigh(c.T @ c / n)
        # [L | mean] with L L^T the points' centred second moment: RMS |dR p + dt| = |[dR L | dR mean + dt]|.
        self.lever = tuple(map(tuple, np.column_stack([V * np.sqrt(np.clip(w, 0.0, None)), mean]).tolist()))
        xy, xy_z = points[:, :2], points[:, :2] / points[:, 2:]
        G = np.zeros((n, 4, 3, 12))                     # per point, the terms of G for 1, f, s, d
        G[:, 0, :, :3] = -tf.skew(points)
        G[:, 0, :, 3:6] = _I3
        G[:, 0, :, 9] = -points
        G[:, 0, :, 10] = -points / points[:, 2:]
        G[:, 0, :2, 11] = -xy
        G[:, 1, :2, 9] = -xy                            # focal_scale
        G[:, 1, :2, 10] = -xy_z
        G[:, 2, :2, 11] = -xy                           # depth_scale
        G[:, 3, :2, 11] = -xy_z                         # depth_offset
        Q = np.einsum("wmai,wnaj->mnji", G, G) / n        # Q_mn^T = mean G_n^T G_m
        m, k = np.triu_indices(4)
        self.terms = (Q[m, k] + np.where((m < k)[:, None, None], Q[k, m], 0.0)).reshape(10, 144)
        self._B = np.eye(12)

    def displacement(self, dR, dt) -> tuple:
        """The points' displacement ``dR p + dt`` (``dR = R_1 - R_2`` as rows of floats, ``dt = t_1 - t_2``) as 12
        floats, linear in ``(dR, dt)``, whose norm is its RMS over the points (`workspace_distance`), m."""
        (a0, a1, a2, a3), (b0, b1, b2, b3), (c0, c1, c2, c3) = self.lever
        (r0, r1, r2), (r3, r4, r5), (r6, r7, r8) = dR
        s0, s1, s2 = dt
        return (r0 * a0 + r1 * b0 + r2 * c0, r0 * a1 + r1 * b1 + r2 * c1, r0 * a2 + r1 * b2 + r2 * c2,
                r0 * a3 + r1 * b3 + r2 * c3 + s0,
                r3 * a0 + r4 * b0 + r5 * c0, r3 * a1 + r4 * b1 + r5 * c1, r3 * a2 + r4 * b2 + r5 * c2,
                r3 * a3 + r4 * b3 + r5 * c3 + s1,
                r6 * a0 + r7 * b0 + r8 * c0, r6 * a1 + r7 * b1 + r8 * c1, r6 * a2 + r7 * b2 + r8 * c2,
                r6 * a3 + r7 * b3 + r8 * c3 + s2)

    def sigma(self, C, theta, cov) -> float:
        """`workspace_sigma` of ``C``, ``theta`` (3,) and the state covariance ``cov`` over the points, m."""
        B = self._B
        B[:3, :3] = B[3:6, 3:6] = C[:3, :3]
        # sum over m <= n of c_m c_n <B^T cov B, Q_mn^T + Q_nm^T (m < n)>, c = [1, f, s, d]
        t00, t01, t02, t03, t11, t12, t13, t22, t23, t33 = (self.terms @ (B.T @ cov[:12, :12] @ B).ravel()).tolist()
        s, d, f = theta.tolist()
        var = (t00 + f * (t01 + f * t11) + s * (t02 + f * t12 + s * t22)
               + d * (t03 + f * t13 + s * t23 + d * t33))
        return math.sqrt(max(var, 0.0))


def sample_model(C, t_K, A, theta, setup: str, factor=None, z=None):
    """One sample's predicted measured marker point, its Jacobian w.r.t. the engine's state, and its robot cofactor.

    The single-sample form of `calib.model.point_jacobians` and
    `calib.model.robot_cofactor` (the same model, tested against them), at
    the flange pose ``A Exp(factor z)`` when the state carries the robot's
    kinematic error ``z``. Its 3-vectors and 3x3 blocks are Python floats:
    numpy's per-call cost would be most of the engine's per-sample cost.

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
    R_C, t_C = _parts(C)
    R_A, t_A = _parts(A)
    if factor is not None:
        w0, w1, w2, w3, w4, w5 = (factor @ z).tolist()
        t_A = _add(t_A, _mv(R_A, (w3, w4, w5)))
        R_A = _mm(R_A, _exp(w0, w1, w2))
    eye_to_hand = setup == Setup.EYE_TO_HAND
    if eye_to_hand:
        R_M, t_M = R_A, t_A
    else:
        R_M = _tr(R_A)
        t_M = _mv(R_M, t_A, -1.0)
    t_K = tuple(t_K.tolist())
    lever = _mv(R_M, t_K)
    y = _add(lever, t_M)                                # marker center in C's parent frame
    v = _add(y, t_C, -1.0)
    Ct = _tr(R_C)
    qx, qy, qz = _mv(Ct, v)                             # the point without camera error
    s, d, f = theta.tolist()
    g, D, dz = 1.0 + s + d / qz, 1.0 + f, d / (qz * qz)
    # The camera's Jacobian J_p = [[gD, 0, jx], [0, gD, jy], [0, 0, jz]], and J_p R_C^T.
    gD, jx, jy, jz = g * D, -D * qx * dz, -D * qy * dz, g - qz * dz
    c0, c1, c2 = Ct
    JR = (_add(_scale(c0, gD), c2, jx), _add(_scale(c1, gD), c2, jy), _scale(c2, jz))
    H_tK = _mm(JR, R_M)
    J_theta = ((D * qx, D * qx / qz, qx * g), (D * qy, D * qy / qz, qy * g), (qz, 1.0, 0.0))
    # dq/d[dC, tC] = R_C^T [[v]x, -I]; a row r of J_p R_C^T times [v]x is r x v.
    rows = [_cross(JR[i], v) + _scale(JR[i], -1.0) + H_tK[i] + J_theta[i] for i in range(3)]
    if factor is None:
        H = np.array(rows)
    else:
        # d/dxi: [-(H_tK [t_K]x), H_tK] eye-to-hand, [J_p R_C^T [y]x, -J_p R_C^T] eye-in-hand.
        if eye_to_hand:
            X = [_cross(t_K, H_tK[i]) + H_tK[i] for i in range(3)]
        else:
            X = [_cross(JR[i], y) + _scale(JR[i], -1.0) for i in range(3)]
        H = np.empty((3, 12 + factor.shape[1]))
        H[:, :12] = rows
        H[:, 12:] = np.array(X) @ factor
    lx, ly, lz = _mv(Ct, lever if eye_to_hand else y)
    rho2 = model.ROBOT_ROTATION_PER_M ** 2
    a = 1.0 + rho2 * (lx * lx + ly * ly + lz * lz)
    cof = np.array([[a - rho2 * lx * lx, -rho2 * lx * ly, -rho2 * lx * lz],
                    [-rho2 * lx * ly, a - rho2 * ly * ly, -rho2 * ly * lz],
                    [-rho2 * lx * lz, -rho2 * ly * lz, a - rho2 * lz * lz]])
    return np.array((qx * gD, qy * gD, qz * g)), H, cof


# 3-vectors and 3x3 matrices (tuples of rows) on Python floats, for `sample_model` and the engine's figures.

def _parts(T):
    """Rotation rows and translation of a (4, 4) transform, as floats."""
    (a, b, c, x), (d, e, f, y), (g, h, i, z), _ = T.tolist()
    return ((a, b, c), (d, e, f), (g, h, i)), (x, y, z)


def _tr(M):
    (a, b, c), (d, e, f), (g, h, i) = M
    return (a, d, g), (b, e, h), (c, f, i)


def _mv(M, v, k: float = 1.0):
    """``k M v``."""
    (a, b, c), (d, e, f), (g, h, i) = M
    x, y, z = v
    return k * (a * x + b * y + c * z), k * (d * x + e * y + f * z), k * (g * x + h * y + i * z)


def _mm(M, N):
    (a, b, c), (d, e, f), (g, h, i) = M
    (p, q, r), (s, t, u), (v, w, x) = N
    return ((a * p + b * s + c * v, a * q + b * t + c * w, a * r + b * u + c * x),
            (d * p + e * s + f * v, d * q + e * t + f * w, d * r + e * u + f * x),
            (g * p + h * s + i * v, g * q + h * t + i * w, g * r + h * u + i * x))


def _add(a, b, k: float = 1.0):
    """``a + k b``."""
    return a[0] + k * b[0], a[1] + k * b[1], a[2] + k * b[2]


def _scale(a, k: float):
    return k * a[0], k * a[1], k * a[2]


def _cross(a, b):
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


def _exp(a0: float, a1: float, a2: float):
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


def _angle(R1, R2) -> float:
    """`calib.transforms.rotation_angle` of ``R1 R2^T`` (rotations as rows of floats), rad."""
    (a, b, c), (d, e, f), (g, h, i) = _mm(R1, _tr(R2))
    return math.atan2(math.sqrt((h - f) ** 2 + (c - g) ** 2 + (d - b) ** 2) / 2.0, (a + e + i - 1.0) / 2.0)


def _inv_sym3(S) -> np.ndarray:
    """Inverse of a symmetric positive definite (3, 3) matrix (cofactors, from its upper triangle)."""
    (a, b, c), (_, d, e), (_, _, f) = S.tolist()
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
    k = 1.0 / (a * A + b * B + c * C)
    D, E, F = (a * f - c * c) * k, (b * c - a * e) * k, (a * d - b * b) * k
    A, B, C = A * k, B * k, C * k
    return np.array([[A, B, C], [B, D, E], [C, E, F]])


def _plain(a, shape) -> bool:
    """``a`` is a float64 array of ``shape``, finite and within `calib.transforms.MAX_MAGNITUDE`: the common case,
    which the general validators would return unchanged (anything else goes to them for their checks and message)."""
    # A sum of squares within the bound's square bounds every entry; NaN and inf fail the comparison.
    return (type(a) is np.ndarray and a.dtype == np.float64 and a.shape == shape
            and float(np.vdot(a, a)) <= tf.MAX_MAGNITUDE ** 2)


def _plain_transform(T) -> bool:
    """`_plain` and a rigid transform within `calib.transforms.check_transform`'s tolerances."""
    if not _plain(T, (4, 4)):
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


def _plain_cov(S) -> bool:
    """`_plain` and symmetric within `calib.model.check_point_cov`'s tolerance."""
    if not _plain(S, (3, 3)):
        return False
    (a, b, c), (d, e, f), (g, h, i) = S.tolist()
    tol = 1e-9 * max(abs(a), abs(b), abs(c), abs(d), abs(e), abs(f), abs(g), abs(h), abs(i), 1e-30)
    return abs(b - d) <= tol and abs(c - g) <= tol and abs(f - h) <= tol


class MonitorEngine:
    """The monitoring engine (module docstring). ``arm`` it, then ``update`` it with every sample.

    State: the camera transform ``C`` (4, 4) and ``u = [t_K, theta, z]``
    (`arm_reference`), with their joint covariance; a random walk moves ``C``
    only. Parameters: ``settings`` (`MonitorSettings`).
    """

    def __init__(self, settings: MonitorSettings | None = None):
        self.settings = settings or MonitorSettings()
        self.detector = ChangeDetector(self.settings.detector)
        self.reference: Reference | None = None
        self._count = 0

    # ------------------------------------------------------------------ arming

    def arm(self, result: CalibrationResult, problem: CalibrationProblem, *, t: float = 0.0) -> Reference:
        """Arm from a calibration and the samples it was solved from (`arm_reference`); the next sample is
        tested at once.

        ``t`` is the time the calibration holds for (s, the samples' clock).
        Returns the calibration in use (its ``sigma_mm``: 1-sigma over the workspace).

        Raises
        ------
        CalibrationError
            The samples are malformed or do not determine the camera.
        """
        ref, cov = arm_reference(result, problem)
        self.reference = ref
        self._C = ref.C.copy()
        self._u = np.r_[ref.K[:3, 3], ref.theta, np.zeros(len(cov) - 12)]
        self._P = cov
        self._t = float(t)
        self._count = 0
        self._window: list[_Visit] = []
        cfg = self.settings
        self._stops = _Stops(cfg.stop_translation_m, np.deg2rad(cfg.stop_rotation_deg))
        self._relearn_set: list[_Stop] = []
        self._rate = _Rate(cfg.rate_window_h * HOUR_S)
        self._workspace = WorkspaceMoments(ref.workspace)
        self._in_use = None, None
        # The random walk's variance per hour (diagonal of the camera transform's block).
        sr, st = np.deg2rad(cfg.walk_deg_per_sqrt_h), cfg.walk_mm_per_sqrt_h * 1e-3
        self._walk_per_h = np.array([sr * sr] * 3 + [st * st] * 3)
        self._moved = False
        self._settle = 0
        self._noise_scale, self._scale_sum, self._scale_n = 1.0, 0.0, 0.0
        self._drifting = False
        self._alarms: list[tuple[int, float, str]] = []
        self.detector.reset()
        return ref

    def disarm(self) -> None:
        """Forget the calibration and everything learnt since (`arm` again to go on)."""
        self.reference = None

    @property
    def armed(self) -> bool:
        return self.reference is not None

    @property
    def samples_until_tested(self) -> int:
        """Samples before the *moved* test runs again (0: it runs): the re-learn's settling, then the
        detector's first three innovations (two points cannot separate a 6-dof move)."""
        return self._settle + max(3 - self.detector.count, 0) if self.reference is not None else 0

    @property
    def n_factor(self) -> int:
        """Robot kinematic-error parameters in the state (0: none)."""
        return len(self._u) - 6 if self.reference is not None else 0

    @property
    def state_size(self) -> int:
        """Floats held (bounded: independent of the stream length)."""
        per_sample = 16 + 3 + 9 + 6 * self.n_factor
        state = 16 + len(self._u) + self._P.size
        return (state + self.detector.state_size + per_sample * len(self._relearn_set)
                + (per_sample + 3 + state) * len(self._window) + 19 * self._stops.count)

    # ------------------------------------------------------------------ the filter

    def _linearize(self, C, u, s: _Stop):
        """Innovation ``r`` (3,), Jacobian ``H`` (3, n) of the predicted point w.r.t. the state, noise ``R`` (3, 3)."""
        ref = self.reference
        h, H, cof = sample_model(C, u[:3], s.A, u[3:6], ref.setup, s.factor, u[6:])
        scale = self._noise_scale
        return s.p - h, H, (scale * ref.noise.point_scale) * s.shape + (scale * ref.noise.robot ** 2) * cof

    def _predict(self, t: float) -> None:
        """The random walk of the camera transform up to ``t``."""
        if t > self._t:
            diagonal = np.einsum("ii->i", self._P[:6, :6])    # a view: the variances in place
            diagonal += self._walk_per_h * ((t - self._t) / HOUR_S)
        self._t = max(t, self._t)

    def _fuse(self, r, H, R, PHt=None, S_inv=None) -> None:
        """Kalman update of the whole state (``PHt = P H^T`` and the innovation's inverse covariance when known)."""
        if PHt is None:
            PHt = self._P @ H.T
            S_inv = _inv_sym3(H @ PHt + R)
        Kg = PHt @ S_inv
        P = self._P - Kg @ PHt.T
        self._P = 0.5 * (P + P.T)
        d = Kg @ r
        d0, d1, d2, d3, d4, d5 = d[:6].tolist()
        R, (x, y, z) = _parts(self._C)
        r0, r1, r2 = _mm(_exp(d0, d1, d2), R)
        self._C = np.array((r0 + (x + d3,), r1 + (y + d4,), r2 + (z + d5,), (0.0, 0.0, 0.0, 1.0)))
        self._u = self._u + d[6:]

    def _state(self):
        return self._C, self._u, self._P

    def _restore(self, state) -> None:
        self._C, self._u, self._P = state

    # ------------------------------------------------------------------ samples

    def update(self, t: float, T_base_flange, point_cam, point_cov=None, robot_factor=None) -> MonitorUpdate:
        """Test and fuse one sample taken at a standstill.

        Parameters
        ----------
        t : float
            Its time, s (the clock of `arm`'s ``t``; not before the previous sample's).
        T_base_flange : array_like, shape (4, 4)
            The flange pose the robot reports.
        point_cam : array_like, shape (3,)
            The marker center in the camera frame, m, as measured (uncorrected).
        point_cov : array_like, shape (3, 3), optional
            Its covariance shape, m^2 (default: `calib.noise`'s depth model).
        robot_factor : array_like, shape (6, P), optional
            The kinematic-error factor at its joints (needed when armed with one).

        Raises
        ------
        CalibrationError
            Not armed, or a malformed sample (nothing changes).
        """
        s = self._sample(t, T_base_flange, point_cam, point_cov, robot_factor)
        self._count += 1
        self._predict(s.t)
        r, H, R = self._linearize(self._C, self._u, s)
        PHt = self._P @ H.T
        S_inv = _inv_sym3(H @ PHt + R)
        nis = float(r @ S_inv @ r)
        if not self._moved and nis < NIS_GATE:
            self._follow_noise(nis)
        verify = math.sqrt(float(r @ r)) * 1e3          # |R_C r|: the prediction error in C's parent frame
        if self._moved:
            self._relearn_set.append(s)
            del self._relearn_set[:-self.settings.relearn_samples]
            alarm, statistic, message = "", 0.0, self._relearn()
        else:
            alarm, statistic, message = self._test(s, r, H, R, PHt, S_inv)
        return self._figures(s, self._next_state(), alarm, message, r, nis, verify, statistic)

    def _follow_noise(self, nis: float) -> None:
        """The arming noise levels come from a few dozen samples: their scale follows the innovations (a running
        mean of the NIS at unit scale, with the arming's level worth `NOISE_SCALE_PRIOR` samples)."""
        keep = 1.0 - 1.0 / NOISE_SCALE_SAMPLES
        self._scale_sum = keep * self._scale_sum + nis * self._noise_scale / 3.0
        self._scale_n = keep * self._scale_n + 1.0
        self._noise_scale = min(max((NOISE_SCALE_PRIOR + self._scale_sum) / (NOISE_SCALE_PRIOR + self._scale_n),
                                    NOISE_SCALE_RANGE[0]), NOISE_SCALE_RANGE[1])

    def _test(self, s: _Stop, r, H, R, PHt, S_inv) -> tuple[str, float, str]:
        """The *moved* test of a sample: ``(alarm, statistic, message)``; fused if it passes, else the re-learn starts."""
        stops = self._stops
        i = stops.lookup(s)
        r_test, S_test_inv, offset_var = r, S_inv, None
        if i is not None and stops.n[i] >= MIN_BASELINE:
            # Against the stop's own earlier visits: what they share (unmodelled errors of the robot or the
            # camera at that pose, the estimate's own error) is no change; only the camera moving is.
            Hc = H[:, :6]
            r_test = s.p - stops.mean[i]
            # A drifting camera has moved since those visits by the same for every stop: the long window's
            # test is for a move beyond the random walk over that time.
            offset_var = self._walk_per_h * ((s.t - stops.t[i]) / HOUR_S)
            S_test_inv = _inv_sym3(R * (1.0 + 1.0 / stops.n[i]) + (Hc * offset_var) @ Hc.T)
        # While a re-learnt camera settles the stops still refine it: that is not a move.
        fired = not self._settle and self.detector.update(r_test, S_test_inv, H[:, :6], offset_var)
        statistic = self.detector.statistic
        if not fired:
            self._window.append(_Visit(s, (self._C, self._u, self._P)))
            self._fuse(r, H, R, PHt, S_inv)
            if len(self._window) > self.settings.detector.window:
                stops.add(self._window.pop(0).sample)
            return "", statistic, ""
        message = (f"camera moved (GLR statistic {statistic:.1f} > {self.detector.threshold:.1f}); "
                   "re-learning it from the production stops")
        # The move lies inside the window, most likely `onset` samples ago: go back to the state before it and
        # re-learn from the samples since; those before it join their stops.
        before = max(len(self._window) + 1 - self.detector.onset(), 0)
        if before < len(self._window):
            self._restore(self._window[before].state)
        for v in self._window[:before]:
            stops.add(v.sample)
        self._relearn_set = [v.sample for v in self._window[before:]] + [s]
        self._window = []
        self._moved = True
        self._drifting = False
        return "moved", statistic, message + "; " + self._relearn()

    def _next_state(self) -> str:
        """The engine's state after a sample (`MonitorUpdate.state`); counts the settling window down."""
        if self._moved:
            return "relearning"
        if self._settle:
            # Just re-learnt: what the next stops add refines that calibration, it is no drift.
            self._settle -= 1
            ref = self.reference
            ref.C, ref.theta = self._C.copy(), self._u[3:6].copy()
            ref.sigma_mm = self._workspace.sigma(self._C, ref.theta, self._P) * 1e3
            return "settling"
        return "armed" if self.detector.count >= 3 else "warming"

    def _sample(self, t, T_base_flange, point_cam, point_cov, robot_factor) -> _Stop:
        if self.reference is None:
            raise CalibrationError("the monitoring engine is not armed: give it a calibration result first")
        # Float arrays of the right shape are checked on the spot; anything else goes through the validators.
        A = T_base_flange.copy() if _plain_transform(T_base_flange) else tf.check_transform(T_base_flange,
                                                                                             "T_base_flange")
        p = point_cam.copy() if _plain(point_cam, (3,)) else tf.check_points(
            np.asarray(point_cam, dtype=float).reshape(1, -1), "point_cam")[0]
        if point_cov is None:
            shape = default_point_cov(p[None])[0]
        else:
            shape = point_cov.copy() if _plain_cov(point_cov) else model.check_point_cov(point_cov, 1)[0]
        factor = None
        if self.n_factor:
            if robot_factor is None:
                raise CalibrationError("the engine was armed with the robot's kinematic error: every sample "
                                       "needs its robot_factor (6, P)")
            factor = robot_factor.copy() if _plain(robot_factor, (6, self.n_factor)) else tf.as_real_array(
                robot_factor, "robot_factor")
            if factor.shape != (6, self.n_factor):
                raise CalibrationError(f"robot_factor must have shape (6, {self.n_factor}), got {factor.shape}")
        if not math.isfinite(t) or t < self._t - 1e-9:
            raise CalibrationError(f"t must be finite and not before the previous sample's ({self._t}), got {t}")
        return _Stop(A, p, shape, factor, float(t), A[:3].ravel().tolist())

    # ------------------------------------------------------------------ stops

    def _same_stop(self, A1, A2) -> bool:
        """Two flange poses closer than `MonitorSettings.stop_translation_m` and ``stop_rotation_deg``."""
        rot, trans = tf.pose_error(A1, A2)
        return bool(trans < self.settings.stop_translation_m and rot < np.deg2rad(self.settings.stop_rotation_deg))

    # ------------------------------------------------------------------ re-learning

    def _relearn(self) -> str:
        """Estimate the move from the stops since it; on success the filter goes on there and re-arms.

        Stops visited before the move (a baseline) give the move itself: their
        innovations' change, with what the stop shares with its earlier
        visits cancelled (`_jump`). Without three such stops, a rigid
        registration of the stops' marker points (`_register`).
        """
        samples = self._relearn_set
        while True:
            why = self._spread(samples)
            if why:
                return why
            fit = self._jump(samples)
            how = "measured at"
            if fit is None:
                if len(samples) < REGISTRATION_SAMPLES:
                    return (f"re-learning: {len(samples)} samples since the move at stops visited before it "
                            f"fewer than 3 times; registering the camera needs {REGISTRATION_SAMPLES}")
                fit = self._refit(self._register(samples), samples)
                how = "registered"
            ok, C, P = fit
            if ok:
                break
            self._relearn_set = samples = samples[1:]         # the oldest is from before the move
        sigma_mm = self._workspace.sigma(C, self._u[3:6], P) * 1e3
        if how == "registered" and sigma_mm > self.settings.tolerance_mm:
            return (f"re-learning: registered from {len(samples)} samples, but its 1-sigma over the workspace is "
                    f"{sigma_mm:.1f} mm (tolerance {self.settings.tolerance_mm:g} mm): waiting for more stops, "
                    "spread across the workspace")
        ref = self.reference
        moved_mm = workspace_distance(C, self._C, ref.workspace) * 1e3
        moved_deg = float(np.rad2deg(tf.rotation_angle(C[:3, :3] @ self._C[:3, :3].T)))
        self._stops.clear()        # the stops' marker points as the old camera saw them
        self._C, self._P = C, P
        ref.C, ref.theta = C.copy(), self._u[3:6].copy()
        ref.sigma_mm = self._workspace.sigma(C, ref.theta, P) * 1e3
        self._rate.reset()
        self._settle = self.settings.detector.window
        self._moved = False
        self._relearn_set = []
        self.detector.reset()
        return (f"re-learnt the camera ({how} {len(self._distinct(samples))} production stops, {len(samples)} "
                f"samples): it moved {moved_mm:.1f} mm over the workspace and {moved_deg:.2f} deg")

    def _jump(self, samples):
        """The move from the innovations' change at stops with a baseline: ``(ok, C, P)`` or None.

        Weighted least squares of ``p_i - mean_stop = H_i delta`` (the marker point's change at its stop) at the
        estimate from before the move; ``ok`` when the fit's chi-square agrees
        with the noise (else the oldest sample is from before the move).
        """
        rows, known = [], []
        stops = self._stops
        for s in samples:
            i = stops.lookup(s)
            if i is None:
                continue
            known.append(s)
            if stops.n[i] < MIN_BASELINE:
                continue
            _, H, R = self._linearize(self._C, self._u, s)
            rows.append((s.p - stops.mean[i], H[:, :6], np.linalg.inv(R * (1.0 + 1.0 / stops.n[i]))))
        if len(self._distinct(known)) < 3:
            return None
        # A bump's prior (`JUMP_PRIOR`): where the stops cannot tell a turn of the camera from a shift (one marker
        # seen from the front, eye-in-hand), the estimate stays small instead of trading the two without bound.
        st, sr = JUMP_PRIOR
        N = sum(H.T @ W @ H for _, H, W in rows) + np.diag([1.0 / sr**2] * 3 + [1.0 / st**2] * 3)
        g = sum(H.T @ W @ r for r, H, W in rows)
        cov = np.linalg.inv(N)
        d = cov @ g
        chi = sum(float((r - H @ d) @ W @ (r - H @ d)) for r, H, W in rows) + float(d @ (N - sum(
            H.T @ W @ H for _, H, W in rows)) @ d)
        dof = 3 * len(rows) - 6
        ok = dof <= 0 or chi <= chi2.ppf(RELEARN_QUANTILE, dof)
        C = tf.make_transform(tf.so3_exp(d[:3]) @ self._C[:3, :3], self._C[:3, 3] + d[3:])
        P = self._P.copy()
        P[:6, :6] += 0.5 * (cov + cov.T)
        return ok, C, P

    def _spread(self, samples) -> str:
        """Why ``samples`` cannot determine the camera transform yet ('' when they can)."""
        ref = self.reference
        distinct = self._distinct(samples)
        if len(distinct) < 3:
            return (f"re-learning: {len(distinct)} distinct stop{'s' if len(distinct) != 1 else ''} since the move, "
                    "3 not on one line are needed")
        y = np.array([self._parent_point(s) for s in distinct])
        _, sv, Vt = np.linalg.svd(y - y.mean(axis=0), full_matrices=False)
        spread = sv[1] / math.sqrt(len(y))
        if spread < self.settings.min_spread_m:
            frame = "base" if ref.setup == Setup.EYE_TO_HAND else "flange"
            return (f"re-learning: the {len(distinct)} stops since the move lie on a line (spread across it "
                    f"{spread * 1e3:.1f} mm): a stop {self.settings.min_spread_m * 2e3:.0f} mm or more off the line "
                    f"along {np.round(Vt[0], 2).tolist()} ({frame} frame) would determine the camera")
        return ""

    def _distinct(self, samples):
        out = []
        for s in samples:
            if not any(self._same_stop(o.A, s.A) for o in out):
                out.append(s)
        return out

    def _parent_point(self, s: _Stop) -> np.ndarray:
        M = s.A if self.reference.setup == Setup.EYE_TO_HAND else tf.invert(s.A)
        return M[:3, :3] @ self.reference.K[:3, 3] + M[:3, 3]

    def _register(self, samples) -> np.ndarray:
        """Rigid registration of the corrected camera points to the held marker mount's points (Kabsch)."""
        corr = model.CameraCorrection(*self.reference.theta)
        c = corr.correct(np.array([s.p for s in samples]))
        y = np.array([self._parent_point(s) for s in samples])
        R = Rotation.align_vectors(y - y.mean(axis=0), c - c.mean(axis=0))[0].as_matrix()
        return tf.make_transform(R, y.mean(axis=0) - R @ c.mean(axis=0))

    def _refit(self, C, samples):
        """The filter over ``samples`` from a registration ``C``: ``(ok, C, P)``, ``ok`` as in `_jump`.

        The camera transform starts at `RELEARN_PRIOR`, independent of the rest
        of the state, which keeps its covariance and moves only as far as the
        samples determine it.
        """
        st, sr = RELEARN_PRIOR
        saved = self._state()
        self._C = C
        for _ in range(2):            # once more from the first pass's estimate: the registration is unweighted
            self._P = saved[2].copy()
            self._P[:6] = 0.0
            self._P[:, :6] = 0.0
            self._P[:6, :6] = np.diag([sr * sr] * 3 + [st * st] * 3)
            for s in samples:
                self._fuse(*self._linearize(self._C, self._u, s))
        chi = 0.0
        for s in samples:
            r, H, R = self._linearize(self._C, self._u, s)
            chi += float(r @ np.linalg.solve(R + H[:, 6:] @ self._P[6:, 6:] @ H[:, 6:].T, r))
        dof = 3 * len(samples) - 6
        ok = dof <= 0 or chi <= chi2.ppf(RELEARN_QUANTILE, dof)
        out = (ok, self._C, self._P)
        self._restore(saved)
        return out

    # ------------------------------------------------------------------ figures

    def _figures(self, s: _Stop, state, alarm, message, r, nis, verify, statistic) -> MonitorUpdate:
        ref, cfg = self.reference, self.settings
        if ref.C is not self._in_use[0]:             # the calibration in use as floats, once per change
            self._in_use = ref.C, _parts(ref.C)
        (R, t), (R0, t0) = _parts(self._C), self._in_use[1]
        dR = (_add(R[0], R0[0], -1.0), _add(R[1], R0[1], -1.0), _add(R[2], R0[2], -1.0))
        dt = _add(t, t0, -1.0)
        moved = self._workspace.displacement(dR, dt)
        drift_m = math.hypot(*moved)
        drift_deg = math.degrees(_angle(R, R0))
        sigma = self._workspace.sigma(self._C, self._u[3:6], self._P)
        error_mm = math.hypot(drift_m * 1e3, ref.sigma_mm)
        rate_mm = rate_deg = hours = None
        if state == "armed":
            # The workspace points' displacement is linear in the drift: its slope gives the drift rate.
            self._rate.add(s.t, moved + (drift_deg, drift_m))
            slope = self._rate.slope()
            if slope is not None:
                rate_mm = math.hypot(*slope[:12]) * 1e3
                rate_deg = abs(slope[12])
                growth = slope[13] * 1e3
                if growth > 0 and drift_m * 1e3 < cfg.tolerance_mm:
                    hours = (cfg.tolerance_mm - drift_m * 1e3) / growth
        # Drifting: the camera has moved from the calibration in use by the tolerance, or will within the
        # horizon at the current rate (the calibration's own uncertainty is in error_mm, not an alarm).
        # Once raised it holds until the drift is back under half the tolerance and not heading there within
        # twice the horizon: a drift hovering at the line is one alarm, not one per crossing.
        held = 0.5 if self._drifting else 1.0
        drifting = state == "armed" and (drift_m * 1e3 >= held * cfg.tolerance_mm
                                         or (hours is not None and hours <= cfg.horizon_h / held))
        if drifting and not self._drifting and not alarm:
            alarm = "drifting"
            when = "now" if hours is None else f"in {hours:.1f} h at {rate_mm:.2f} mm/h"
            message = (f"camera drifting: {drift_m * 1e3:.2f} mm over the workspace from the calibration in use "
                       f"(predicted error {error_mm:.2f} mm), tolerance {cfg.tolerance_mm:g} mm reached {when}")
        self._drifting = drifting
        if alarm:
            self._alarms.append((self._count, s.t, alarm))
        level = "moved" if (alarm == "moved" or state == "relearning") else ("drifting" if drifting else "")
        return MonitorUpdate(self._count, s.t, state, alarm, level, self._C.copy(), self._P[:6, :6].copy(), r, nis,
                             verify, statistic, drift_m * 1e3, drift_deg, rate_mm, rate_deg, error_mm, hours,
                             sigma * 1e3, message)

    @property
    def camera_transform(self) -> np.ndarray:
        """Live ``T_base_cam`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand)."""
        return self._C.copy()

    @property
    def cov(self) -> np.ndarray:
        """Its covariance (6, 6), `calib.result` convention."""
        return self._P[:6, :6].copy()

    @property
    def camera_correction(self) -> model.CameraCorrection:
        """The live camera correction (refined by every sample; held through a re-learn)."""
        return model.CameraCorrection(*self._u[3:6])

    @property
    def alarms(self) -> list[tuple[int, float, str]]:
        """``(sample index, t, "drifting" | "moved")`` of every alarm since arming."""
        return list(self._alarms)

    def result(self) -> CalibrationResult:
        """The live estimate as a `CalibrationResult` (``method`` ``"auto+monitor"``).

        Live camera transform, marker-side translation and camera correction;
        the marker-side rotation and the noise levels of the arming result.
        Per-sample residuals are not kept.
        """
        ref = self.reference
        K = tf.make_transform(ref.K[:3, :3], self._u[:3])
        X, Y = model.join(self._C, K, ref.setup)
        sig = np.sqrt(np.diag(self._P)[9:12])
        base = ref.result.auto
        estimated = base.camera_correction if base is not None else {}
        correction = {name: CameraParameter(value=float(self._u[3 + i]), sigma=float(sig[i]),
                                            estimated=name in estimated and estimated[name].estimated)
                      for i, name in enumerate(model.CAMERA_PARAMS)}
        # The arming result's model, with the live camera correction; its notes were about the arming fit.
        details = None if base is None else dataclasses.replace(base, camera_correction=correction, notes=(),
                                                                blocked_folds=None)
        return CalibrationResult(method="auto+monitor", setup=ref.setup, X=X, Y=Y, n_samples=self._count,
                                 residuals=Residuals(translation=np.zeros(0)), cov=self.cov,
                                 marker_rotation_known=ref.result.marker_rotation_known, auto=details)
