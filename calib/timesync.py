"""Pairing unsynchronised pose streams: interpolation and clock-offset estimation.

Works for both setups. A robot stream (``A(t) = T_base_flange``, clock a) and a
camera stream (``B(t) = T_cam_marker``, clock b) are recorded by different
clocks; an event stamped ``t`` by clock b happens at ``t + offset`` on clock a.
Pairing a camera sample at ``t_b`` therefore interpolates the robot stream at
``t_b + offset`` (SLERP for rotation, linear for translation).

The offset is estimated in two steps:

1. `estimate_clock_offset`: cross-correlate the angular speed of both streams.
   The rotation angle of a relative motion is the same for the hand and the
   camera (``A_j^-1 A_i X = X B_j B_i^-1``, paper eq. 1 rearranged; conjugate
   rotations have equal angles), so both speed signals coincide up to the
   offset, whatever X is and whichever direction each stream is stored in.
2. `refine_clock_offset`: bounded 1-D minimisation of a cost (e.g. the
   calibration residual of `calibration_cost`) around the first estimate.

Times are seconds, translations metres, quaternions scalar-last.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation, Slerp

from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError, InsufficientDataError


def check_stream(t, T, name: str = "stream") -> tuple[np.ndarray, np.ndarray]:
    """Validate a timed pose stream.

    Parameters
    ----------
    t : array_like, shape (N,)
        Strictly increasing, finite timestamps (s).
    T : array_like, shape (N, 4, 4)
        Rigid transforms at those times.
    name : str
        Used in error messages.

    Returns
    -------
    t : ndarray, shape (N,)
    T : ndarray, shape (N, 4, 4)

    Raises
    ------
    CalibrationError
        Wrong shapes, fewer than 2 samples, NaN, non-increasing times (the
        message names the first bad index) or a non-rigid transform.
    """
    t = np.asarray(t, dtype=float)
    if t.ndim != 1:
        raise CalibrationError(f"{name} times must have shape (N,), got {t.shape}")
    T = tf.check_transforms(T, f"{name} poses")
    if len(T) != len(t):
        raise CalibrationError(f"{name}: {len(t)} times but {len(T)} poses")
    if len(t) < 2:
        raise InsufficientDataError(f"{name} needs at least 2 samples, got {len(t)}")
    if not np.isfinite(t).all():
        raise CalibrationError(f"{name} time[{int(np.argmin(np.isfinite(t)))}] is NaN or inf")
    steps = np.diff(t)
    if (steps <= 0).any():
        i = int(np.argmax(steps <= 0)) + 1
        raise CalibrationError(f"{name} time[{i}] = {t[i]!r} does not increase (previous {t[i - 1]!r})")
    return t, T


def _gap_free(tq: np.ndarray, t: np.ndarray, max_gap: float) -> np.ndarray:
    """Whether each query time's two neighbouring samples are at most ``max_gap`` apart."""
    hi = np.clip(np.searchsorted(t, tq, side="left"), 1, len(t) - 1)
    return (t[hi] - t[hi - 1]) <= max_gap


