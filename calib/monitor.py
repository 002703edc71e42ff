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
   point's change from the stop's earlier visits instead.
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
from dataclasses import dataclass, field
from typing import Annotated, NamedTuple

import numpy as np
from pydantic import Field
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from calib import model
from calib import transforms as tf
from calib.errors import CalibrationError
from calib.noise import default_point_cov
from calib.change import ChangeDetector, DetectorConfig
from calib.params import NonNegativeFloat, Params, PositiveFloat
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
    A: np.ndarray
    p: np.ndarray
    shape: np.ndarray
    factor: np.ndarray | None
    t: float


@dataclass
class _Visit:
    """A sample in the detector's window and the filter state before it was fused."""

    sample: _Stop
    state: tuple


@dataclass
class _Baseline:
    """A production stop's typical measured marker point (running mean over its last visits, camera frame)."""

    A: np.ndarray
    mean: np.ndarray
    n: float


@dataclass
class _Rate:
    """Exponentially weighted least-squares slope of a vector against time (running sums: O(1))."""

    tau_s: float
    t0: float | None = None
    t_last: float = 0.0
    sums: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ty: np.ndarray | None = None

    def add(self, t: float, y: np.ndarray) -> None:
        if self.t0 is None:
            self.t0, self.ty = t, np.zeros((2, len(y)))
        decay = math.exp(-(t - self.t_last) / self.tau_s) if self.sums[0] else 1.0
        x = (t - self.t0) / HOUR_S
        self.sums = self.sums * decay + (1.0, x, x * x)
        self.ty = self.ty * decay + (y, x * y)
        self.t_last = t

    def slope(self) -> np.ndarray | None:
        """Per hour, or None before the regression spans `RATE_MIN_SPAN` of its window."""
        if self.t0 is None or self.t_last - self.t0 < RATE_MIN_SPAN * self.tau_s:
            return None
        s0, s1, s2 = self.sums
        den = s0 * s2 - s1 * s1
        if den <= 0:
            return None
        return (s0 * self.ty[1] - s1 * self.ty[0]) / den

    def reset(self) -> None:
        self.t0, self.sums, self.ty = None, np.zeros(3), None


