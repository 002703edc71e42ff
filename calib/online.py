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
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.linalg.lapack import dposv
from scipy.stats import chi2

from calib import refine as rf
from calib import transforms as tf
from calib.errors import CalibrationError, ConfigError
from calib.noise import default_point_cov
from calib.observation import SETUPS
from calib.result import CalibrationResult, Residuals

_I3 = np.eye(3)
_I6 = np.eye(6)
#: The detector's long window is tested every this many samples.
LONG_STRIDE = 4


def _inv3(S):
    """Inverse of a 3x3 matrix by cofactors (np.linalg.inv's overhead dominates at this size)."""
    (a, b, c), (d, e, f), (g, h, i) = S.tolist()
    co = np.array([[e * i - f * h, c * h - b * i, b * f - c * e],
                   [f * g - d * i, a * i - c * g, c * d - a * f],
                   [d * h - e * g, b * g - a * h, a * e - b * d]])
    return co / (a * co[0, 0] + b * co[1, 0] + c * co[2, 0])


def _exp(v):
    """Rodrigues' formula in scalars; scipy's Rotation costs more than a whole filter update."""
    x, y, z = v.tolist()
    th = math.sqrt(x * x + y * y + z * z)
    if th < 1e-9:
        a, b = 1.0, 0.5
    else:
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / (th * th)
    return np.array([
        [1.0 - b * (y * y + z * z), b * x * y - a * z, b * x * z + a * y],
        [b * x * y + a * z, 1.0 - b * (x * x + z * z), b * y * z - a * x],
        [b * x * z - a * y, b * y * z + a * x, 1.0 - b * (x * x + y * y)],
    ])


def _check_sample(T_base_flange, point_cam, point_cov):
    """Validate one sample; the per-sample budget (< 50 us) rules out the generic stack checks."""
    A = np.asarray(T_base_flange, dtype=float)
    p = np.asarray(point_cam, dtype=float)
    if A.shape != (4, 4):
        raise CalibrationError(f"T_base_flange must have shape (4, 4), got {A.shape}")
    if p.shape != (3,):
        raise CalibrationError(f"point_cam must have shape (3,), got {p.shape}")
    # NaN/inf is caught by the caller: it propagates into the NIS (filter) or
    # the batch checks (bootstrap) before any state changes.
    R = A[:3, :3]
    if A[3].tolist() != [0.0, 0.0, 0.0, 1.0] or np.abs(R @ R.T - _I3).max() > 1e-5:
        raise CalibrationError("T_base_flange is not a rigid transform (rotation or last row)")
    if point_cov is None:
        return A, p, None
    S = np.asarray(point_cov, dtype=float)
    if S.shape != (3, 3):
        raise CalibrationError(f"point_cov must have shape (3, 3), got {S.shape}")
    if not min(S[0, 0], S[1, 1], S[2, 2]) > 0:
        raise CalibrationError("point_cov must have a positive diagonal")
    return A, p, S


@dataclass
class DetectorConfig:
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

    window: int = 20
    long_window: int | None = 100
    false_alarm_rate: float = 1e-7

    def __post_init__(self):
        if not isinstance(self.window, int) or self.window < 3:
            raise ConfigError(f"window must be an int >= 3, got {self.window!r}")
        if self.long_window is not None and (not isinstance(self.long_window, int) or self.long_window <= self.window):
            raise ConfigError(f"long_window must be None or an int > window ({self.window}), got {self.long_window!r}")
        if not 0.0 < self.false_alarm_rate < 0.1:
            raise ConfigError(f"false_alarm_rate must be in (0, 0.1), got {self.false_alarm_rate!r}")


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
        self._size = self.config.long_window or self.config.window
        self._Fg = np.zeros((self._size, 6, 7))
        self._Hr = np.empty((3, 7))
        self.reset()

    def reset(self) -> None:
        """Forget all innovations."""
        self._Fg[:] = 0.0
        self._short = np.zeros((6, 7))
        self._long = np.zeros((6, 7))
        self._count = 0
        self.statistic = 0.0
        self.statistics = (0.0, 0.0)

    def update(self, r: np.ndarray, S_inv: np.ndarray, H: np.ndarray) -> bool:
        """Add one innovation ``r`` (3,) with inverse covariance ``S_inv`` (3, 3) and Jacobian ``H`` (3, 6).

        Returns True if a window's GLR statistic exceeds the threshold.
        """
        # [H^T S^-1 H | H^T S^-1 r] in one product; window sums are kept by
        # adding the newest and subtracting the one that leaves the window.
        Hr = self._Hr
        Hr[:, :6] = H
        Hr[:, 6] = r
        Fg = H.T @ S_inv @ Hr
        cfg, n, size = self.config, self._count, self._size
        self._short += Fg - self._Fg[(n - cfg.window) % size] if n >= cfg.window else Fg
        if cfg.long_window is not None:
            self._long += Fg - self._Fg[n % size]
        self._Fg[n % size] = Fg
        self._count = n + 1
        if self._count < 3:
            # Two points cannot yet separate six pose parameters.
            return False
        short = _glr(self._short)
        long = self.statistics[1]
        # The long window is for slow, small moves: testing it every LONG_STRIDE samples
        # delays those alarms a little and saves a 6x6 solve per sample.
        if cfg.long_window is not None and self._count > cfg.window and self._count % LONG_STRIDE == 0:
            long = _glr(self._long)
        self.statistics = (short, long)
        self.statistic = max(short, long)
        return self.statistic > self.threshold