def interpolate_poses(t_query, t, T, *, max_gap: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Poses of a stream at other times: SLERP rotation, linear translation.

    Parameters
    ----------
    t_query : array_like, shape (M,)
        Times to interpolate at (s, same clock as ``t``).
    t : array_like, shape (N,)
        Stream times, strictly increasing (s).
    T : array_like, shape (N, 4, 4)
        Stream poses.
    max_gap : float, optional
        A query whose two neighbouring samples are more than ``max_gap`` s
        apart is invalid (the stream dropped out there, e.g. marker not seen).

    Returns
    -------
    T_query : ndarray, shape (M, 4, 4)
        Interpolated poses; identity where invalid.
    valid : ndarray of bool, shape (M,)
        False outside ``[t[0], t[-1]]`` and across gaps.
    """
    t, T = check_stream(t, T)
    tq = np.asarray(t_query, dtype=float)
    if tq.ndim != 1 or not np.isfinite(tq).all():
        raise CalibrationError(f"t_query must be finite with shape (M,), got shape {tq.shape}")
    valid = (tq >= t[0]) & (tq <= t[-1])
    if max_gap is not None:
        valid &= _gap_free(tq, t, max_gap)
    out = np.broadcast_to(np.eye(4), (len(tq), 4, 4)).copy()
    if valid.any():
        tv = tq[valid]
        R = Slerp(t, Rotation.from_matrix(T[:, :3, :3]))(tv).as_matrix()
        p = np.column_stack([np.interp(tv, t, T[:, k, 3]) for k in range(3)])
        out[valid] = tf.make_transform(R, p)
    return out, valid


def angular_speed(t, T, grid, *, baseline: float, max_gap: float | None = None) -> np.ndarray:
    """Angular speed of a stream on a uniform time grid, over a finite baseline.

    Parameters
    ----------
    t : array_like, shape (N,)
    T : array_like, shape (N, 4, 4)
        The stream; ``grid`` must lie within ``[t[0], t[-1]]``.
    grid : array_like, shape (G,)
        Uniform times (s).
    baseline : float
        Time span (s) over which the rotation angle is measured; rounded to a
        whole number of grid steps (at least one).
    max_gap : float, optional
        Where either end of a baseline falls into a gap of the stream longer
        than this (s), the speed is NaN: interpolating across a dropout would
        invent a smooth motion.

    Returns
    -------
    omega : ndarray, shape (G - m,)
        ``angle(R(g_k)^T R(g_{k+m})) / (m * step)`` (rad/s) with ``m`` the
        baseline in steps. The angle of a relative rotation is the same for a
        stream and its inverse, and for the hand and the camera of a rigid rig.
        A baseline much longer than the sample period averages out the pose
        noise that a frame-to-frame difference would amplify.
    """
    grid = np.asarray(grid, dtype=float)
    step = float(grid[1] - grid[0])
    m = max(1, int(round(baseline / step)))
    if len(grid) <= m:
        raise InsufficientDataError(f"grid of {len(grid)} steps is shorter than the baseline of {m} steps")
    T_g, valid = interpolate_poses(grid, t, T)
    if not valid.all():
        raise CalibrationError("angular_speed: grid extends outside the stream's time span")
    R = T_g[:, :3, :3]
    omega = tf.rotation_angle(np.swapaxes(R[:-m], -1, -2) @ R[m:]) / (m * step)
    if max_gap is not None:
        ok = _gap_free(grid, t, max_gap)
        omega[~(ok[:-m] & ok[m:])] = np.nan
    return omega


@dataclass(frozen=True)
class ClockOffset:
    """Result of a clock-offset estimate.

    Attributes
    ----------
    offset : float
        Seconds to add to stream b's timestamps to get stream a's clock.
    score : float
        Normalised cross-correlation at ``offset`` (1 = identical speed
        profiles), or the cost at the minimum for a refined estimate.
    method : str
        ``"angular-speed-xcorr"`` or ``"residual-min"``.
    """

    offset: float
    score: float
    method: str


def estimate_clock_offset(
    t_a, T_a, t_b, T_b, *, max_offset: float = 1.0, resolution: float = 0.005, baseline: float = 0.3,
    max_gap: float | None = None,
) -> ClockOffset:
    """Clock offset between two streams by correlating their angular speeds.

    Both streams' orientations are resampled (SLERP) on a grid of
    ``resolution`` s, their angular speeds taken over ``baseline`` s (see
    `angular_speed`), and the lag in ``[-max_offset, max_offset]`` with the
    largest normalised cross-correlation is refined to sub-grid precision with
    a parabola through the peak.

    Parameters
    ----------
    t_a, T_a : array_like, shapes (N,), (N, 4, 4)
        Reference stream (e.g. robot ``T_base_flange``).
    t_b, T_b : array_like, shapes (M,), (M, 4, 4)
        Other stream (e.g. camera ``T_cam_marker`` or its inverse).
    max_offset : float
        Largest |offset| searched (s).
    resolution : float
        Grid step (s).
    baseline : float
        Span (s) of the finite difference giving the angular speed: several
        camera frames, so that pose noise does not swamp the rotation between
        them.
    max_gap : float, optional
        Leave out of the correlation the baselines that touch a gap longer
        than this (s) in either stream (e.g. marker out of view).

    Returns
    -------
    ClockOffset
        ``offset`` such that ``t_a = t_b + offset`` for the same event;
        ``score`` is the peak normalised correlation.

    Raises
    ------
    InsufficientDataError
        If the streams overlap too little for the searched offsets, or stream
        b does not rotate (its speed signal is flat).
    CalibrationError
        If the best lag is at the edge of ``[-max_offset, max_offset]`` (the
        true offset may lie outside).
    """
    t_a, T_a = check_stream(t_a, T_a, "stream a")
    t_b, T_b = check_stream(t_b, T_b, "stream b")
    if max_offset <= 0 or resolution <= 0 or baseline <= 0:
        raise CalibrationError("max_offset, resolution and baseline must be > 0")
    grid, n_lag = _lag_grid(t_a, t_b, max_offset, resolution, baseline)
    sb = angular_speed(t_b, T_b, grid, baseline=baseline, max_gap=max_gap)
    vb = np.isfinite(sb)
    if vb.sum() < 10 or np.nanstd(sb) < 1e-12:
        raise InsufficientDataError("stream b does not rotate: its angular speed carries no timing information")
    # Stream a once on a grid widened by the lag range; each lag is then a slice.
    grid_a = grid[0] + np.arange(-n_lag, len(grid) + n_lag) * resolution
    # By construction inside stream a's span; the clip only absorbs floating-point rounding at the ends.
    grid_a = np.clip(grid_a, t_a[0], t_a[-1])
    sa_all = angular_speed(t_a, T_a, grid_a, baseline=baseline, max_gap=max_gap)
    lags = np.arange(-n_lag, n_lag + 1)
    scores = _lag_correlations(sa_all, sb, vb, lags)
    i = int(np.argmax(scores))
    if i in (0, len(lags) - 1):
        raise CalibrationError(
            f"the angular speeds correlate best at the edge of the search range ({lags[i] * resolution:+.3f} s): "
            f"the clock offset may be larger than max_offset = {max_offset} s"
        )
    y0, y1, y2 = scores[i - 1 : i + 2]
    curv = y0 - 2 * y1 + y2
    offset = lags[i] * resolution
    if curv < 0:
        # Vertex of the parabola through the peak and its neighbours.
        offset += 0.5 * resolution * (y0 - y2) / curv
    return ClockOffset(float(offset), float(scores[i]), "angular-speed-xcorr")




def _lag_grid(t_a, t_b, max_offset: float, resolution: float, baseline: float):
    """Stream b's time grid (its part that, shifted by any lag tried, stays inside stream a's span) and the
    number of grid steps in ``max_offset``."""
    lo = max(t_b[0], t_a[0] + max_offset)
    hi = min(t_b[-1], t_a[-1] - max_offset)
    grid = np.arange(lo, hi, resolution)
    m = max(1, int(round(baseline / resolution)))
    if len(grid) < 2 * m + 10:
        raise InsufficientDataError(
            f"streams overlap for {max(hi - lo, 0.0):.3f} s after allowing +-{max_offset} s of offset; "
            f"need more than {2 * baseline:.2f} s"
        )
    return grid, int(np.floor(max_offset / resolution))

def _lag_correlations(sa_all, sb, vb, lags) -> np.ndarray:
    """Normalised cross-correlation (len(lags),) of stream b's speeds ``sb`` (valid where ``vb``) with the
    slice of stream a's ``sa_all`` at each lag; -1 where fewer than 10 samples overlap."""
    n_lag = (len(lags) - 1) // 2
    scores = np.full(len(lags), -1.0)
    for i, lag in enumerate(lags):
        sa = sa_all[lag + n_lag : lag + n_lag + len(sb)]
        v = vb & np.isfinite(sa)
        if v.sum() < 10:
            continue
        x, y = sa[v] - sa[v].mean(), sb[v] - sb[v].mean()
        denom = np.linalg.norm(x) * np.linalg.norm(y)
        if denom > 1e-12:
            scores[i] = float(x @ y / denom)
    return scores

