"""Continuous hand-eye calibration from a stream of marker points, with a change detector.

The paper's point is that YKronT' needs only the marker center, so calibration
can run continuously while the robot works. This module makes it recursive:

- `OnlineCalibrator` buffers the first ``bootstrap`` samples, solves them with
  YKronT' (paper eq. 20) and refines them (`calib.refine`), then runs an
  extended Kalman filter (recursive least squares with forgetting, in
  covariance form) over the camera transform (6 dof)
  and the marker-side translation (3 dof) on the equation of translation
  (paper eq. 5) in the camera frame. Each update is a fixed amount of work
  on 9x9 matrices (constant time and memory); old information fades with the
  ``forgetting`` factor ``lambda`` (effective memory ``1 / (1 - lambda)``
  samples; 1 keeps everything).
- `ChangeDetector` tests, over sliding windows of the last ``window`` (20)
  and ``long_window`` (100) innovations (predicted before each sample is
  fused, so they are white with known covariance when nothing changed), the
  generalised likelihood ratio of "the camera moved by some 6-dof delta":
  ``g^T F^-1 g`` with ``F = sum H^T S^-1 H``, ``g = sum H^T S^-1 r``, which is
  chi-square with 6 dof before a change. It alarms above the
  ``1 - false_alarm_rate / 2`` quantile. The short window flags clear moves
  (1 cm, 0.5 deg about most axes) within a few samples; the long one catches
  moves the points barely show, such as a small rotation about the optical axis.

Setups: eye-to-hand (``X = T_flange_marker``, ``Y = T_base_cam``) and
eye-in-hand (``X = T_flange_cam``, ``Y = T_base_marker``); the "camera
transform" is ``Y`` resp. ``X``. Covariances follow `calib.result`.

Example (what ``handeye monitor`` does)::

    cal = OnlineCalibrator(OnlineConfig(setup="eye_to_hand", forgetting=0.999))
    for obs in stream:
        upd = cal.update(obs.T_base_flange, obs.point_cam, obs.point_cov)
        if upd.alarm:
            print("camera moved", upd.statistic)   # the filter restarts itself
    result = cal.result()                           # CalibrationResult, any time
"""

from __future__ import annotations

import math
from collections import deque
from typing import Annotated, NamedTuple

import numpy as np
from pydantic import Field, model_validator
from scipy.linalg.lapack import dposv
from scipy.stats import chi2

from calib import model
from calib import refine as rf
from calib import transforms as tf
from calib.errors import CalibrationError
from calib.noise import default_point_cov
from calib.result import CalibrationResult, Residuals
from calib.params import Bool, Float, Int, NonNegativeInt, Params
from calib.setup import Setup

_I3 = np.eye(3)
_I6 = np.eye(6)
#: The detector's long window is tested every this many samples.
LONG_STRIDE = 4


def _inv3(S):
    """Inverse of a symmetric 3x3 matrix (nested lists) by cofactors, as nested lists.

    Plain float arithmetic: at this size each numpy call costs more than the maths.
    """
    (a, b, c), (_, e, f), (_, _, i) = S
    c00, c01, c02 = e * i - f * f, c * f - b * i, b * f - c * e
    c11, c12, c22 = a * i - c * c, b * c - a * f, a * e - b * b
    k = 1.0 / (a * c00 + b * c01 + c * c02)
    return [[k * c00, k * c01, k * c02], [k * c01, k * c11, k * c12], [k * c02, k * c12, k * c22]]


def _exp(x, y, z):
    """Rodrigues' formula in scalars (nested lists); scipy's Rotation costs more than a whole filter update."""
    th = math.sqrt(x * x + y * y + z * z)
    if th < 1e-9:
        a, b = 1.0, 0.5
    else:
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / (th * th)
    return [
        [1.0 - b * (y * y + z * z), b * x * y - a * z, b * x * z + a * y],
        [b * x * y + a * z, 1.0 - b * (x * x + z * z), b * y * z - a * x],
        [b * x * z - a * y, b * y * z + a * x, 1.0 - b * (x * x + y * y)],
    ]


