"""`MonitorEngine`: the filter (`handeye.calib.monitor.filter`), the change test, the re-learn after a move, and the figures
of each update."""

from __future__ import annotations

import collections
import dataclasses
import math
from typing import NamedTuple

import numpy as np
from scipy.stats import chi2

from handeye.calib import model
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError, FilterDivergedError
from handeye.calib.noise import default_point_cov
from handeye.calib.change import ChangeDetector
from handeye.calib.problem import CalibrationProblem
from handeye.calib.result import CalibrationResult, CameraParameter, Residuals
from handeye.calib.setup import Setup
from handeye.calib.monitor.filter import (GROSS_NIS, FilterState, Layout, NoiseTrack, SampleModel, Walk,
                                          clear_slots, filter_state, find_slot, follow_noise, fuse, fuse_linear,
                                          innovate, layout_of, linearize, next_slot, noise, observed_walk, open_slot,
                                          predict, prediction, relinearize, restart_walk, visit_slot)
from handeye.calib.monitor.settings import AlarmLevel, EngineState, MonitorSettings, MonitorUpdate
from handeye.calib.monitor.kernels import (inv_sym3_floats, is_plain, is_positive_definite3, parts, plain_cov,
                                   plain_point, plain_transform, sym3)
from handeye.calib.monitor.reference import InUse, Reference, WorkspaceMoments, arm_reference, workspace_distance
from handeye.calib.monitor.snapshot import Snapshot
from handeye.calib.monitor.stops import HOUR_S, Rate, Stop, Stops, Visit

#: Hours of the camera's world over which a predicted drift crossing must also hold as a trend, and a raised drift
#: must stay quiet before it clears (`MonitorEngine`'s drift figures): one day, a mount's thermal cycle.
TREND_H = 24.0


#: Visits of a stop before the detector compares its marker point with the stop's earlier ones.
MIN_BASELINE = 3
#: A visit whose flange pose is within this of its stop's mean pose (m, and rad on the rotation entries) is an
#: exact repeat: the marker point moves by some 10 um at most, so it is compared as it is (`_against_stop`).
SAME_POSE_TOL = 1e-5
#: Prior 1-sigma of the camera transform when a registration after a move starts the filter again
#: (translation m, rotation rad): wide against the registration's own error, narrow for linearity.
RELEARN_PRIOR = (0.01, np.deg2rad(1.0))
#: A re-learn registration is accepted when its residuals' chi-square is below this quantile;
#: above it, the oldest sample of the set is taken as one from before the move and dropped.
RELEARN_QUANTILE = 0.999
#: An innovation beyond this gate (chi-square 3 dof, 1e-5) does not move the noise scale (a move, an outlier).
NIS_GATE = float(chi2.ppf(1.0 - 1e-5, 3))
#: A sample whose test statistic (chi-square, 3 dof) is beyond this quantile's value is one the state before it
#: cannot explain on its own: when the move is flagged, the re-learn starts at the earliest such sample since the
#: detector's onset.
ONSET_GATE = float(chi2.ppf(1.0 - 1e-3, 3))
#: Prior 1-sigma of a bump (translation m, rotation rad) in the estimate of the move from the stops.
JUMP_PRIOR = (0.01, np.deg2rad(1.0))
#: Fewest samples a re-learn registers the camera from (without stops visited before the move): three
#: stops determine it, more average the point noise and let the consistency test find the move.
REGISTRATION_SAMPLES = 6
#: Alarms the engine remembers (`MonitorEngine.alarms`): the newest; months of drifting alarms stay bounded.
MAX_ALARMS = 1000
#: Two stops this far apart share about 61 % of a pose-only source's robot error
#: (`MonitorSettings.robot_accuracy_mm`; squared exponential in the flange positions): the error of a kinematic
#: model varies smoothly with the pose, and a program's stops lie within a few decimetres of each other.
SHARED_ERROR_LENGTH_M = 0.3


def wild_point(nis: float) -> str:
    """Why a sample is not re-learnt from: its marker point is `GROSS_NIS` or more off the camera before the move."""
    return (f"re-learning: a sample skipped, its marker point {math.sqrt(nis):.0f} sigma off the camera before the "
            "move (a glitch; if every sample is, the camera moved too far to re-learn from the stops: calibrate "
            "again)")


class Waiting(NamedTuple):
    """The re-learn cannot determine the camera yet: why, in plain words, and what would fix it."""

    reason: str


class Fit(NamedTuple):
    """A re-learn's estimate from the samples since the move: the filter state, how it was found, and whether its
    residuals agree with the noise (else the oldest sample is taken as one from before the move)."""

    state: FilterState
    how: str
    consistent: bool