def refine_clock_offset(
    cost: Callable[[float], float], offset0: float, *, half_width: float = 0.1, xatol: float = 1e-4
) -> ClockOffset:
    """Minimise ``cost(offset)`` over ``[offset0 - half_width, offset0 + half_width]``.

    Parameters
    ----------
    cost : callable
        Scalar cost of an offset, e.g. from `calibration_cost`.
    offset0 : float
        Starting estimate (s), e.g. from `estimate_clock_offset`.
    half_width : float
        Half the search interval (s).
    xatol : float
        Absolute tolerance on the offset (s).

    Returns
    -------
    ClockOffset
        ``method="residual-min"``, ``score`` = cost at the minimum.
    """
    if half_width <= 0:
        raise CalibrationError(f"half_width must be > 0, got {half_width}")
    res = minimize_scalar(
        cost, bounds=(offset0 - half_width, offset0 + half_width), method="bounded", options={"xatol": xatol}
    )
    return ClockOffset(float(res.x), float(res.fun), "residual-min")


def pair_streams(
    t_a, T_a, t_b, T_b, offset: float, *, max_gap: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Stream a interpolated at stream b's samples shifted by ``offset``.

    Parameters
    ----------
    t_a, T_a : array_like, shapes (N,), (N, 4, 4)
        Stream interpolated (usually the faster robot stream).
    t_b, T_b : array_like, shapes (M,), (M, 4, 4)
        Stream whose samples are kept as they are (usually the camera).
    offset : float
        ``t_a = t_b + offset`` (s).
    max_gap : float, optional
        See `interpolate_poses`.

    Returns
    -------
    t : ndarray, shape (K,)
        Kept times on clock b (s).
    A : ndarray, shape (K, 4, 4)
        Stream a at ``t + offset``.
    B : ndarray, shape (K, 4, 4)
        Stream b at ``t``.
    index_b : ndarray of int, shape (K,)
        Indices of the kept stream-b samples.
    """
    t_b, T_b = check_stream(t_b, T_b, "stream b")
    A, valid = interpolate_poses(t_b + offset, t_a, T_a, max_gap=max_gap)
    idx = np.flatnonzero(valid)
    return t_b[idx], A[idx], T_b[idx], idx


def calibration_cost(
    t_a, T_a, t_b, T_b, solve_fn: Callable[[np.ndarray, np.ndarray], float], *, max_gap: float | None = None
) -> Callable[[float], float]:
    """Cost of an offset = residual of a calibration on the streams paired with it.

    Parameters
    ----------
    t_a, T_a, t_b, T_b :
        As in `pair_streams`.
    solve_fn : callable
        ``solve_fn(A, B) -> float``: calibrates ``A_i X = Y B_i`` (paper eq. 1)
        from paired poses and returns a residual (e.g. RMS translation, m).
    max_gap : float, optional
        See `interpolate_poses`.

    Returns
    -------
    cost : callable
        ``cost(offset) -> float``.
    """

    def cost(offset: float) -> float:
        _, A, B, _ = pair_streams(t_a, T_a, t_b, T_b, offset, max_gap=max_gap)
        return float(solve_fn(A, B))

    return cost