def _check_sample(T_base_flange, point_cam, point_cov):
    """Validate one sample; the per-sample budget (< 50 us) rules out the generic stack checks.

    Returns the arrays and ``T_base_flange`` as nested lists (the filter works on those).
    """
    A = np.asarray(T_base_flange, dtype=float)
    p = np.asarray(point_cam, dtype=float)
    if A.shape != (4, 4):
        raise CalibrationError(f"T_base_flange must have shape (4, 4), got {A.shape}")
    if p.shape != (3,):
        raise CalibrationError(f"point_cam must have shape (3,), got {p.shape}")
    # NaN/inf is caught by the caller: it propagates into the NIS (filter) or
    # the batch checks (bootstrap) before any state changes.
    a = A.tolist()
    (r00, r01, r02, _), (r10, r11, r12, _), (r20, r21, r22, _), last = a
    deviation = max(abs(r00 * r00 + r01 * r01 + r02 * r02 - 1.0), abs(r10 * r10 + r11 * r11 + r12 * r12 - 1.0),
                    abs(r20 * r20 + r21 * r21 + r22 * r22 - 1.0), abs(r00 * r10 + r01 * r11 + r02 * r12),
                    abs(r00 * r20 + r01 * r21 + r02 * r22), abs(r10 * r20 + r11 * r21 + r12 * r22))
    finite = math.isfinite(r00 + r01 + r02 + r10 + r11 + r12 + r20 + r21 + r22)
    if last != [0.0, 0.0, 0.0, 1.0] or (finite and deviation > 1e-5):
        raise CalibrationError("T_base_flange is not a rigid transform (rotation or last row)")
    if point_cov is None:
        return A, a, p, None
    S = np.asarray(point_cov, dtype=float)
    if S.shape != (3, 3):
        raise CalibrationError(f"point_cov must have shape (3, 3), got {S.shape}")
    (s00, s01, s02), (s10, s11, s12), (s20, s21, s22) = S.tolist()
    # The filter reads only the upper triangle, so check every entry here.
    if not math.isfinite(s00 + s01 + s02 + s10 + s11 + s12 + s20 + s21 + s22):
        raise CalibrationError("point_cov contains NaN or inf")
    if not min(s00, s11, s22) > 0:
        raise CalibrationError("point_cov must have a positive diagonal")
    return A, a, p, S


class DetectorConfig(Params):
    """Settings of `ChangeDetector`.

    Attributes
    ----------
    window : int
        Innovations in the short sliding GLR window (>= 3): reacts within a
        few samples to a clear move.
    long_window : int or None
        A second, longer window (> ``window``) for small moves the short one
        cannot resolve (e.g. a rotation about the optical axis); None disables it.
    false_alarm_rate : float
        Per-sample probability of a false alarm on an unchanged cell, in
        (0, 0.1), split evenly between the two windows.
    """

    window: Annotated[Int, Field(ge=3)] = 20
    long_window: Int | None = 100
    false_alarm_rate: Annotated[Float, Field(gt=0, lt=0.1)] = 1e-7

    @model_validator(mode="after")
    def _windows(self):
        if self.long_window is not None and self.long_window <= self.window:
            raise ValueError(f"long_window must be None or an int > window ({self.window}), got {self.long_window!r}")
        return self