def _glr(Fg):
    """``g^T F^-1 g`` of a window sum ``[F | g]`` (6, 7)."""
    F = Fg[:, :6]
    g = Fg[:, 6]
    # A tiny ridge keeps a rank-deficient window (robot standing still) solvable;
    # g lies in the range of F then, so the statistic is unaffected.
    _, x, info = dposv(F + (1e-9 * (F[0, 0] + F[3, 3])) * _I6, g)
    return float(g @ x) if info == 0 else 0.0


@dataclass
class OnlineConfig:
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
    detector : DetectorConfig, optional
        Change-detector settings (default `DetectorConfig()`).
    """

    setup: str = "eye_to_hand"
    forgetting: float = 1.0
    bootstrap: int = 10
    warmup: int = 20
    reset_on_alarm: bool = True
    detector: DetectorConfig | None = None

    def __post_init__(self):
        if self.setup not in SETUPS:
            raise ConfigError(f"setup must be one of {SETUPS}, got {self.setup!r}")
        if not 0.9 < self.forgetting <= 1.0:
            raise ConfigError(f"forgetting must be in (0.9, 1], got {self.forgetting!r}")
        if not isinstance(self.bootstrap, int) or self.bootstrap < 6:
            raise ConfigError(f"bootstrap must be an int >= 6, got {self.bootstrap!r}")
        if not isinstance(self.warmup, int) or self.warmup < 0:
            raise ConfigError(f"warmup must be an int >= 0, got {self.warmup!r}")
        if self.detector is None:
            self.detector = DetectorConfig()


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
        self._C = None
        self._tK = None
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
        return buf + (0 if self._P is None else 16 + 3 + 81 + 81) + self.detector._Fg.size + 2 * 42

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
        A, p, Sigma = _check_sample(T_base_flange, point_cam, point_cov)
        if Sigma is None:
            Sigma = default_point_cov(p[None])[0]
            self._given_cov = False
        if self._C is None:
            return self._bootstrap(A, p, Sigma)
        return self._filter(A, p, Sigma)

    def _bootstrap(self, A, p, Sigma) -> OnlineUpdate:
        if not math.isfinite(float(A.sum() + p.sum() + Sigma.sum())):
            raise CalibrationError("T_base_flange, point_cam or point_cov contains NaN or inf")
        self._buffer.append((A, p, Sigma))
        self._n += 1
        if len(self._buffer) >= self.config.bootstrap:
            As = np.array([b[0] for b in self._buffer])
            ps = np.array([b[1] for b in self._buffer])
            covs = np.array([b[2] for b in self._buffer])
            # Imported here: calib.api imports this package's refine/robust lazily too.
            from calib.api import closed_form

            try:
                start = closed_form("YKronT'", As, ps, setup=self.config.setup)
                res = rf.refine(start, As, ps, point_cov=covs)
            except CalibrationError:
                # Degenerate motions so far: keep buffering (the deque drops the oldest).
                return OnlineUpdate(self._n, None, None, None, None, 0.0, False)
            C, K, M = rf._split(res.X, res.Y, As, self.config.setup)
            problem = rf._Problem(M, ps, rf._whitener(covs))
            self._C, self._tK = C, K[:3, 3].copy()
            info = rf._information(problem, C, K)
            self._P = np.linalg.inv(info)
            self._I2 = info
            self._buffer.clear()
            return OnlineUpdate(self._n, self._C.copy(), self.cov, None, None, 0.0, False)
        return OnlineUpdate(self._n, None, None, None, None, 0.0, False)

    def _filter(self, A, p, Sigma) -> OnlineUpdate:
        # Covariance form of the information filter with forgetting (recursive
        # least squares): one 3x3 inverse per sample, no 9x9 solve. Written for
        # few numpy calls, since each costs about a microsecond at this size.
        cfg = self.config
        lam = cfg.forgetting
        if cfg.setup == "eye_to_hand":
            R_M, t_M = A[:3, :3], A[:3, 3]
        else:
            R_M = A[:3, :3].T
            t_M = -R_M @ A[:3, 3]
        R_C, t_C = self._C[:3, :3], self._C[:3, 3]
        RCt = R_C.T
        w = R_M @ self._tK + (t_M - t_C)
        r = p - RCt @ w
        x, y, z = w.tolist()
        # d(predicted point)/d[dC, tC, tK] = R_C^T [ [w]x, -I, R_M ]  (refine._point_residuals)
        G = np.array([[0.0, -z, y, -1.0, 0.0, 0.0], [z, 0.0, -x, 0.0, -1.0, 0.0], [-y, x, 0.0, 0.0, 0.0, -1.0]])
        J = RCt @ np.concatenate((G, R_M), axis=1)
        P = self._P if lam == 1.0 else self._P / lam
        JP = J @ P
        JPJ = JP @ J.T
        K_inv = _inv3(Sigma + JPJ)
        # The prediction uses the information before forgetting (lam * P).
        S_inv = K_inv if lam == 1.0 else _inv3(Sigma + lam * JPJ)
        scale = self._noise_scale()
        if scale != 1.0:
            S_inv = S_inv / scale
        nis = float(r @ S_inv @ r)
        if not math.isfinite(nis):
            raise CalibrationError("T_base_flange, point_cam or point_cov contains NaN or inf")
        if not self._given_cov:
            # NIS at unit scale, so the estimate does not feed back on itself.
            self._scale_sum = lam * self._scale_sum + nis * scale
            self._scale_weight = lam * self._scale_weight + 3.0

        alarm = False
        statistic = 0.0
        if self._filtered >= cfg.warmup:
            alarm = self.detector.update(r, S_inv, J[:, :6])
            statistic = self.detector.statistic

        K = JP.T @ K_inv
        P = P - K @ JP
        if self._filtered % 64 == 0:
            # Rounding slowly breaks the symmetry of the rank-3 downdates.
            P = 0.5 * (P + P.T)
        self._P = P
        if lam != 1.0:
            # Information weighted by lam^2: the sandwich P I2 P is the error covariance of
            # the exponentially weighted estimate of a constant camera (P alone is ~2x too big).
            self._I2 = (lam * lam) * self._I2 + J.T @ _inv3(Sigma) @ J
        delta = K @ r
        C = np.empty((4, 4))
        C[:3, :3] = _exp(delta[:3]) @ R_C
        C[:3, 3] = t_C + delta[3:6]
        C[3] = (0.0, 0.0, 0.0, 1.0)
        self._C = C
        self._tK = self._tK + delta[6:]
        self._n += 1
        self._filtered += 1
        upd = OnlineUpdate(self._n, C.copy(), self.cov, r, nis, statistic, alarm)
        if alarm and cfg.reset_on_alarm:
            self.reset()
        return upd

    @property
    def camera_transform(self) -> np.ndarray | None:
        """``T_base_cam`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand), or None while bootstrapping."""
        return None if self._C is None else self._C.copy()

    @property
    def cov(self) -> np.ndarray | None:
        """Covariance (6, 6) of the camera transform, marker translation marginalised."""
        if self._P is None:
            return None
        if self.config.forgetting == 1.0:
            return self._noise_scale() * self._P[:6, :6]
        P6 = self._P[:6] @ self._I2 @ self._P[:, :6]
        return self._noise_scale() * 0.5 * (P6 + P6.T)

    def result(self) -> CalibrationResult | None:
        """The current estimate as a `CalibrationResult` (method ``"YKronT'+online"``), or None.

        The marker-side rotation is unknown (identity, ``marker_rotation_known``
        False); per-sample residuals are not kept, so ``residuals`` is empty.
        """
        if self._C is None:
            return None
        K = tf.make_transform(_I3, self._tK)
        X, Y = rf._join(self._C.copy(), K, self.config.setup)
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