class MonitorEngine:
    """The monitoring engine (`handeye.calib.monitor`'s docstring). ``arm`` it, then ``update`` it with every sample.

    Eye-to-hand it follows ``C = Y = T_base_cam`` and holds ``X =
    T_flange_marker``; eye-in-hand ``C = X = T_flange_cam`` and ``Y =
    T_base_marker`` (paper eq. 1, ``A_i X = Y B_i``).

    Attributes
    ----------
    settings : MonitorSettings
    detector : ChangeDetector
        The *moved* test.
    reference : Reference or None
        What it is armed from (None: not armed).
    origin : InUse or None
        The cell's first calibration (the arming one, or that of the first run a snapshot carries).
    relearns : int
        Re-learns since ``origin``.
    in_use : InUse or None
        The calibration in use: the arming one, then each re-learnt one (replaced, never changed).
    filter : FilterState or None
        The live estimate (`handeye.calib.monitor.filter`; replaced at every sample).
    state : EngineState
        After the last sample.
    """

    def __init__(self, settings: MonitorSettings | None = None):
        self.settings = settings or MonitorSettings()
        self.detector = ChangeDetector(self.settings.detector)
        self.reference: Reference | None = None
        self.origin: InUse | None = None
        self.in_use: InUse | None = None
        self.filter: FilterState | None = None
        self.state = EngineState.WARMING
        self._count = 0

    # ------------------------------------------------------------------ arming

    def arm(self, result: CalibrationResult, problem: CalibrationProblem, *, t: float = 0.0) -> Reference:
        """Arm from a calibration and the samples it was solved from (`arm_reference`); the next sample is
        tested at once.

        ``t`` is the time the calibration holds for (s, the samples' clock).
        Returns what the engine is armed from (its ``sigma_mm``: 1-sigma over the workspace).

        Raises
        ------
        CalibrationError
            The samples are malformed or do not determine the camera, or the result leaves part of it open
            (``result.undetermined``: a recording whose tool never turned, without the marker's offset).
        """
        if result.undetermined:
            # The open part was held at a guess: at the production's other tool orientations it would read as a move.
            raise CalibrationError("the calibration leaves part of the camera open, which the monitor cannot follow: "
                                   + "; ".join(result.undetermined))
        ref, cov = arm_reference(result, problem)
        layout = SampleModel.of(ref.setup == Setup.EYE_TO_HAND, len(cov) - 12, ref.noise).layout
        P = np.zeros((layout.size, layout.size))
        P[:layout.model, :layout.model] = cov
        # After the camera transform: marker translation, camera correction, kinematic error, the stops' own
        # errors (none held yet), and the camera's random walk since the calibration in use (the drift, told apart
        # from what the samples refine).
        u = np.r_[ref.K[:3, 3], ref.theta, np.zeros(layout.n_factor + 6)]
        in_use = InUse(ref.C.copy(), ref.theta.copy(), ref.sigma_mm)
        self._start(Snapshot(ref, in_use, in_use, filter_state(ref.C.copy(), u, P, t), NoiseTrack()))
        return ref

    def resume(self, snapshot: Snapshot, *, t: float | None = None) -> Reference:
        """Arm from where an earlier run left off (`snapshot`): its live estimate, covariance, noise level and
        calibration in use; the next sample is tested at once, against the model (the stops' baselines are
        learnt again), unless the run ended while a re-learnt camera settled (the settling goes on). Returns
        what the first run was armed from.

        ``t``: the time this run starts (s, the samples' clock); the random walk runs from the snapshot's time
        to the first sample (at most `MonitorSettings.walk_max_gap_h`). A ``t`` before the snapshot's time (a
        recording older than the run the snapshot comes from, a clock set back) starts the clock there.
        """
        if t is not None and t < snapshot.filter.t:
            snapshot = dataclasses.replace(snapshot, filter=snapshot.filter._replace(t=float(t)))
        # The stops' own errors are learnt again, with their baselines.
        snapshot = dataclasses.replace(snapshot, filter=clear_slots(snapshot.filter))
        self._start(snapshot)
        return snapshot.reference

    def snapshot(self) -> Snapshot:
        """What the next run continues from (`resume`; `handeye.calib.monitor.snapshot.snapshot_to_dict` for a file).

        Raises
        ------
        CalibrationError
            Not armed.
        """
        if not self.armed:
            raise CalibrationError("the monitoring engine is not armed: there is no calibration to carry over")
        return Snapshot(self.reference, self.origin, self.in_use, self.filter, self.noise_track, self.relearns,
                        self._settle)

    def _start(self, snap: Snapshot) -> None:
        cfg, ref = self.settings, snap.reference
        self.reference, self.origin, self.in_use, self.filter = ref, snap.origin, snap.in_use, snap.filter
        self.model = SampleModel.of(ref.setup == Setup.EYE_TO_HAND, snap.n_factor, ref.noise)
        self.noise_track = snap.noise_track
        self.relearns = snap.relearns
        # An hour of the camera's world on the samples' clock.
        self.hour_s = HOUR_S / cfg.time_scale
        sr, st = np.deg2rad(cfg.walk_deg_per_sqrt_h), cfg.walk_mm_per_sqrt_h * 1e-3
        self._q = np.array([sr * sr] * 3 + [st * st] * 3) / self.hour_s
        self._info: dict[tuple, np.ndarray] = {}     # per held stop's pose: what one visit tells of the camera
        # per held stop's pose: its prior, flange position, Q and its error as its neighbours told it or None (`_open`)
        self._priors: dict[tuple, tuple] = {}
        self._walk_slots: tuple | None = None         # the slots `walk` was made for
        self._walk_for(snap.filter.slots)
        self.workspace = WorkspaceMoments(ref.workspace)
        self.stops = Stops(cfg.stop_translation_m, np.deg2rad(cfg.stop_rotation_deg))
        self.rate = Rate(cfg.rate_window_h * self.hour_s, self.hour_s)
        self.trend = Rate(TREND_H * self.hour_s, self.hour_s)
        self._count = 0
        self._window: collections.deque[Visit] = collections.deque()
        self._window_visits: collections.Counter[int] = collections.Counter()   # per stop key, its visits in it
        self._relearn_set: list[Stop] = []
        self._before_alarm = 0                   # the re-learn's first samples that are from before its alarm
        self._settle = snap.settle
        self._drifting = False
        self._quiet_since: float | None = None     # since when a raised drift has been back under the line
        self._drift_factor: tuple[InUse | None, np.ndarray | None] = (None, None)
        self._alarms: collections.deque[tuple[int, float, AlarmLevel]] = collections.deque(maxlen=MAX_ALARMS)
        self.state = EngineState.SETTLING if snap.settle else EngineState.WARMING
        self.detector.reset()
        self.detector.shared_var = ref.shared_var

    def disarm(self) -> None:
        """Forget the calibration and everything learnt since (`arm` again to go on)."""
        self.reference = self.origin = self.in_use = self.filter = None
        self.state = EngineState.WARMING

    @property
    def armed(self) -> bool:
        return self.reference is not None

    @property
    def samples_until_tested(self) -> int:
        """Samples before the *moved* test runs again (0: it runs): the detector's first three innovations after
        arming or a re-learn (two points cannot separate a 6-dof move)."""
        return max(3 - self.detector.count, 0) if self.armed else 0

    @property
    def n_factor(self) -> int:
        """Robot kinematic-error parameters in the state (0: none)."""
        return self.model.layout.n_factor if self.armed else 0

    @property
    def state_size(self) -> int:
        """Floats held (bounded: independent of the stream length)."""
        per_sample = 16 + 3 + 9 + 6 * self.n_factor
        f = self.filter
        state = 16 + len(f.u) + f.P.size
        return (state + self.detector.state_size + per_sample * len(self._relearn_set)
                + (per_sample + 3 + state) * len(self._window) + 31 * self.stops.count + 3 * len(self._alarms))

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
            Its covariance shape, m^2, positive definite (default: `handeye.calib.noise`'s depth model).
        robot_factor : array_like, shape (6, P), optional
            The kinematic-error factor at its joints (needed when armed with one).

        Raises
        ------
        CalibrationError
            Not armed, or a malformed sample (nothing changes).
        """
        s = self._sample(t, T_base_flange, point_cam, point_cov, robot_factor)
        self._count += 1
        if self.filter.slots is not self._walk_slots:     # a re-learn, or a return to the state before a move
            self._walk_for(self.filter.slots)
        f, slot = self._slot(predict(self.filter, s.t, self.walk), s)
        if f.slots is not self._walk_slots:
            self._walk_for(f.slots)
        s.walk_t = f.walk_t
        inn = innovate(f, s.pose, s.point, s.shape_upper, s.factor, self.model, slot)
        s.w = tuple(f.u[-6:].tolist())
        relearning = self.state == EngineState.RELEARNING
        if not relearning and inn.nis < NIS_GATE:
            f, self.noise_track = follow_noise(f, self.noise_track, inn.nis, inn.share)
        self.filter = f
        r0, r1, r2 = inn.r
        verify = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2) * 1e3   # |R_C r|: the prediction error in C's parent frame
        if relearning and inn.nis > GROSS_NIS:
            alarm, statistic, message = AlarmLevel.NONE, 0.0, wild_point(inn.nis)
        elif relearning:
            self._relearn_set.append(s)
            trimmed = max(len(self._relearn_set) - self.settings.relearn_samples, 0)
            del self._relearn_set[:trimmed]
            self._before_alarm = max(self._before_alarm - trimmed, 0)
            message, again = self._relearn()
            alarm, statistic = (AlarmLevel.MOVED if again else AlarmLevel.NONE), 0.0
        else:
            alarm, statistic, message = self._test(s, inn, f.slots[slot])
        self.state = self._next_state()
        return self._figures(s, alarm, message, np.array(inn.r), inn.nis, verify, statistic)

    def _against_stop(self, i: int, s: Stop, ref: FilterState, Hc, r=None) -> tuple:
        """Sample ``s``'s marker point against its stop ``i``'s earlier visits (3 floats): its change from their
        mean, less the change the camera's walk since them explains.

        ``ref`` is the state the sample is judged at, ``Hc`` (3, 6) the
        point's Jacobian w.r.t. the camera transform and ``r`` the sample's
        innovation at ``ref`` (None: not computed yet). What the visits share
        (the systematic errors at that place) cancels. The walk the filter
        followed between those visits and ``ref`` (its walk states' change:
        the drift, not what the filter has since learnt about the
        calibration) is taken off, so that a stop's baseline does not lag a
        drifting camera. ``ref`` is the state from before the detector's
        window (`_test`) or from before the move (`_rows`): the filter has
        fused the window's samples, which takes part of a move away into its
        live walk.

        A stop repeated only roughly (vision-guided picks, a pallet's
        pattern: each visit a few mm or cm off the last) has its mean point
        carried from the visits' mean pose to this one by the model at
        ``ref``: the innovation less the stop's mean innovation there."""
        stops = self.stops
        m0, m1, m2 = stops.mean[i]
        pose = stops.pose_mean[i]
        d0, d1, d2 = Hc.dot(np.subtract(ref.u[-6:], stops.mean_w[i])).tolist()
        p0, p1, p2 = s.point
        if max(abs(a - b) for a, b in zip(pose, s.pose)) <= SAME_POSE_TOL:
            return p0 - m0 - d0, p1 - m1 - d1, p2 - m2 - d2
        if r is None:
            (h0, h1, h2), _, _ = prediction(ref, s.pose, s.factor, self.model)
            r = p0 - h0, p1 - h1, p2 - h2
        (h0, h1, h2), _, _ = prediction(ref, pose, s.factor, self.model)
        r0, r1, r2 = r
        return r0 - (m0 - h0) - d0, r1 - (m1 - h1) - d1, r2 - (m2 - h2) - d2

    def _test(self, s: Stop, inn, held: tuple) -> tuple[AlarmLevel, float, str]:
        """The *moved* test of a sample (its stop's error held in the slot of pose ``held``): ``(alarm, statistic,
        message)``; fused if it passes, else the re-learn starts."""
        stops = self.stops
        i = stops.lookup(s)
        S_inv = sym3(inn.S_inv)
        r_test, S_test_inv, test_inv, offset_var, stop_id = inn.r, S_inv, inn.S_inv, None, None
        Hc = inn.H[:, :6]
        baseline = i is not None and stops.n[i] >= MIN_BASELINE
        if baseline:
            # Against the stop's own earlier visits: what they share (unmodelled errors of the robot or the
            # camera at that pose, the estimate's own error) is no change; only the camera moving is.
            ref = self._window[0].state if self._window else self.filter
            # (the model's innovation: the stop's own error cancels in the comparison)
            model_r = tuple(a + b for a, b in zip(inn.r, inn.bias))
            r_test = self._against_stop(i, s, ref, Hc, model_r if ref is self.filter else None)
            # The camera may have walked since the reference state by the same for every stop, and the filter
            # followed the walk since the stop's visits only to within its own lag: the long window's test is for
            # a move beyond the random walk over the window.
            offset_var = self.walk.variance(s.walk_t - ref.walk_t)
            # The m visits of this stop in the window share the error of its mean of n earlier visits: their sum
            # has the variance of m samples each of (1 + m / n) times the noise, not (1 + 1 / n).
            stop_id = stops.ids[i]
            k = 1.0 + (self._window_visits[stop_id] + 1) / stops.n[i]
            R = inn.R
            (a, b, c), (_, d, e), (_, _, f) = (Hc * offset_var).dot(Hc.T).tolist()
            test_inv = inv_sym3_floats(a + k * R[0], b + k * R[1], c + k * R[2], d + k * R[3], e + k * R[4],
                                       f + k * R[5])
            S_test_inv = sym3(test_inv)
        elif (carried := self._priors.get(held, (None,) * 4)[3]) is not None:
            r_test, test_inv = self._without_carried(inn, *carried)
            S_test_inv = sym3(test_inv)
        # While a re-learnt camera settles, its stops have no baselines yet: the test is against the model, whose
        # innovation covariance holds the re-learnt camera's, so the stops refining it are no move; a second
        # knock is.
        fired = self.detector.update(r_test, S_test_inv, Hc, offset_var, shared=not baseline)
        statistic = self.detector.statistic
        (r0, r1, r2), (i0, i1, i2, i3, i4, i5) = r_test, test_inv
        nis = ((r0 * i0 + r1 * i1 + r2 * i2) * r0 + (r0 * i1 + r1 * i3 + r2 * i4) * r1
               + (r0 * i2 + r1 * i4 + r2 * i5) * r2)
        if not fired:
            fused = fuse(self.filter, inn.PHt, S_inv, inn.r)
            self._window.append(Visit(s, self.filter, nis, stop_id))
            if stop_id is not None:
                self._window_visits[stop_id] += 1
            self.filter = fused
            if len(self._window) > self.settings.detector.window:
                old = self._window.popleft()
                if old.stop_id is not None:
                    self._window_visits[old.stop_id] -= 1
                stops.add(old.sample)
            return AlarmLevel.NONE, statistic, ""
        message = (f"camera moved (GLR statistic {statistic:.1f} > {self.detector.threshold:.1f}); "
                   "re-learning it from the production stops")
        # The move lies inside the window, most likely `onset` samples ago (at least 3: the GLR's fewest). A sample
        # since then that the state before it cannot explain on its own (`ONSET_GATE`) is after the move: a clear
        # move starts at the earliest such sample, and the samples before it stay out of the re-learn. Go back to
        # the state before the move (the clock and the noise level as they are now) and re-learn from the samples
        # since; those before it join their stops.
        window = list(self._window)
        before = max(len(window) + 1 - self.detector.onset(), 0)
        tail = [v.nis for v in window[before:]] + [nis]
        before += next((k for k, x in enumerate(tail) if x > ONSET_GATE), 0)
        if before < len(window):
            now = self.filter
            self.filter = window[before].state._replace(t=now.t, walk_t=now.walk_t, scale=now.scale)
        for v in window[:before]:
            stops.add(v.sample)
        # A point a thousand sigma off is a glitch that fired the test, or a move too large to re-learn: either
        # way no sample to re-learn from.
        self._relearn_set = [v.sample for v in window[before:]] + ([s] if nis <= GROSS_NIS else [])
        # A count, not the samples' ids: a trimmed sample's id is free for a later one, which then passed as from
        # before the alarm (the state machine's outcome followed what the process had allocated before it).
        self._before_alarm = len(window) - before
        self._window.clear()
        self._window_visits.clear()
        self.state = EngineState.RELEARNING
        self._drifting = False
        return AlarmLevel.MOVED, statistic, message + "; " + self._relearn()[0]

    @staticmethod
    def _without_carried(inn, carried, V) -> tuple:
        """A new stop of a source without joints, tested against the model: its innovation with the error its
        neighbours' errors told of it when its slot opened (``carried`` (3,), `_open`) added back, and the inverse
        of its covariance with that estimate's variance ``V`` (3, 3) allowed for (upper triangle). Right after a
        knock those neighbours have taken part of it in as the robot's error, which would carry it into this
        prediction and out of the test: the ETH recordings' knocks flagged, 6/20 and 9/20 with it, 12/20 and 16/20
        without (docs/benchmarks.md)."""
        (m0, m1, m2), (r0, r1, r2) = carried, inn.r
        (a, b, c), (_, d, e), (_, _, f) = (np.linalg.inv(sym3(inn.S_inv)) + V).tolist()
        return (r0 + m0, r1 + m1, r2 + m2), inv_sym3_floats(a, b, c, d, e, f)

    def _next_state(self) -> EngineState:
        """The engine's state after a sample; counts the settling window down."""
        if self.state == EngineState.RELEARNING:
            return EngineState.RELEARNING
        if self._settle:
            # Just re-learnt: what the next stops add refines that calibration, it is no drift.
            self._settle -= 1
            self._use_estimate()
            return EngineState.SETTLING
        return EngineState.ARMED if self.detector.count >= 3 else EngineState.WARMING

    def _use_estimate(self) -> None:
        """The live estimate becomes the calibration in use: no walk since it, the Jacobians taken at it."""
        f = self.filter
        theta = f.u[3:6].copy()
        self.in_use = InUse(f.C.copy(), theta, self.workspace.sigma(f.C, theta, f.P) * 1e3)
        self.filter = relinearize(restart_walk(f))

    def _sample(self, t, T_base_flange, point_cam, point_cov, robot_factor) -> Stop:
        if not self.armed:
            raise CalibrationError("the monitoring engine is not armed: give it a calibration result first")
        # Float arrays of the right shape are checked on the spot, as floats; anything else goes through the
        # validators (their checks and messages).
        pose = plain_transform(T_base_flange)
        if pose is None:
            A = tf.check_transform(T_base_flange, "T_base_flange")
            pose = A[:3].ravel().tolist()
        else:
            A = T_base_flange.copy()
        point = plain_point(point_cam)
        if point is None:
            p = tf.check_points(np.asarray(point_cam, dtype=float).reshape(1, -1), "point_cam")[0]
            point = tuple(p.tolist())
        else:
            p = point_cam.copy()
        upper = None if point_cov is None else plain_cov(point_cov)
        if upper is None:
            shape = default_point_cov(p[None])[0] if point_cov is None else model.check_point_cov(point_cov, 1)[0]
            (a, b, c), (_, d, e), (_, _, f) = shape.tolist()
            upper = a, b, c, d, e, f
        else:
            shape = point_cov.copy()
        if not is_positive_definite3(*upper):
            raise CalibrationError("point_cov is not positive definite (a point covariance, m^2)")
        factor = None
        n_factor = self.n_factor
        if n_factor:
            if robot_factor is None:
                raise CalibrationError("the engine was armed with the robot's kinematic error: every sample "
                                       "needs its robot_factor (6, P)")
            factor = robot_factor.copy() if is_plain(robot_factor, (6, n_factor)) else tf.as_real_array(
                robot_factor, "robot_factor")
            if factor.shape != (6, n_factor):
                raise CalibrationError(f"robot_factor must have shape (6, {n_factor}), got {factor.shape}")
        last = self.filter.t
        if not math.isfinite(t) or t < last - 1e-9:
            raise CalibrationError(f"t must be finite and not before the previous sample's ({last}), got {t}")
        return Stop(A, p, shape, factor, float(t), pose, point, upper)

    # ------------------------------------------------------------------ stops

    def _same_stop(self, A1, A2) -> bool:
        """Two flange poses closer than `MonitorSettings.stop_translation_m` and ``stop_rotation_deg``."""
        rot, trans = tf.pose_error(A1, A2)
        return bool(trans < self.settings.stop_translation_m and rot < np.deg2rad(self.settings.stop_rotation_deg))

    def _held(self, f: FilterState, s: Stop) -> int | None:
        """The slot holding ``s``'s stop's own error in ``f``, or None."""
        return find_slot(f, lambda pose: self.stops.same(pose, s.pose))

    def _slot(self, f: FilterState, s: Stop) -> tuple[FilterState, int]:
        """The state with ``s``'s stop's own error held (`handeye.calib.monitor.filter.open_slot`: a new stop's at its prior,
        `stop_prior`), and its slot; what a visit tells of the camera noted for the walk (`_walk_for`)."""
        k = self._held(f, s)
        if k is not None and f.slots[k] in self._info:
            return visit_slot(f, k), k
        _, H, cof = prediction(f, s.pose, s.factor, self.model)
        Hc = H[:, :6]
        if k is None:
            f, k = self._open(f, s, cof)
        else:
            f = visit_slot(f, k)
        self._info[f.slots[k]] = Hc.T.dot(np.linalg.solve(sym3(noise(f, s.shape_upper, cof, self.model)), Hc))
        return f, k

    def _open(self, f: FilterState, s: Stop, cof) -> tuple[FilterState, int]:
        """`open_slot` for ``s``'s new stop: its own error at `stop_prior`, and for a source without joints the
        robot's error it shares with the held stops (`MonitorSettings.robot_accuracy_mm`).

        That shared error is a field over the flange positions, 1-sigma ``a`` per axis in the base frame with
        correlation ``exp(-d^2 / 2 L^2)`` (`SHARED_ERROR_LENGTH_M`); a stop sees it in the camera frame through
        ``Q`` (3, 3): ``R_C^T`` eye-to-hand, ``-R_C^T R_A^T`` eye-in-hand. The prior of two stops' errors is then
        ``a^2 k_ij Q_i Q_j^T`` off the diagonal and their own plus ``a^2 I`` on it, and the new one is regressed on
        the held ones (`open_slot`): a program's stops, visited a thousand times, tell the camera no more than
        one robot error they share allows, and a stop that comes back after its slot was taken starts from what
        its neighbours know."""
        a2 = (self.settings.robot_accuracy_mm * 1e-3) ** 2 if self.n_factor == 0 else 0.0
        R_C = f.C[:3, :3]
        Q = R_C.T if self.model.eye_to_hand else -R_C.T.dot(s.A[:3, :3].T)
        prior = self.stop_prior(cof) + a2 * np.eye(3)
        here = (prior, s.A[:3, 3].copy(), Q)
        k = next_slot(f)
        held = [j for j, pose in enumerate(f.slots) if j != k and pose in self._priors]
        shared = carried = None
        if a2 > 0.0 and held:
            K = np.zeros((3 * len(held),) * 2)
            K_new = np.zeros((3, 3 * len(held)))
            known = [self._priors[f.slots[j]] for j in held]
            for i, (S_i, p_i, Q_i, _) in enumerate(known):
                K[3 * i:3 * i + 3, 3 * i:3 * i + 3] = S_i
                for j in range(i + 1, len(known)):
                    _, p_j, Q_j, _ = known[j]
                    block = a2 * self._shared(p_i, p_j) * Q_i.dot(Q_j.T)
                    K[3 * i:3 * i + 3, 3 * j:3 * j + 3] = block
                    K[3 * j:3 * j + 3, 3 * i:3 * i + 3] = block.T
                K_new[:, 3 * i:3 * i + 3] = a2 * self._shared(here[1], p_i) * Q.dot(Q_i.T)
            G = np.linalg.solve(K, K_new.T).T
            rest = prior - G.dot(K_new.T)
            shared, prior = (G, held), 0.5 * (rest + rest.T)
            # What the held stops' errors tell of this one (`_test`): G u_held, whose variance is what they have
            # learnt, G (K - P_held) G^T.
            rows = np.concatenate([layout_of(f).slot(j) + np.arange(3) for j in held])
            V = G.dot(K_new.T) - G.dot(f.P[np.ix_(rows, rows)]).dot(G.T)
            carried = G.dot(f.u[rows - 6]), 0.5 * (V + V.T)
        f, k = open_slot(f, s.pose, prior, shared)
        self._priors[f.slots[k]] = here + (carried,)
        return f, k

    @staticmethod
    def _shared(p_i, p_j) -> float:
        """The share of the robot's error two stops at flange positions ``p_i``, ``p_j`` (3,) have in common."""
        d = p_i - p_j
        return math.exp(-0.5 * float(d.dot(d)) / SHARED_ERROR_LENGTH_M ** 2)

    def _walk_for(self, slots: tuple) -> None:
        """The camera's walk in the directions one visit of each held stop observes (`observed_walk`)."""
        self._info = {pose: self._info[pose] for pose in slots if pose in self._info}
        self._priors = {pose: self._priors[pose] for pose in slots if pose in self._priors}
        info = sum(self._info.values(), np.zeros((6, 6)))
        self.walk = Walk.of(Layout(self.model.layout.n_factor, len(slots)), self._q,
                            observed_walk(self._q, info, self.hour_s), self.settings.walk_max_gap_h * self.hour_s)
        self._walk_slots = slots

    def stop_prior(self, cofactor) -> np.ndarray:
        """Covariance (3, 3) of a stop's own error, camera frame, m^2, from the robot cofactor at the stop (upper
        triangle): the robot's noise level of the arming (all of its error a pose repeats) and
        `MonitorSettings.stop_error_mm` on each axis."""
        floor = (self.settings.stop_error_mm * 1e-3) ** 2
        return self.model.robot_var * sym3(cofactor) + floor * np.eye(3)

    def _distinct(self, samples) -> list[Stop]:
        out = []
        for s in samples:
            if not any(self._same_stop(o.A, s.A) for o in out):
                out.append(s)
        return out

    # ------------------------------------------------------------------ re-learning

    def _relearn(self) -> tuple[str, bool]:
        """Estimate the move from the samples since it; when the stops determine it, the filter goes on from
        there and re-arms. Returns what happened or what is missing, in plain words, and whether the camera moved
        again since the alarm (its own alarm).

        Stops visited `MIN_BASELINE` times before the
        move (three of them, not on one line) give the move itself: their
        innovations' change, with what the stop shares with its earlier
        visits cancelled (`_jump`). Otherwise a rigid registration of the
        stops' marker points (`_register`) from `REGISTRATION_SAMPLES`
        samples. A fit whose residuals the noise does not explain still had a
        sample from before the move in it: the oldest is dropped and the fit
        tried again.
        """
        samples = self._relearn_set
        while True:
            fit = self._fit(samples)
            if isinstance(fit, Waiting):
                return fit.reason, False
            if fit.consistent:
                break
            samples = samples[1:]         # the oldest is from before the move
        dropped = len(self._relearn_set) - len(samples)
        if dropped > self._before_alarm:
            # Samples taken after the alarm do not fit the camera the newer ones show: it moved again (a second
            # knock while the first was re-learnt). Its own alarm; where between them it moved is not known, so the
            # re-learn starts again from the newest sample (a fit that kept one from before the knock was off by
            # the knock, and a third alarm followed).
            self._relearn_set, self._before_alarm = self._relearn_set[-1:], 0
            return (f"camera moved again while re-learning (the {dropped} oldest of {dropped + len(samples)} "
                    "samples since the move do not fit the newer ones); re-learning it from the next stops"), True
        f = fit.state
        sigma_mm = self.workspace.sigma(f.C, f.u[3:6], f.P) * 1e3
        # A registration from a few stops may not yet determine the camera to what a plant can use: the tolerance,
        # or what the arming calibration itself was good for when that is less (its marker mount and camera
        # correction are held, so the re-learnt camera cannot be better than they allow).
        enough = max(self.settings.tolerance_mm, 1.5 * self.reference.sigma_mm)
        if fit.how == "registered" and sigma_mm > enough and not self._saturated(samples):
            return (f"re-learning: registered from {len(samples)} samples, but its 1-sigma over the workspace is "
                    f"{sigma_mm:.1f} mm (it must be within {enough:.1f} mm): waiting for more stops, spread across "
                    "the workspace"), False
        before = self.filter.C
        moved_mm = workspace_distance(f.C, before, self.reference.workspace) * 1e3
        moved_deg = float(np.rad2deg(tf.rotation_angle(f.C[:3, :3] @ before[:3, :3].T)))
        self.stops.clear()        # the stops' marker points as the old camera saw them
        self.filter = f
        self._use_estimate()
        self.relearns += 1
        self.rate.reset()
        self.trend.reset()
        self._settle = self.settings.detector.window
        self.state = EngineState.SETTLING
        self._relearn_set, self._before_alarm = [], 0
        self.detector.reset()
        short = (f"; its 1-sigma over the workspace is {sigma_mm:.1f} mm, more than the {enough:.1f} mm the cell "
                 "needs, and the program's stops cannot determine it better: calibrate again"
                 if sigma_mm > enough else "")
        return (f"re-learnt the camera ({fit.how} {len(self._distinct(samples))} production stops, {len(samples)} "
                f"samples): it moved {moved_mm:.1f} mm over the workspace and {moved_deg:.2f} deg" + short), False

    def _fit(self, samples) -> Fit | Waiting:
        """The camera from ``samples``: the move measured at stops with a baseline (`_jump`), else registered
        (`_register`, `_refit`), or why neither is possible yet."""
        waiting = self._spread(self._distinct(samples), "since the move")
        if waiting is not None:
            return waiting
        fit = self._jump(samples)
        if isinstance(fit, Fit):
            return fit
        if len(samples) < REGISTRATION_SAMPLES:
            return Waiting(f"re-learning: {fit.reason}; registering the camera from the samples since the move "
                           f"instead needs {REGISTRATION_SAMPLES} of them ({len(samples)} so far)")
        return self._refit(self._register(samples), samples)

    def _spread(self, distinct: list[Stop], since: str) -> Waiting | None:
        """Why the ``distinct`` stops cannot determine the camera transform (None when they can): fewer than
        three, or on one line."""
        if len(distinct) < 3:
            return Waiting(f"re-learning: {len(distinct)} distinct stop{'s' if len(distinct) != 1 else ''} "
                           f"{since}, 3 not on one line are needed")
        y = np.array([self._parent_point(s) for s in distinct])
        _, sv, Vt = np.linalg.svd(y - y.mean(axis=0), full_matrices=False)
        spread = sv[1] / math.sqrt(len(y))
        if spread < self.settings.min_spread_m:
            frame = "base" if self.reference.setup == Setup.EYE_TO_HAND else "flange"
            return Waiting(f"re-learning: the {len(distinct)} stops {since} lie on a line (spread across it "
                           f"{spread * 1e3:.1f} mm): a stop {self.settings.min_spread_m * 2e3:.0f} mm or more off "
                           f"the line along {np.round(Vt[0], 2).tolist()} ({frame} frame) would determine the camera")
        return None

    def _rows(self, samples) -> tuple[list, list]:
        """The samples at stops with a baseline (`MIN_BASELINE` visits before the move), as rows ``(k, r, H, W)``
        of the move's least squares (``k`` the sample's place in ``samples``; ``r`` the marker point's change at
        its stop, `_against_stop`, ``H`` its Jacobian (3, 6) w.r.t. the camera transform, ``W`` its weight),
        and the visits from before the move of the stops that have none."""
        measured, short = [], []
        stops = self.stops
        for k, s in enumerate(samples):
            i = stops.lookup(s)
            if i is None:
                continue
            if stops.n[i] < MIN_BASELINE:
                short.append(int(stops.n[i]))
                continue
            measured.append((k, i))
        # The m samples of a stop share the error of its mean of n earlier visits (as in `_test`).
        visits = collections.Counter(i for _, i in measured)
        rows = []
        for k, i in measured:
            s = samples[k]
            r, H, R = linearize(self.filter, s, self.model, None)
            rows.append((k, np.array(self._against_stop(i, s, self.filter, H[:, :6], r)), H[:, :6],
                         np.linalg.inv(R * (1.0 + visits[i] / stops.n[i]))))
        return rows, short

    @staticmethod
    def _jump_prior() -> np.ndarray:
        """The information of a bump's prior (`JUMP_PRIOR`): where the stops cannot tell a turn of the camera from a
        shift (one marker seen from the front, eye-in-hand), the estimate stays small instead of trading the two
        without bound."""
        st, sr = JUMP_PRIOR
        return np.diag([1.0 / sr**2] * 3 + [1.0 / st**2] * 3)

    def _jump(self, samples) -> Fit | Waiting:
        """The move from the innovations' change at stops with a baseline (`MIN_BASELINE` visits before the move).

        Weighted least squares of ``p_i - mean_stop = H_i delta`` (the marker
        point's change at its stop, `_against_stop`) at the estimate from
        before the move, over the samples at such stops (`_rows`); those
        stops must be three not on one line (else `Waiting` says which have
        too few visits). Consistent when the fit's chi-square agrees with the noise.
        """
        rows, short = self._rows(samples)
        measured = self._distinct([samples[k] for k, _, _, _ in rows])
        waiting = self._spread(measured, f"with {MIN_BASELINE} visits from before the move")
        if waiting is not None:
            if short:
                visits = min(short)
                return Waiting(f"{len(measured)} of the stops seen since the move have {MIN_BASELINE} visits from "
                               f"before it to measure the move against (one seen since has {visits} visit"
                               f"{'s' if visits != 1 else ''} from before it)")
            return Waiting(waiting.reason.removeprefix("re-learning: "))
        prior = self._jump_prior()
        N = prior + sum(H.T @ W @ H for _, _, H, W in rows)
        g = sum(H.T @ W @ r for _, r, H, W in rows)
        cov = np.linalg.inv(N)
        d = cov @ g
        chi = sum(float((r - H @ d) @ W @ (r - H @ d)) for _, r, H, W in rows) + float(d @ prior @ d)
        dof = 3 * len(rows) - 6
        consistent = dof <= 0 or chi <= chi2.ppf(RELEARN_QUANTILE, dof)
        f = self.filter
        C = tf.make_transform(tf.so3_exp(d[:3]) @ f.C[:3, :3], f.C[:3, 3] + d[3:])
        P = f.P.copy()
        P[:6, :6] += 0.5 * (cov + cov.T)
        return Fit(f._replace(C=C, P=P, parts=parts(C)), "measured at", consistent)

    def _saturated(self, samples) -> bool:
        """Every stop among ``samples`` is visited `MIN_BASELINE` times or more: further visits of the same stops
        would not determine the camera better (each stop's own error bounds what they tell), only new stops
        would."""
        distinct = self._distinct(samples)
        visits = collections.Counter(next(k for k, d in enumerate(distinct) if self._same_stop(d.A, s.A))
                                     for s in samples)
        return min(visits.values()) >= MIN_BASELINE

    def _parent_point(self, s: Stop) -> np.ndarray:
        M = s.A if self.reference.setup == Setup.EYE_TO_HAND else tf.invert(s.A)
        return M[:3, :3] @ self.reference.K[:3, 3] + M[:3, 3]

    def _register(self, samples) -> np.ndarray:
        """Rigid registration of the corrected camera points to the held marker mount's points (Kabsch)."""
        corr = model.CameraCorrection(*self.in_use.theta)
        c = corr.correct(np.array([s.p for s in samples]))
        return tf.register_points(c, np.array([self._parent_point(s) for s in samples]))

    def _refit(self, C, samples) -> Fit:
        """The filter over ``samples`` from a registration ``C``.

        The camera transform starts at `RELEARN_PRIOR`, independent of the rest
        of the state, which keeps its covariance (and its estimate: only the
        camera transform and the covariance are taken from the fit), but for
        the stops' own errors, which start again at their priors.
        """
        st, sr = RELEARN_PRIOR
        saved = self.filter
        f = saved._replace(C=C, parts=parts(C))
        P = clear_slots(saved).P
        P[:6] = 0.0
        P[:, :6] = 0.0
        P[:6, :6] = np.diag([sr * sr] * 3 + [st * st] * 3)
        for _ in range(2):            # once more from the first pass's estimate: the registration is unweighted
            f = clear_slots(f)._replace(P=P)
            try:
                for s in samples:
                    f, k = self._slot(f, s)
                    f = fuse_linear(f, *linearize(f, s, self.model, k))
            except FilterDivergedError:
                return Fit(saved, "registered", False)    # these samples do not hold together: drop the oldest
        chi = 0.0
        for s in samples:
            r, H, R = linearize(f, s, self.model, self._held(f, s))
            chi += float(r @ np.linalg.solve(R + H[:, 6:] @ f.P[6:, 6:] @ H[:, 6:].T, r))
        dof = 3 * len(samples) - 6
        consistent = dof <= 0 or chi <= chi2.ppf(RELEARN_QUANTILE, dof)
        return Fit(f, "registered", consistent)

    # ------------------------------------------------------------------ figures

    def _drift_of(self, in_use: InUse) -> np.ndarray:
        """`WorkspaceMoments.drift_factor` of the calibration in use (once per calibration in use)."""
        held, factor = self._drift_factor
        if held is not in_use:
            factor = self.workspace.drift_factor(in_use.C, in_use.theta)
            self._drift_factor = in_use, factor
        return factor

    def _figures(self, s: Stop, alarm, message, r, nis, verify, statistic) -> MonitorUpdate:
        cfg, in_use, f, state = self.settings, self.in_use, self.filter, self.state
        # The drift: the camera's walk since the calibration in use, not what the samples have refined since.
        w0, w1, w2, w3, w4, w5 = f.u[-6:].tolist()
        delta = (w0, w1, w2, w3, w4, w5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        moved = tuple(self._drift_of(in_use).dot(delta).tolist()) if any(delta) else (0.0,) * 12
        drift_m = math.hypot(*moved)
        drift_deg = math.degrees(math.sqrt(w0 * w0 + w1 * w1 + w2 * w2))
        sigma = self.workspace.sigma(f.C, f.u[3:6], f.P)
        error_mm = math.hypot(drift_m * 1e3, in_use.sigma_mm)
        rate_mm = rate_deg = hours = None
        if state == EngineState.ARMED:
            # The workspace points' displacement is linear in the drift: its slope gives the drift rate.
            self.rate.add(s.t, moved + (drift_deg, drift_m))
            self.trend.add(s.t, (drift_m,))
            slope, trend = self.rate.slope(), self.trend.slope()
            if slope is not None:
                rate_mm = math.hypot(*slope[:12]) * 1e3
                rate_deg = abs(slope[12])
                growth = slope[13] * 1e3
                if growth > 0 and drift_m * 1e3 < cfg.tolerance_mm:
                    hours = (cfg.tolerance_mm - drift_m * 1e3) / growth
                    if trend is not None:
                        # A day of samples: the rise must hold over the day too. A mount's daily thermal cycle
                        # rises for half a day and falls back (bounded: no crossing ahead); a drift rises all day.
                        day = trend[0] * 1e3
                        hours = max(hours, (cfg.tolerance_mm - drift_m * 1e3) / day) if day > 0 else None
        # Drifting: the camera has moved from the calibration in use by the tolerance, or will within the
        # horizon at the current rate (the calibration's own uncertainty is in error_mm, not an alarm).
        # Once raised it holds until the drift has stayed under half the tolerance, and not heading there within
        # twice the horizon, for a day: a drift hovering at the line, or a mount's daily cycle touching it every
        # day, is one alarm, not one per crossing.
        held = 0.5 if self._drifting else 1.0
        over = state == EngineState.ARMED and (drift_m * 1e3 >= held * cfg.tolerance_mm
                                               or (hours is not None and hours <= cfg.horizon_h / held))
        if over or not self._drifting:
            self._quiet_since = None
        elif self._quiet_since is None:
            self._quiet_since = s.t
        drifting = over or (self._drifting and state == EngineState.ARMED
                            and s.t - self._quiet_since < TREND_H * self.hour_s)
        if drifting and not self._drifting and not alarm:
            alarm = AlarmLevel.DRIFTING
            when = "now" if hours is None else f"in {hours:.1f} h at {rate_mm:.2f} mm/h"
            message = (f"camera drifting: {drift_m * 1e3:.2f} mm over the workspace from the calibration in use "
                       f"(predicted error {error_mm:.2f} mm), tolerance {cfg.tolerance_mm:g} mm reached {when}")
        self._drifting = drifting
        if alarm:
            self._alarms.append((self._count, s.t, alarm))
        level = (AlarmLevel.MOVED if alarm == AlarmLevel.MOVED or state == EngineState.RELEARNING
                 else AlarmLevel.DRIFTING if drifting else AlarmLevel.NONE)
        return MonitorUpdate(self._count, s.t, state, alarm, level, f.C.copy(), f.P[:6, :6].copy(), r, nis,
                             verify, statistic, drift_m * 1e3, drift_deg, rate_mm, rate_deg, error_mm, hours,
                             sigma * 1e3, message)

    def moved_since(self, calibration: InUse) -> tuple[float, float]:
        """How far the live estimate is from a calibration (e.g. `origin`: the camera's total move since the
        cell's first calibration): RMS over the workspace points, mm, each with its camera correction, and the
        rotation angle, deg."""
        f = self.filter
        corrected = model.CameraCorrection(*calibration.theta).correct(self.reference.workspace)
        a = tf.transform_points(calibration.C, corrected)
        b = tf.transform_points(f.C, model.CameraCorrection(*f.u[3:6]).correct(self.reference.workspace))
        mm = float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1)))) * 1e3
        return mm, float(np.rad2deg(tf.rotation_angle(f.C[:3, :3] @ calibration.C[:3, :3].T)))

    @property
    def camera_transform(self) -> np.ndarray:
        """Live ``T_base_cam`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand)."""
        return self.filter.C.copy()

    @property
    def cov(self) -> np.ndarray:
        """Its covariance (6, 6), `handeye.calib.result` convention."""
        return self.filter.P[:6, :6].copy()

    @property
    def camera_correction(self) -> model.CameraCorrection:
        """The live camera correction (refined by every sample; held through a re-learn)."""
        return model.CameraCorrection(*self.filter.u[3:6])

    @property
    def alarms(self) -> list[tuple[int, float, AlarmLevel]]:
        """``(sample index, t, level)`` of the newest `MAX_ALARMS` alarms since arming."""
        return list(self._alarms)

    def result(self) -> CalibrationResult:
        """The live estimate as a `CalibrationResult` (``method`` ``"auto+monitor"``).

        Live camera transform, marker-side translation and camera correction;
        the marker-side rotation and the noise levels of the arming result.
        Per-sample residuals are not kept.
        """
        ref, f = self.reference, self.filter
        K = tf.make_transform(ref.K[:3, :3], f.u[:3])
        X, Y = model.join(f.C, K, ref.setup)
        sig = np.sqrt(np.diag(f.P)[9:12])
        base = ref.result.auto
        estimated = base.camera_correction if base is not None else {}
        correction = {name: CameraParameter(value=float(f.u[3 + i]), sigma=float(sig[i]),
                                            estimated=name in estimated and estimated[name].estimated)
                      for i, name in enumerate(model.CAMERA_PARAMS)}
        # The arming result's model, with the live camera correction; its notes were about the arming fit.
        details = None if base is None else dataclasses.replace(base, camera_correction=correction, notes=(),
                                                                blocked_folds=None)
        return CalibrationResult(method="auto+monitor", setup=ref.setup, X=X, Y=Y, n_samples=self._count,
                                 residuals=Residuals(translation=np.zeros(0)), cov=self.cov,
                                 marker_rotation_known=ref.result.marker_rotation_known, auto=details)
