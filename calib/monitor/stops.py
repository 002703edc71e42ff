"""The production program's stops as the engine sees them: one sample (`Stop`), a visit of the detector's
window (`Visit`), the stops' typical marker points (`Stops`), and a rate by regression (`Rate`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np




#: A stop's typical marker point is the running mean of at most this many of its last visits.
BASELINE_VISITS = 48
#: Stops whose typical marker point is kept (the most recently visited).
MAX_STOPS = 64
#: Seconds per hour: rates are per hour at the edges, times are seconds inside.
HOUR_S = 3600.0
#: A rate needs this much of its regression window covered before it is reported: the drift is a random
#: walk, whose slope over less than the window is mostly its noise.
RATE_MIN_SPAN = 1.0


@dataclass(slots=True)
class Stop:
    """A sample: flange pose, measured point, its covariance shape, kinematic-error factor, time; as floats for
    the per-sample model, ``pose`` is ``A[:3]`` flat (also the stop lookup's key), ``point`` is ``p`` and
    ``shape_upper`` the shape's upper triangle ``(xx, xy, xz, yy, yz, zz)``; ``stop`` is the lookup's memo
    (`Stops.lookup`); ``walk_t`` the random walk's clock at the sample
    (`handeye.calib.monitor.filter.FilterState.walk_t`); ``w`` the filter's walk states then (6 floats: how far the
    camera had walked since the calibration in use, as the filter saw it before this sample)."""

    A: np.ndarray
    p: np.ndarray
    shape: np.ndarray
    factor: np.ndarray | None
    t: float
    pose: list
    point: tuple
    shape_upper: tuple
    stop: tuple | None = None
    walk_t: float = 0.0
    w: tuple = (0.0,) * 6


class Visit(NamedTuple):
    """A sample in the detector's window, the filter state (`handeye.calib.monitor.filter.FilterState`) before it was
    fused, its test statistic (chi-square, 3 dof, against that state or its stop's earlier visits), and the key
    of the stop it was compared with (`Stops.ids`; None: against the model)."""

    sample: Stop
    state: object
    nis: float
    stop_id: int | None


class Stops:
    """Production stops' typical measured marker points (camera frame): the running mean of each stop's last
    `BASELINE_VISITS` visits, of the filter's walk states at them, and of their flange poses, for the
    `MAX_STOPS` most recently visited stops.

    Two flange poses are the same stop when closer than ``translation_m`` and
    ``rotation_rad``; a sample's stop is the least recently visited match.
    A lookup is memoised on the sample while the set of stops is unchanged
    and the match unique (a sample is looked up when tested, and again when
    it leaves the detector's window and joins its stop).
    """

    def __init__(self, translation_m: float, rotation_rad: float):
        self.poses: list[list] = []                     # per stop: its first flange pose, A[:3] flat
        self.mean: list[tuple] = []                      # per stop: the mean marker point, 3 floats
        self.mean_w: list[tuple] = []                    # per stop: the mean walk states, 6 floats
        self.pose_mean: list[list] = []                  # per stop: the mean flange pose of those visits, likewise
        self.n: list[float] = []
        self.last: list[int] = []
        self.ids: list[int] = []                        # per stop: a key no other stop of this set has had
        self._next_id = 0
        self.generation = 0                             # changes whenever a stop is added or dropped
        self._visits = 0
        self._t2 = translation_m * translation_m
        # trace(R1^T R2) = 1 + 2 cos(angle): under the angle <=> above this trace
        self._trace = 1.0 + 2.0 * math.cos(rotation_rad)

    @property
    def count(self) -> int:
        return len(self.poses)

    def same(self, a, b) -> bool:
        """Two flange poses (``A[:3]`` flat, 12 floats) are the same stop."""
        a0, a1, a2, x, a3, a4, a5, y, a6, a7, a8, z = a
        b0, b1, b2, bx, b3, b4, b5, by, b6, b7, b8, bz = b
        dx, dy, dz = bx - x, by - y, bz - z
        return (dx * dx + dy * dy + dz * dz < self._t2
                and a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3 + a4 * b4 + a5 * b5 + a6 * b6 + a7 * b7 + a8 * b8
                > self._trace)

    def lookup(self, s: Stop) -> int | None:
        """The index of ``s``'s stop, or None."""
        if s.stop is not None and s.stop[0] == self.generation:
            return s.stop[1]
        hits = [i for i, pose in enumerate(self.poses) if self.same(s.pose, pose)]
        if len(hits) > 1:
            return min(hits, key=self.last.__getitem__)
        i = hits[0] if hits else None
        s.stop = (self.generation, i)
        return i

    def add(self, s: Stop) -> None:
        """Fold a visit's marker point into its stop's mean (a new stop replaces the least recently visited one
        when `MAX_STOPS` are held)."""
        i = self.lookup(s)
        if i is None:
            if len(self.poses) == MAX_STOPS:
                j = self.last.index(min(self.last))
                for held in (self.poses, self.mean, self.mean_w, self.pose_mean, self.n, self.last, self.ids):
                    del held[j]
            i = len(self.poses)
            self.poses.append(s.pose)
            self.mean.append((0.0, 0.0, 0.0))
            self.mean_w.append((0.0,) * 6)
            self.pose_mean.append(s.pose)
            self.n.append(0.0)
            self.last.append(0)
            self.ids.append(self._next_id)
            self._next_id += 1
            self.generation += 1
        n = self.n[i] = min(self.n[i] + 1.0, BASELINE_VISITS)
        (m0, m1, m2), (p0, p1, p2) = self.mean[i], s.point
        self.mean[i] = (m0 + (p0 - m0) / n, m1 + (p1 - m1) / n, m2 + (p2 - m2) / n)
        self.mean_w[i] = tuple(a + (b - a) / n for a, b in zip(self.mean_w[i], s.w))
        if self.pose_mean[i] != s.pose:      # a stop repeated only roughly (exact repeats leave it as it is)
            self.pose_mean[i] = [a + (b - a) / n for a, b in zip(self.pose_mean[i], s.pose)]
        self._visits += 1
        self.last[i] = self._visits

    def clear(self) -> None:
        self.poses, self.mean, self.mean_w, self.pose_mean, self.n, self.last, self.ids = [], [], [], [], [], [], []
        self.generation += 1


class Rate:
    """Exponentially weighted least-squares slope of a vector (a sequence of floats) against time (running sums: O(1))."""

    def __init__(self, tau_s: float, hour_s: float):
        self.tau_s, self.hour_s = tau_s, hour_s
        self.reset()

    def add(self, t: float, y) -> None:
        if self.t0 is None:
            self.t0 = t
            self.y0, self.y1 = [0.0] * len(y), [0.0] * len(y)
        decay = math.exp(-(t - self.t_last) / self.tau_s) if self.s0 else 1.0
        x = (t - self.t0) / self.hour_s
        self.s0, self.s1, self.s2 = self.s0 * decay + 1.0, self.s1 * decay + x, self.s2 * decay + x * x
        self.y0 = [a * decay + b for a, b in zip(self.y0, y)]
        self.y1 = [a * decay + x * b for a, b in zip(self.y1, y)]
        self.t_last = t

    def slope(self) -> list | None:
        """Per ``hour_s`` of the clock, or None before the regression spans `RATE_MIN_SPAN` of its window."""
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