class ChangeDetector:
    """Windowed GLR test for a 6-dof jump of the camera transform.

    Feed it the innovation ``r`` (3,) of each new point predicted from the
    current estimate, its inverse covariance ``S^-1`` (3, 3) and the Jacobian ``H`` (3, 6)
    of the predicted point w.r.t. the camera transform perturbation
    (`calib.result` convention). Over each window the statistic
    ``g^T F^-1 g`` is chi-square(6) while the camera stays put; a moved camera
    makes the innovations line up with ``H``. ``statistics`` holds the
    (short, long) window values, ``statistic`` the larger; both share one threshold.
    """

    def __init__(self, config: DetectorConfig | None = None):
        self.config = config or DetectorConfig()
        windows = 1 if self.config.long_window is None else 2
        self.threshold = float(chi2.ppf(1.0 - self.config.false_alarm_rate / windows, 6))
        # Running sums of the per-sample H^T S^-1 [H | . | r] (F = [:, :6], g = [:, -1]; the calibrator
        # fills the middle columns with marker-side terms the test ignores) over the last
        # size samples: a window sum is one difference, not an add and a subtract per window.
        # Unwritten slots are zero, i.e. the sum before the first sample.
        self._size = (self.config.long_window or self.config.window) + 1
        self._cum = np.zeros((self._size, 6, 10))
        self._Hr = np.zeros((3, 10))
        self.reset()

    @property
    def count(self) -> int:
        """Innovations since the last reset."""
        return self._count

    @property
    def state_size(self) -> int:
        """Floats held: the window's running sums."""
        return self._cum.size

    def reset(self) -> None:
        """Forget all innovations."""
        self._cum[:] = 0.0
        self._count = 0
        self.statistic = 0.0
        self.statistics = (0.0, 0.0)

    def update(self, r: np.ndarray, S_inv: np.ndarray, H: np.ndarray) -> bool:
        """Add one innovation ``r`` (3,) with inverse covariance ``S_inv`` (3, 3) and Jacobian ``H`` (3, 6).

        Returns True if a window's GLR statistic exceeds the threshold.
        """
        # [H^T S^-1 H | H^T S^-1 r] in one product.
        Hr = self._Hr
        Hr[:, :6] = H
        Hr[:, 9] = r
        return self._push(H.T @ S_inv @ Hr)

    def _push(self, Fg: np.ndarray) -> bool:
        """`update` from the sample's ``[H^T S^-1 H | . | H^T S^-1 r]`` (6, 10), which the calibrator builds itself."""
        cfg, n, size, cum = self.config, self._count, self._size, self._cum
        slot = n % size
        now = np.add(cum[slot - 1], Fg, out=cum[slot])        # slot - 1 = -1 wraps to the last slot
        self._count = n + 1
        if self._count < 3:
            # Two points cannot yet separate six pose parameters.
            return False
        short = _glr(now - cum[(n - cfg.window) % size])
        long = self.statistics[1]
        # The long window is for slow, small moves: testing it every LONG_STRIDE samples
        # delays those alarms a little and saves a 6x6 solve per sample.
        if cfg.long_window is not None and self._count > cfg.window and self._count % LONG_STRIDE == 0:
            long = _glr(now - cum[(n - cfg.long_window) % size])
        self.statistics = (short, long)
        self.statistic = max(short, long)
        return self.statistic > self.threshold


def _glr(Fg):
    """``g^T F^-1 g`` of a window sum ``[F | . | g]`` (6, 10)."""
    F = Fg[:, :6]
    g = Fg[:, 9]
    # A tiny ridge keeps a rank-deficient window (robot standing still) solvable;
    # g lies in the range of F then, so the statistic is unaffected.
    _, x, info = dposv(F + (1e-9 * (Fg.item(0, 0) + Fg.item(3, 3))) * _I6, g)
    return float(g.dot(x)) if info == 0 else 0.0


class OnlineConfig(Params):
    """Settings of `OnlineCalibrator`.

    Attributes
    ----------
    setup : {"eye_to_hand", "eye_in_hand"}
    forgetting : float
        Information decay per sample, in (0.9, 1]; 1 never forgets.
    bootstrap : int
        Samples solved in batch (YKronT' + ML) before the filter starts (>= 6).
    warmup : int
        Filter samples before the change detector starts (it needs a settled
        estimate to predict from).
    reset_on_alarm : bool
        Restart from scratch after an alarm, so the new camera pose is learnt
        from post-change samples only.
    detector : DetectorConfig
        Change-detector settings (default `DetectorConfig()`).
    """

    setup: Setup = Setup.EYE_TO_HAND
    forgetting: Annotated[Float, Field(gt=0.9, le=1.0)] = 1.0
    bootstrap: Annotated[Int, Field(ge=6)] = 10
    warmup: NonNegativeInt = 20
    reset_on_alarm: Bool = True
    detector: DetectorConfig = Field(default_factory=DetectorConfig)


