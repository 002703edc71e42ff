"""The *moved* test of the monitoring engine: a windowed GLR test for a 6-dof jump of the camera transform.

`ChangeDetector` tests, over sliding windows of the last ``window`` (20) and
``long_window`` (100) innovations (predicted before each sample is fused, so
they are white with known covariance when nothing changed), the generalised
likelihood ratio of "the camera moved by some 6-dof delta":
``g^T F^-1 g`` with ``F = sum H^T S^-1 H``, ``g = sum H^T S^-1 r``, which is
chi-square with 6 dof before a change. It alarms above the
``1 - false_alarm_rate / 2`` quantile. The short window flags clear moves
within a few samples; the long one catches moves the points barely show,
such as a small rotation about the optical axis. `handeye.calib.monitor.MonitorEngine`
feeds it (eye-to-hand the camera transform is ``Y = T_base_cam``, eye-in-hand
``X = T_flange_cam``; perturbations as in `handeye.calib.result`).
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import Field, model_validator
from scipy.linalg.lapack import dposv
from scipy.stats import chi2, ncx2

from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError
from handeye.calib.model import point_jacobians
from handeye.calib.params import Float, Int, Params
from handeye.calib.setup import Setup, check_setup

#: The detector's long window is tested every this many samples.
LONG_STRIDE = 4
#: Per-sample false-alarm rate of the *moved* test. A production program gives a sample at every standstill,
#: thousands a day: at 1e-5 a still camera raised a false *moved* alarm every 2-4 weeks per cell; at 1e-6 about
#: one a year (8 in 2,400 simulated cell-days, each starting a re-learn of a move that did not happen: "moved
#: 2.3 mm and 0.67 deg", the live error from 2.9 to 4.2 mm); at 1e-7 none, for 4 of 320 knocks flagged after 20
#: samples instead of within, knocks the program's stops barely see (docs/benchmarks.md, "A month left alone").
FALSE_ALARM_RATE = 1e-7

_EYE3 = np.eye(3)


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
        (0, 0.1), split evenly between the two windows (`FALSE_ALARM_RATE`).
    """

    window: Annotated[Int, Field(ge=3)] = 20
    long_window: Int | None = 100
    false_alarm_rate: Annotated[Float, Field(gt=0, lt=0.1)] = FALSE_ALARM_RATE

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
    (`handeye.calib.result` convention). Over each window the statistic
    ``g^T F^-1 g`` is chi-square(6) while the camera stays put; a moved camera
    makes the innovations line up with ``H``. ``statistics`` holds the
    (short, long) window values, ``statistic`` the larger; both share one threshold.
    """

    def __init__(self, config: DetectorConfig | None = None):
        self.config = config or DetectorConfig()
        windows = 1 if self.config.long_window is None else 2
        self.threshold = float(chi2.ppf(1.0 - self.config.false_alarm_rate / windows, 6))
        # Running sums of the per-sample H^T S^-1 [H | r | I] (F = [:, :6], g = [:, 6], G = [:, 7:]) over the
        # last size samples: a window sum is one difference, not an add and a subtract per window.
        # Unwritten slots are zero, i.e. the sum before the first sample.
        self._size = (self.config.long_window or self.config.window) + 1
        self._cum = np.zeros((self._size, 6, 10))
        self._Hr = np.zeros((3, 10))
        #: Variance (m^2 per axis) of an error of the predicted point that nearby samples share: the
        #: calibration's own systematic error (`shared_error_var`); 0 treats the innovations as white.
        self.shared_var = 0.0
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

    def update(self, r: np.ndarray, S_inv: np.ndarray, H: np.ndarray, offset_var=None, shared: bool = True) -> bool:
        """Add one innovation ``r`` (3,) with inverse covariance ``S_inv`` (3, 3) and Jacobian ``H`` (3, 6).

        ``offset_var`` (6,), optional: variances of a camera offset that the
        long window's innovations share, whatever happens in it (e.g. how far
        a drifting camera moved since the baselines they are measured
        against). The long window's test is for a move beyond it: with that
        offset marginalised, ``g^T (F + F Q F)^-1 g`` (Q its diagonal
        covariance) is chi-square with 6 dof before a change.

        ``shared``: the innovation is against the model's prediction, so it
        carries the calibration's systematic error that the window's other
        such innovations share (`shared_var`); False for an innovation against
        earlier visits of the same pose, where that error cancels. With it
        marginalised, ``g^T (F + shared_var G G^T)^-1 g``, ``G = sum H^T S^-1``
        over those innovations, is chi-square with 6 dof before a change.

        Returns True if a window's GLR statistic exceeds the threshold.
        """
        # [H^T S^-1 H | H^T S^-1 r | H^T S^-1 (shared)] in one product.
        Hr = self._Hr
        Hr[:, :6] = H
        Hr[:, 6] = r
        Hr[:, 7:] = _EYE3 if shared else 0.0
        Fg = H.T.dot(S_inv).dot(Hr)         # ndarray.dot: @'s product, less call overhead on small arrays
        cfg, n, size, cum = self.config, self._count, self._size, self._cum
        slot = n % size
        now = np.add(cum[slot - 1], Fg, out=cum[slot])        # slot - 1 = -1 wraps to the last slot
        self._count = n + 1
        if self._count < 3:
            # Two points cannot yet separate six pose parameters.
            return False
        shared_var = self.shared_var
        short = _glr(now - cum[(n - cfg.window) % size], None, shared_var)
        long = self.statistics[1]
        # The long window is for slow, small moves: testing it every LONG_STRIDE samples
        # delays those alarms a little and saves a 6x6 solve per sample.
        if cfg.long_window is not None and self._count > cfg.window and self._count % LONG_STRIDE == 0:
            long = _glr(now - cum[(n - cfg.long_window) % size], offset_var, shared_var)
        self.statistics = (short, long)
        self.statistic = max(short, long)
        return self.statistic > self.threshold


    def onset(self) -> int:
        """Innovations since the most likely start of a change: the ``k`` (3 to ``window``, at most those
        since the last reset) whose last-``k`` window has the largest statistic (the change point's maximum
        likelihood estimate; 3 innovations are the fewest that separate six pose parameters)."""
        n, size, cum = self._count - 1, self._size, self._cum
        last = min(self._count, self.config.window)
        if last < 3:
            return last
        stats = [_glr(cum[n % size] - cum[(n - k) % size], None, self.shared_var) for k in range(3, last + 1)]
        return 3 + int(np.argmax(stats))


def _glr(Fg, offset_var=None, shared_var=0.0):
    """``g^T F^-1 g`` of a window sum ``[F | g | G]`` (6, 10); ``F + F Q F`` with ``Q = diag(offset_var)``, plus
    ``shared_var G G^T``, in place of ``F``."""
    g = Fg[:, 6]
    # A tiny ridge keeps a rank-deficient window (robot standing still) solvable;
    # g lies in the range of F then, so the statistic is unaffected. Fg is a contiguous
    # temporary: F's diagonal is every 11th entry of its (6, 10) rows.
    diagonal = Fg.reshape(-1)[0:66:11]
    diagonal += 1e-9 * (Fg.item(0, 0) + Fg.item(3, 3))
    F = Fg[:, :6]
    if offset_var is not None:
        F = F + (F * offset_var).dot(F)
    if shared_var:
        G = Fg[:, 7:]
        F = F + shared_var * G.dot(G.T)
    _, x, info = dposv(F, g)
    return float(g.dot(x)) if info == 0 else 0.0


def move_information(H, R, visits, baseline) -> np.ndarray:
    """Information (6, 6) on a rigid move of the camera transform from a window of samples at repeated stops.

    The detection limit's model: noise known, the move's onset known, and each
    stop's marker point compared with the mean of its ``baseline`` visits from
    before the move, so that what the visits of a stop share (the
    calibration's systematic error there) cancels. Stop ``j``'s ``visits``
    samples in the window average to a point whose change has covariance
    ``R_j (1 / m_j + 1 / n_j)``; the move ``delta`` shows in it as ``H_j delta``.

    Parameters
    ----------
    H : array_like, shape (S, 3, 6)
        Each stop's marker point Jacobian w.r.t. the camera transform
        (left perturbation ``[rotation, translation]``, rad and m, as `handeye.calib.result`).
    R : array_like, shape (S, 3, 3)
        The covariance of one sample's point at each stop, m^2.
    visits : array_like of int, shape (S,)
        Samples of each stop in the window (stops with none add nothing).
    baseline : array_like of int, shape (S,)
        Visits of each stop before the move (stops with none add nothing).

    Returns
    -------
    N : ndarray, shape (6, 6)
        ``sum_j H_j^T (R_j (1/m_j + 1/n_j))^-1 H_j``; ``delta^T N delta`` is the
        non-centrality of the GLR statistic ``g^T N^-1 g`` (chi-square, 6 dof).
    """
    H = np.asarray(H, dtype=float)
    R = np.asarray(R, dtype=float)
    m = np.asarray(visits, dtype=float)
    n = np.asarray(baseline, dtype=float)
    S = len(H)
    if H.shape != (S, 3, 6) or R.shape != (S, 3, 3) or m.shape != (S,) or n.shape != (S,):
        raise CalibrationError(f"move_information needs H (S, 3, 6), R (S, 3, 3), visits and baseline (S,); got "
                               f"{H.shape}, {R.shape}, {m.shape}, {n.shape}")
    if not (np.all(np.isfinite(H)) and np.all(np.isfinite(R)) and np.all(m >= 0) and np.all(n >= 0)):
        raise CalibrationError("move_information needs finite H and R and visit counts >= 0")
    used = (m > 0) & (n > 0)
    N = np.zeros((6, 6))
    for Hj, Rj, mj, nj in zip(H[used], R[used], m[used], n[used]):
        N += Hj.T @ np.linalg.solve(Rj * (1.0 / mj + 1.0 / nj), Hj)
    return N


def window_power(C, after, K, A, R, visits, baseline, setup: str, robot_cov, threshold: float) -> float:
    """Probability that the best test flags the camera's move from ``C`` to ``after`` from a window of samples at
    repeated stops, each stop against its visits before the move (`move_information`, `detection_power`).

    Parameters
    ----------
    C, after : array_like, shape (4, 4)
        The camera transform before and after the move (eye-to-hand ``T_base_cam``, eye-in-hand ``T_flange_cam``).
    K : array_like, shape (4, 4)
        The marker-side transform (eye-to-hand ``T_flange_marker``, eye-in-hand ``T_base_marker``).
    A : array_like, shape (S, 4, 4)
        The stops' flange poses ``T_base_flange``.
    R : array_like, shape (S, 3, 3)
        One sample's point covariance at each stop, m^2.
    visits, baseline : array_like of int, shape (S,)
        Samples of each stop in the window, and before the move.
    setup : str
    robot_cov : array_like, shape (6, 6), or None
        The flange twist's covariance per visit (rad^2, m^2; the robot's repeatability), added to ``R`` through the
        point's Jacobian; None: an exact robot.
    threshold : float
        The GLR threshold.
    """
    A = np.asarray(A, dtype=float)
    C, after = np.asarray(C, dtype=float), np.asarray(after, dtype=float)
    M = A if check_setup(setup) == Setup.EYE_TO_HAND else tf.invert(A)
    _, H, _, _, H_xi = point_jacobians(C, np.asarray(K, dtype=float), M, None, setup)
    R = np.asarray(R, dtype=float)
    if robot_cov is not None:
        R = R + H_xi @ np.asarray(robot_cov, dtype=float) @ H_xi.transpose(0, 2, 1)
    delta = np.r_[tf.so3_log(after[:3, :3] @ C[:3, :3].T), after[:3, 3] - C[:3, 3]]
    return detection_power(move_information(H, R, visits, baseline), delta, threshold)


def detection_power(N, delta, threshold: float) -> float:
    """Probability that the GLR statistic of a window with information ``N`` (`move_information`) exceeds
    ``threshold`` when the camera moved by ``delta`` (6,): ``P(chi2_6(delta^T N delta) > threshold)``."""
    N = np.asarray(N, dtype=float)
    delta = np.asarray(delta, dtype=float)
    if N.shape != (6, 6) or delta.shape != (6,) or not threshold > 0:
        raise CalibrationError(f"detection_power needs N (6, 6), delta (6,) and threshold > 0; got {N.shape}, "
                               f"{delta.shape}, {threshold}")
    return float(ncx2.sf(threshold, 6, max(float(delta @ N @ delta), 1e-12)))