def arm_reference(result: CalibrationResult, A, points, *, point_cov=None, robot_factor=None,
                  consider_theta=None) -> tuple[Reference, np.ndarray]:
    """The calibration in use and the covariance of the engine's state, from a result and its samples.

    The state is ``[dC, tC, t_K, theta, z]``: the camera transform (left
    perturbation, `calib.result`), the marker-side translation, the camera
    parameters (`calib.model.CAMERA_PARAMS`) and, with ``robot_factor``, the P
    kinematic-error parameters all samples share (unit variance). Its
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
    A : array_like, shape (N, 4, 4)
        ``T_base_flange`` of the samples it was solved from.
    points : array_like, shape (N, 3)
        Their marker centers in the camera frame, m (as measured).
    point_cov : array_like, shape (N, 3, 3), optional
        Their covariance shapes, m^2 (default: `calib.noise`'s depth model).
    robot_factor : array_like, shape (N, 6, P), optional
        The kinematic-error factor at their joints (``robot_shared_error`` of `calib.auto`).

    Returns
    -------
    reference : Reference
    cov : ndarray (12 + P, 12 + P)

    Raises
    ------
    CalibrationError
        Malformed samples, or samples that do not determine the camera.
    """
    from calib.auto import CONSIDER_SIGMA

    setup = Setup(result.setup)
    A = tf.check_transforms(A, "A")
    p = tf.check_points(points, "points")
    if len(p) != len(A):
        raise CalibrationError(f"points must have one row per pose ({len(A)}), got {len(p)}")
    C, K, M = model.split(result.X, result.Y, A, setup)
    theta = result.camera_correction.as_array()
    levels = result.auto.noise if result.auto is not None else model.NoiseLevels()
    # Held-out samples predicted worse than the model expects (auto's self-check): the noise levels were
    # fitted too closely, so they are widened by that ratio (never narrowed).
    ratio = result.self_check.loo_ratio if result.self_check is not None else 1.0
    widen = max(1.0, float(ratio or 1.0)) ** 2
    noise = model.NoiseLevels(levels.point_scale * widen, levels.robot * math.sqrt(widen))
    shape, _ = model.point_shape(p, point_cov)
    _, H_C, H_tK, H_th, H_xi = model.point_jacobians(C, K, M, theta, setup)
    W = np.linalg.inv(noise.point_cov(shape, model.robot_cofactor(C, K, M, setup)))
    J = np.concatenate([H_C, H_tK, H_th], axis=2)                     # (N, 3, 12)
    N = np.einsum("nki,nkl,nlj->ij", J, W, J)
    correction = result.auto.camera_correction if result.auto is not None else {}
    consider = CONSIDER_SIGMA if consider_theta is None else consider_theta
    for i, name in enumerate(model.CAMERA_PARAMS):
        if not (name in correction and correction[name].estimated):
            N[9 + i, 9 + i] += 1.0 / consider[name] ** 2
    try:
        cov = np.linalg.inv(N)
    except np.linalg.LinAlgError:
        raise CalibrationError("the reference samples do not determine the camera transform") from None
    if robot_factor is not None:
        F = tf.as_real_array(robot_factor, "robot_factor")
        if F.ndim != 3 or F.shape[:2] != (len(A), 6):
            raise CalibrationError(f"robot_factor must have shape ({len(A)}, 6, P), got {F.shape}")
        # The estimate's error from a shared error z ~ N(0, I): -N^-1 J^T W H_z z.
        G = -cov @ np.einsum("nki,nkl,nlj->ij", J, W, H_xi @ F)
        cov = np.block([[cov + G @ G.T, G], [G.T, np.eye(F.shape[2])]])
    cov = 0.5 * (cov + cov.T)
    q = model.CameraCorrection(*theta).correct(p)
    ref = Reference(setup, C.copy(), K.copy(), theta, noise, q[::max(1, len(q) // WORKSPACE_POINTS)], 0.0, result)
    ref.sigma_mm = workspace_sigma(C, theta, ref.workspace, cov) * 1e3
    return ref, cov


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


def workspace_displacement(C1, C2, points) -> np.ndarray:
    """``C1 p - C2 p`` (W, 3), m, for camera-frame ``points`` (W, 3)."""
    return points @ (C1[:3, :3] - C2[:3, :3]).T + (C1[:3, 3] - C2[:3, 3])


def workspace_distance(C1, C2, points) -> float:
    """RMS distance (m) between where two camera transforms put camera-frame ``points`` (W, 3)."""
    d = workspace_displacement(C1, C2, points)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


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

    def arm(self, result: CalibrationResult, A, points, *, point_cov=None, robot_factor=None,
            t: float = 0.0) -> Reference:
        """Arm from a calibration and its samples (`arm_reference`); the next sample is tested at once.

        ``t`` is the time the calibration holds for (s, the samples' clock).
        Returns the calibration in use (its ``sigma_mm``: 1-sigma over the workspace).

        Raises
        ------
        CalibrationError
            The samples are malformed or do not determine the camera.
        """
        ref, cov = arm_reference(result, A, points, point_cov=point_cov, robot_factor=robot_factor)
        self.reference = ref
        self._C = ref.C.copy()
        self._u = np.r_[ref.K[:3, 3], ref.theta, np.zeros(len(cov) - 12)]
        self._P = cov
        self._t = float(t)
        self._count = 0
        self._window: list[_Visit] = []
        self._baselines: list[_Baseline] = []
        self._relearn_set: list[_Stop] = []
        self._rate = _Rate(self.settings.rate_window_h * HOUR_S)
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
                + (per_sample + 3 + state) * len(self._window) + 19 * len(self._baselines))

    # ------------------------------------------------------------------ the filter

    def _linearize(self, C, u, s: _Stop):
        """Innovation ``r`` (3,), Jacobian ``H`` (3, n) of the predicted point w.r.t. the state, noise ``R`` (3, 3)."""
        ref = self.reference
        K = tf.make_transform(ref.K[:3, :3], u[:3])
        A = s.A
        if self.n_factor:
            w = s.factor @ u[6:]
            A = A @ tf.from_rotvec_translation(w[:3], w[3:])
        M = A[None] if ref.setup == Setup.EYE_TO_HAND else tf.invert(A)[None]
        h, H_C, H_tK, H_th, H_xi = model.point_jacobians(C, K, M, u[3:6], ref.setup)
        H = [H_C[0], H_tK[0], H_th[0]]
        if self.n_factor:
            H.append(H_xi[0] @ s.factor)
        R = self._noise_scale * ref.noise.point_cov(s.shape[None], model.robot_cofactor(C, K, M, ref.setup))[0]
        return s.p - h[0], np.concatenate(H, axis=1), R

    def _walk(self, hours: float) -> np.ndarray:
        """Covariance (6, 6) the random walk adds to the camera transform in ``hours``."""
        st = self.settings.walk_mm_per_sqrt_h * 1e-3
        sr = np.deg2rad(self.settings.walk_deg_per_sqrt_h)
        return np.diag([sr * sr] * 3 + [st * st] * 3) * hours

    def _predict(self, t: float) -> None:
        if t > self._t:
            self._P[:6, :6] += self._walk((t - self._t) / HOUR_S)
        self._t = max(t, self._t)

    def _fuse(self, r, H, R) -> None:
        """Kalman update of the whole state."""
        PHt = self._P @ H.T
        Kg = np.linalg.solve(H @ PHt + R, PHt.T).T
        self._P = self._P - Kg @ PHt.T
        self._P = 0.5 * (self._P + self._P.T)
        d = Kg @ r
        self._C = tf.make_transform(tf.so3_exp(d[:3]) @ self._C[:3, :3], self._C[:3, 3] + d[3:6])
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
        S = H @ self._P @ H.T + R
        nis = float(r @ np.linalg.solve(S, r))
        if not self._moved and nis < NIS_GATE:
            # The arming noise levels come from a few dozen samples: their scale follows the innovations
            # (a running mean of the NIS at unit scale, with the arming's level worth NOISE_SCALE_PRIOR samples).
            keep = 1.0 - 1.0 / NOISE_SCALE_SAMPLES
            self._scale_sum = keep * self._scale_sum + nis * self._noise_scale / 3.0
            self._scale_n = keep * self._scale_n + 1.0
            self._noise_scale = min(max((NOISE_SCALE_PRIOR + self._scale_sum) / (NOISE_SCALE_PRIOR + self._scale_n),
                                        NOISE_SCALE_RANGE[0]), NOISE_SCALE_RANGE[1])
        verify = float(np.linalg.norm(self._C[:3, :3] @ r)) * 1e3
        alarm, message, statistic = "", "", 0.0
        if self._moved:
            self._relearn_set.append(s)
            del self._relearn_set[:-self.settings.relearn_samples]
            message = self._relearn()
        else:
            base = self._baseline(s.A)
            if base is not None and base.n >= MIN_BASELINE:
                # Against the stop's own earlier visits: what they share (unmodelled errors of the robot or the
                # camera at that pose, the estimate's own error) is no change; only the camera moving is.
                Hc = H[:, :6]
                r_test = s.p - base.mean
                S_test = R * (1.0 + 1.0 / base.n) + Hc @ self._walk(self.settings.rate_window_h) @ Hc.T
            else:
                r_test, S_test = r, S
            # While a re-learnt camera settles the stops still refine it: that is not a move.
            fired = not self._settle and self.detector.update(r_test, np.linalg.inv(S_test), H[:, :6])
            statistic = self.detector.statistic
            if fired:
                alarm = "moved"
                message = (f"camera moved (GLR statistic {statistic:.1f} > {self.detector.threshold:.1f}); "
                           "re-learning it from the production stops")
                # The move lies inside the window: go back to the state before it, re-learn from its samples.
                if self._window:
                    self._restore(self._window[0].state)
                self._relearn_set = [v.sample for v in self._window] + [s]
                self._window = []
                self._moved = True
                self._drifting = False
                message += "; " + self._relearn()
            else:
                self._window.append(_Visit(s, (self._C, self._u, self._P)))
                self._fuse(r, H, R)
                if len(self._window) > self.settings.detector.window:
                    old = self._window.pop(0)
                    self._add_baseline(old.sample)
        if self._moved:
            state = "relearning"
        elif self._settle:
            # Just re-learnt: what the next stops add refines that calibration, it is no drift.
            self._settle -= 1
            self.reference.C, self.reference.theta = self._C.copy(), self._u[3:6].copy()
            self.reference.sigma_mm = workspace_sigma(self._C, self._u[3:6], self.reference.workspace, self._P) * 1e3
            state = "settling"
        else:
            state = "armed" if self.detector.count >= 3 else "warming"
        return self._figures(s, state, alarm, message, r, nis, verify, statistic)

    def _sample(self, t, T_base_flange, point_cam, point_cov, robot_factor) -> _Stop:
        if self.reference is None:
            raise CalibrationError("the monitoring engine is not armed: give it a calibration result first")
        A = tf.check_transform(T_base_flange, "T_base_flange")
        p = tf.check_points(np.asarray(point_cam, dtype=float).reshape(1, -1), "point_cam")[0]
        shape = default_point_cov(p[None])[0] if point_cov is None else model.check_point_cov(point_cov, 1)[0]
        factor = None
        if self.n_factor:
            if robot_factor is None:
                raise CalibrationError("the engine was armed with the robot's kinematic error: every sample "
                                       "needs its robot_factor (6, P)")
            factor = tf.as_real_array(robot_factor, "robot_factor")
            if factor.shape != (6, self.n_factor):
                raise CalibrationError(f"robot_factor must have shape (6, {self.n_factor}), got {factor.shape}")
        if not math.isfinite(t) or t < self._t - 1e-9:
            raise CalibrationError(f"t must be finite and not before the previous sample's ({self._t}), got {t}")
        return _Stop(A, p, shape, factor, float(t))

    # ------------------------------------------------------------------ stops

    def _same_stop(self, A1, A2) -> bool:
        """Two flange poses closer than `MonitorSettings.stop_translation_m` and ``stop_rotation_deg``."""
        rot, trans = tf.pose_error(A1, A2)
        return bool(trans < self.settings.stop_translation_m and rot < np.deg2rad(self.settings.stop_rotation_deg))

    def _stop_index(self, A) -> int | None:
        for i, b in enumerate(self._baselines):
            if self._same_stop(b.A, A):
                return i
        return None

    def _baseline(self, A) -> _Baseline | None:
        i = self._stop_index(A)
        return None if i is None else self._baselines[i]

    def _add_baseline(self, s: _Stop) -> None:
        """Fold a sample's marker point into its stop's running mean (the most recent stops kept, `MAX_STOPS`)."""
        i = self._stop_index(s.A)
        if i is None:
            b = _Baseline(s.A, np.zeros(3), 0.0)
        else:
            b = self._baselines.pop(i)
        b.n = min(b.n + 1.0, BASELINE_VISITS)
        b.mean = b.mean + (s.p - b.mean) / b.n
        self._baselines.append(b)
        del self._baselines[:-MAX_STOPS]

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
        sigma_mm = workspace_sigma(C, self._u[3:6], self.reference.workspace, P) * 1e3
        if how == "registered" and sigma_mm > self.settings.tolerance_mm:
            return (f"re-learning: registered from {len(samples)} samples, but its 1-sigma over the workspace is "
                    f"{sigma_mm:.1f} mm (tolerance {self.settings.tolerance_mm:g} mm): waiting for more stops, "
                    "spread across the workspace")
        ref = self.reference
        moved_mm = workspace_distance(C, self._C, ref.workspace) * 1e3
        moved_deg = float(np.rad2deg(tf.rotation_angle(C[:3, :3] @ self._C[:3, :3].T)))
        self._baselines = []       # the stops' marker points as the old camera saw them
        self._C, self._P = C, P
        ref.C, ref.theta = C.copy(), self._u[3:6].copy()
        ref.sigma_mm = workspace_sigma(C, ref.theta, ref.workspace, P) * 1e3
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
        rows = []
        for s in samples:
            b = self._baseline(s.A)
            if b is None or b.n < MIN_BASELINE:
                continue
            _, H, R = self._linearize(self._C, self._u, s)
            rows.append((s.p - b.mean, H[:, :6], np.linalg.inv(R * (1.0 + 1.0 / b.n))))
        if len(self._distinct([s for s in samples if self._baseline(s.A) is not None])) < 3:
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
        moved = workspace_displacement(self._C, ref.C, ref.workspace)
        drift_m = float(np.sqrt(np.mean(np.sum(moved * moved, axis=1))))
        drift_deg = float(np.rad2deg(tf.rotation_angle(self._C[:3, :3] @ ref.C[:3, :3].T)))
        sigma = workspace_sigma(self._C, self._u[3:6], ref.workspace, self._P)
        error_mm = math.hypot(drift_m * 1e3, ref.sigma_mm)
        rate_mm = rate_deg = hours = None
        if state == "armed":
            # The displacement of every workspace point is linear in the drift: its slope is the drift rate.
            self._rate.add(s.t, np.r_[moved.ravel(), drift_deg, drift_m])
            slope = self._rate.slope()
            if slope is not None:
                rate_mm = float(np.sqrt(np.mean(np.sum(slope[:-2].reshape(-1, 3) ** 2, axis=1)))) * 1e3
                rate_deg = abs(float(slope[-2]))
                growth = slope[-1] * 1e3
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
        return MonitorUpdate(self._count, s.t, state, alarm, level, self._C.copy(), self.cov, r, nis, verify, statistic,
                             drift_m * 1e3, drift_deg, rate_mm, rate_deg, error_mm, hours, sigma * 1e3, message)

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