class OnlineUpdate(NamedTuple):
    """What one `OnlineCalibrator.update` learnt (a NamedTuple: cheap to build at every sample).

    Attributes
    ----------
    n_samples : int
        Samples fused since the last reset (bootstrap included).
    camera_transform : ndarray (4, 4) or None
        ``T_base_cam`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand); None
        while bootstrapping.
    cov : ndarray (6, 6) or None
        Its covariance (`calib.result` convention).
    innovation : ndarray (3,) or None
        Measured minus predicted marker center in the camera frame, m, before fusing.
    nis : float or None
        Normalised innovation squared (chi-square, 3 dof, when consistent).
    statistic : float
        Change detector's GLR statistic (0 while it is not running).
    alarm : bool
        The camera (or the marker mount) moved: the detector fired.
    """

    n_samples: int
    camera_transform: np.ndarray | None
    cov: np.ndarray | None
    innovation: np.ndarray | None
    nis: float | None
    statistic: float
    alarm: bool


class OnlineCalibrator:
    """Recursive YKronT'-started ML calibration from marker points, with change detection.

    See the module docstring. State is O(1) in the number of samples: a
    bootstrap buffer of at most ``4 * bootstrap`` samples (used only until the
    first solve succeeds), the estimate, two 9x9 matrices, two
    scalars for the noise scale, and the detector's fixed window.
    """

    def __init__(self, config: OnlineConfig | None = None):
        self.config = config or OnlineConfig()
        self.detector = ChangeDetector(self.config.detector)
        self.reset()

    def reset(self) -> None:
        """Drop everything learnt; the next samples bootstrap again."""
        self._buffer = deque(maxlen=4 * self.config.bootstrap)
        # The estimate: columns of R_C, t_C and t_K as float tuples (the filter's arithmetic is on floats).
        self._cols = self._tC = self._tK = None
        self._P = None
        self._I2 = None
        self._n = 0
        self._filtered = 0
        self._scale_sum = 0.0
        self._scale_weight = 0.0
        self._given_cov = True
        self.detector.reset()

    @property
    def n_samples(self) -> int:
        """Samples fused since the last reset."""
        return self._n

    @property
    def state_size(self) -> int:
        """Floats held in the state (bounded, independent of the stream length)."""
        buf = len(self._buffer) * (16 + 3 + 9)
        return buf + (0 if self._P is None else 16 + 3 + 81 + 81) + self.detector._cum.size

    def _noise_scale(self) -> float:
        # Given covariances are trusted; the default model's scale comes from the NIS.
        if self._given_cov or self._scale_weight < 10.0:
            return 1.0
        return self._scale_sum / self._scale_weight

    def update(self, T_base_flange, point_cam, point_cov=None) -> OnlineUpdate:
        """Fuse one sample.

        Parameters
        ----------
        T_base_flange : array_like, shape (4, 4)
            Robot flange pose at the frame's time, m.
        point_cam : array_like, shape (3,)
            Marker center in the camera frame, m.
        point_cov : array_like, shape (3, 3), optional
            Its covariance, m^2; default: the depth model of `calib.noise`
            with its scale estimated from the innovations.

        Returns
        -------
        OnlineUpdate

        Raises
        ------
        CalibrationError
            Malformed input (the sample is not fused).
        """
        A, a, p, Sigma = _check_sample(T_base_flange, point_cam, point_cov)
        if Sigma is None:
            Sigma = default_point_cov(p[None])[0]
            self._given_cov = False
        if self._cols is None:
            return self._bootstrap(A, p, Sigma)
        return self._filter(a, p, Sigma)

    def _bootstrap(self, A, p, Sigma) -> OnlineUpdate:
        if not math.isfinite(float(A.sum() + p.sum() + Sigma.sum())):
            raise CalibrationError("T_base_flange, point_cam or point_cov contains NaN or inf")
        self._buffer.append((A, p, Sigma))
        self._n += 1
        if len(self._buffer) >= self.config.bootstrap:
            As = np.array([b[0] for b in self._buffer])
            ps = np.array([b[1] for b in self._buffer])
            covs = np.array([b[2] for b in self._buffer])
            try:
                self._start(As, ps, covs)
            except CalibrationError:
                # Degenerate motions so far: keep buffering (the deque drops the oldest).
                return OnlineUpdate(self._n, None, None, None, None, 0.0, False)
            self._buffer.clear()
            return OnlineUpdate(self._n, self.camera_transform, self.cov, None, None, 0.0, False)
        return OnlineUpdate(self._n, None, None, None, None, 0.0, False)

    def _start(self, As, ps, covs) -> None:
        """Filter state from a batch: YKronT' (paper eq. 20) + ML refinement, and its information."""
        # Imported here: calib.api imports this package's refine/robust lazily too.
        from calib.api import closed_form

        start = closed_form("YKronT'", As, ps, setup=self.config.setup)
        res = rf.refine(start, As, ps, point_cov=covs)
        C, K, M = model.split(res.X, res.Y, As, self.config.setup)
        problem = model.Problem(M, ps, model.whitener(covs))
        self._cols = [tuple(c) for c in C[:3, :3].T.tolist()]
        self._tC, self._tK = tuple(C[:3, 3].tolist()), tuple(K[:3, 3].tolist())
        info = model.information(problem, C, K)
        self._P = np.linalg.inv(info)
        self._I2 = info

    def arm(self, T_base_flange, points_cam, point_cov=None) -> OnlineUpdate:
        """Start from a reference calibration's samples, with the change detector armed at once.

        The reference samples are solved in one batch (YKronT' + ML
        refinement); the estimate and its information (covariance) become the
        filter state, and the warm-up is skipped: the reference batch already
        is a settled estimate, so the very next sample is tested.

        Parameters
        ----------
        T_base_flange : array_like, shape (N, 4, 4)
            Flange poses of the reference samples (N >= ``bootstrap``'s minimum of 6).
        points_cam : array_like, shape (N, 3)
            Their marker centers in the camera frame, m.
        point_cov : array_like, shape (N, 3, 3), optional
            Their covariances, m^2 (default: the depth model of `calib.noise`).

        Raises
        ------
        CalibrationError
            Malformed, too few or degenerate reference samples (the state is reset).
        """
        self.reset()
        samples = [_check_sample(A, p, None if point_cov is None else point_cov[i])
                   for i, (A, p) in enumerate(zip(T_base_flange, points_cam))]
        if len(samples) < 6:
            raise CalibrationError(f"a reference needs at least 6 samples, got {len(samples)}")
        As = np.array([s_[0] for s_ in samples])
        ps = np.array([s_[2] for s_ in samples])
        if point_cov is None:
            covs = default_point_cov(ps)
            self._given_cov = False
        else:
            covs = np.array([s_[3] for s_ in samples])
        try:
            self._start(As, ps, covs)
        except CalibrationError:
            self.reset()
            raise
        self._n = len(samples)
        self._filtered = self.config.warmup
        return OnlineUpdate(self._n, self.camera_transform, self.cov, None, None, 0.0, False)

    @property
    def samples_until_armed(self) -> int:
        """New samples before the change detector can fire (0: armed).

        Bootstrap, then warm-up, then the detector's first three innovations
        (two points cannot separate a 6-dof move); while bootstrapping this
        assumes the bootstrap solve succeeds.
        """
        warm = self.config.warmup + 2
        if self._cols is None:
            return max(self.config.bootstrap - len(self._buffer), 1) + warm
        return max(warm - self._filtered, 0)

    def _filter(self, a, p, Sigma) -> OnlineUpdate:
        # Covariance form of the information filter with forgetting (recursive
        # least squares): one 3x3 inverse per sample, no 9x9 solve. Each numpy
        # call costs a microsecond or more at this size, so everything 3x3 is
        # plain float arithmetic and numpy only sees the 9x9 products.
        cfg = self.config
        lam = cfg.forgetting
        (m00, m01, m02, m03), (m10, m11, m12, m13), (m20, m21, m22, m23) = a[0], a[1], a[2]
        if cfg.setup == Setup.EYE_TO_HAND:
            t0, t1, t2 = m03, m13, m23
        else:
            # M = A^-1: transpose the rotation in place of the names.
            m01, m02, m10, m12, m20, m21 = m10, m20, m01, m21, m02, m12
            t0 = -(m00 * m03 + m01 * m13 + m02 * m23)
            t1 = -(m10 * m03 + m11 * m13 + m12 * m23)
            t2 = -(m20 * m03 + m21 * m13 + m22 * m23)
        (k0, k1, k2), (u0, u1, u2) = self._tK, self._tC
        w0 = m00 * k0 + m01 * k1 + m02 * k2 + t0 - u0
        w1 = m10 * k0 + m11 * k1 + m12 * k2 + t1 - u1
        w2 = m20 * k0 + m21 * k1 + m22 * k2 + t2 - u2
        # Row j of d(predicted point)/d[dC, tC, tK] = R_C^T [[w]x, -I, R_M] (model.point_residuals)
        # is [c_j x w, -c_j, c_j^T R_M], c_j the j-th column of R_C; the innovation r_j ends the row.
        rows = []
        for (c0, c1, c2), pj in zip(self._cols, p.tolist()):
            rows += [c1 * w2 - c2 * w1, c2 * w0 - c0 * w2, c0 * w1 - c1 * w0, -c0, -c1, -c2,
                     c0 * m00 + c1 * m10 + c2 * m20, c0 * m01 + c1 * m11 + c2 * m21, c0 * m02 + c1 * m12 + c2 * m22,
                     pj - (c0 * w0 + c1 * w1 + c2 * w2)]
        r0, r1, r2 = rows[9], rows[19], rows[29]
        Jr = np.array(rows).reshape(3, 10)               # [H (camera) | J_tK | r]
        J, r = Jr[:, :9], Jr[:, 9]
        P = self._P if lam == 1.0 else self._P / lam
        JP = J.dot(P)
        (q00, q01, q02), (_, q11, q12), (_, _, q22) = JP.dot(J.T).tolist()
        (s00, s01, s02), (_, s11, s12), (_, _, s22) = Sigma.tolist()
        K_inv = _inv3(((s00 + q00, s01 + q01, s02 + q02), (0, s11 + q11, s12 + q12), (0, 0, s22 + q22)))
        # The prediction uses the information before forgetting (lam * P).
        if lam == 1.0:
            S_inv = K_inv
        else:
            S_inv = _inv3(((s00 + lam * q00, s01 + lam * q01, s02 + lam * q02), (0, s11 + lam * q11, s12 + lam * q12),
                           (0, 0, s22 + lam * q22)))
        scale = self._noise_scale()
        if scale != 1.0:
            S_inv = [[v / scale for v in row] for row in S_inv]
        (a00, a01, a02), (_, a11, a12), (_, _, a22) = S_inv
        nis = (a00 * r0 * r0 + a11 * r1 * r1 + a22 * r2 * r2
               + 2.0 * (a01 * r0 * r1 + a02 * r0 * r2 + a12 * r1 * r2))
        if not math.isfinite(nis):
            raise CalibrationError("T_base_flange, point_cam or point_cov contains NaN or inf")
        if not self._given_cov:
            # NIS at unit scale, so the estimate does not feed back on itself.
            self._scale_sum = lam * self._scale_sum + nis * scale
            self._scale_weight = lam * self._scale_weight + 3.0

        alarm = False
        statistic = 0.0
        K_inv = np.array(K_inv)
        if self._filtered >= cfg.warmup:
            # H^T S^-1 [H | J_tK | r]: the detector reads [F | g] from its first 6 and last columns.
            S_inv = K_inv if S_inv is K_inv else np.array(S_inv)
            alarm = self.detector._push(Jr[:, :6].T.dot(S_inv.dot(Jr)))
            statistic = self.detector.statistic

        K = JP.T.dot(K_inv)
        P -= K.dot(JP)                                   # in place: P is self._P or a fresh P / lam
        if self._filtered % 64 == 0:
            # Rounding slowly breaks the symmetry of the rank-3 downdates.
            P = 0.5 * (P + P.T)
        self._P = P
        if lam != 1.0:
            # Information weighted by lam^2: the sandwich P I2 P is the error covariance of
            # the exponentially weighted estimate of a constant camera (P alone is ~2x too big).
            self._I2 *= lam * lam
            self._I2 += J.T.dot(np.array(_inv3(Sigma.tolist())).dot(J))
        d0, d1, d2, d3, d4, d5, d6, d7, d8 = K.dot(r).tolist()
        (e00, e01, e02), (e10, e11, e12), (e20, e21, e22) = _exp(d0, d1, d2)
        # R_C <- Exp(d) R_C, column by column.
        self._cols = [(e00 * c0 + e01 * c1 + e02 * c2, e10 * c0 + e11 * c1 + e12 * c2, e20 * c0 + e21 * c1 + e22 * c2)
                      for c0, c1, c2 in self._cols]
        self._tC = (u0 + d3, u1 + d4, u2 + d5)
        self._tK = (k0 + d6, k1 + d7, k2 + d8)
        self._n += 1
        self._filtered += 1
        upd = OnlineUpdate(self._n, self.camera_transform, self.cov, r, nis, statistic, alarm)
        if alarm and cfg.reset_on_alarm:
            self.reset()
        return upd

    @property
    def camera_transform(self) -> np.ndarray | None:
        """``T_base_cam`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand), or None while bootstrapping."""
        if self._cols is None:
            return None
        (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = self._cols
        t0, t1, t2 = self._tC
        return np.array(((a0, b0, c0, t0), (a1, b1, c1, t1), (a2, b2, c2, t2), (0.0, 0.0, 0.0, 1.0)))

    @property
    def cov(self) -> np.ndarray | None:
        """Covariance (6, 6) of the camera transform, marker translation marginalised."""
        if self._P is None:
            return None
        if self.config.forgetting == 1.0:
            return self._noise_scale() * self._P[:6, :6]
        P6 = self._P[:6].dot(self._I2).dot(self._P[:, :6])
        return self._noise_scale() * 0.5 * (P6 + P6.T)

    def result(self) -> CalibrationResult | None:
        """The current estimate as a `CalibrationResult` (method ``"YKronT'+online"``), or None.

        The marker-side rotation is unknown (identity, ``marker_rotation_known``
        False); per-sample residuals are not kept, so ``residuals`` is empty.
        """
        if self._cols is None:
            return None
        K = tf.make_transform(_I3, np.array(self._tK))
        X, Y = model.join(self.camera_transform, K, self.config.setup)
        return CalibrationResult(
            method="YKronT'+online",
            setup=self.config.setup,
            X=X,
            Y=Y,
            n_samples=self._n,
            residuals=Residuals(translation=np.zeros(0)),
            cov=self.cov,
            marker_rotation_known=False,
            info={"forgetting": self.config.forgetting, "noise_scale": self._noise_scale()},
        )
