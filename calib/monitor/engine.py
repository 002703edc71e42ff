"""`MonitorEngine`: the filter, the change test, the re-learn after a move, and the figures of each update."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from calib import model
from calib import transforms as tf
from calib.errors import CalibrationError
from calib.noise import default_point_cov
from calib.change import ChangeDetector
from calib.problem import CalibrationProblem
from calib.result import CalibrationResult, CameraParameter, Residuals
from calib.setup import Setup
from calib.monitor.settings import MonitorSettings, MonitorUpdate
from calib.monitor.kernels import (inv_sym3, inv_sym3_floats, is_plain, matmul3, parts, plain_cov, plain_point,
    plain_transform, sample_floats, sample_model, so3_exp_scalar, sym3)
from calib.monitor.reference import Reference, WorkspaceMoments, arm_reference, workspace_distance
from calib.monitor.stops import HOUR_S, Rate, Stop, Stops, Visit


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


class MonitorEngine:
    """The monitoring engine (module docstring). ``arm`` it, then ``update`` it with every sample.

    State: the camera transform ``C`` (4, 4) and ``u = [t_K, theta, z, w]``
    (`arm_reference`; ``w`` (6,) the camera's walk since the calibration in
    use), with their joint covariance; a random walk moves ``C`` and ``w``
    together. Parameters: ``settings`` (`MonitorSettings`).
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
        self._eye_to_hand = ref.setup == Setup.EYE_TO_HAND
        self._point_scale, self._robot_var = ref.noise.point_scale, ref.noise.robot ** 2     # the arming's levels
        self._C = ref.C.copy()
        # The state after the camera transform: marker translation, camera correction, kinematic error, and the
        # camera's random walk since the calibration in use (`_predict`): the drift, told apart from what the
        # samples refine.
        self._nf = len(cov) - 12
        m = self._columns = len(cov)
        self._u = np.r_[ref.K[:3, 3], ref.theta, np.zeros(self._nf + 6)]
        self._P = np.zeros((m + 6, m + 6))
        self._P[:m, :m] = cov
        self._t = float(t)
        self._count = 0
        self._window: list[Visit] = []
        cfg = self.settings
        self._stops = Stops(cfg.stop_translation_m, np.deg2rad(cfg.stop_rotation_deg))
        self._relearn_set: list[Stop] = []
        # An hour of the camera's world on the samples' clock.
        self._hour_s = HOUR_S / cfg.time_scale
        self._rate = Rate(cfg.rate_window_h * self._hour_s, self._hour_s)
        self._workspace = WorkspaceMoments(ref.workspace)
        self._in_use = None, None, None         # the calibration in use: C, theta, its drift factor
        # The random walk's variance per hour (diagonal of the camera transform's block), and where it enters
        # the flat covariance: the camera's variances, the walk states', and the two equal cross terms.
        sr, st = np.deg2rad(cfg.walk_deg_per_sqrt_h), cfg.walk_mm_per_sqrt_h * 1e-3
        self._walk_per_h = np.array([sr * sr] * 3 + [st * st] * 3)
        n, i = m + 6, np.arange(6)
        self._walk_at = np.r_[i * (n + 1), (m + i) * (n + 1), i * n + m + i, (m + i) * n + i]
        self._walk_4 = np.tile(self._walk_per_h, 4)
        self._moved = False
        self._settle = 0
        self._noise_scale, self._scale_sum, self._scale_n = 1.0, 0.0, 0.0
        self._pending_scale = 1.0
        self._drifting = False
        self._alarms: list[tuple[int, float, str]] = []
        self.detector.reset()
        self.detector.shared_var = ref.shared_var
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
        return self._nf if self.reference is not None else 0

    @property
    def state_size(self) -> int:
        """Floats held (bounded: independent of the stream length)."""
        per_sample = 16 + 3 + 9 + 6 * self.n_factor
        state = 16 + len(self._u) + self._P.size
        return (state + self.detector.state_size + per_sample * len(self._relearn_set)
                + (per_sample + 3 + state) * len(self._window) + 31 * self._stops.count)

    # ------------------------------------------------------------------ the filter

    @property
    def _C(self) -> np.ndarray:
        """The camera transform (4, 4); ``_camera_parts`` holds it as `parts` for the per-sample model."""
        return self._camera

    @_C.setter
    def _C(self, C) -> None:
        self._camera, self._camera_parts = C, parts(C)

    def _linearize(self, C, u, s: Stop):
        """Innovation ``r`` (3,), Jacobian ``H`` (3, n) of the predicted point w.r.t. the state, noise ``R`` (3, 3)."""
        ref = self.reference
        h, H_model, cof = sample_model(C, u[:3], s.A, u[3:6], ref.setup, s.factor, u[6:6 + self._nf])
        H = np.zeros((3, len(self._P)))
        H[:, :self._columns] = H_model             # the walk states do not enter the measurement
        scale = self._noise_scale
        return s.p - h, H, (scale * ref.noise.point_scale) * s.shape + (scale * ref.noise.robot ** 2) * cof

    def _predict(self, t: float) -> None:
        """The noise level's change since the last sample (`_follow_noise`), then the random walk of the camera
        transform up to ``t``."""
        if self._pending_scale != 1.0:
            self._P = self._P * self._pending_scale      # a new array: the window's states hold the old one
            self._pending_scale = 1.0
        if t > self._t:
            # Every covariance the engine holds is a fresh contiguous array, so its flat view adds in place.
            # The walk moves the camera and the walk states alike: both variances and their covariance grow.
            self._P.reshape(-1)[self._walk_at] += self._walk_4 * ((t - self._t) / self._hour_s)
        self._t = max(t, self._t)

    def _fuse(self, r, H, R) -> None:
        """Kalman update of the whole state with innovation ``r``, Jacobian ``H`` and noise ``R`` (arrays)."""
        PHt = self._P.dot(H.T)
        self._gain(PHt, inv_sym3(H.dot(PHt) + R), r)

    def _gain(self, PHt, S_inv, r) -> None:
        """Kalman update from ``PHt = P H^T``, the innovation's inverse covariance (3, 3) and the innovation."""
        # ndarray.dot: the same BLAS products as @, with less call overhead on these small arrays.
        Kg = PHt.dot(S_inv)
        P = self._P - Kg.dot(PHt.T)          # a new array: the window's states hold the old one
        P += P.T
        P *= 0.5
        self._P = P
        d = Kg.dot(r)
        d0, d1, d2, d3, d4, d5 = d[:6].tolist()
        R, (x, y, z) = self._camera_parts
        r0, r1, r2 = matmul3(so3_exp_scalar(d0, d1, d2), R)
        t = (x + d3, y + d4, z + d5)
        self._camera = np.array(r0 + t[:1] + r1 + t[1:2] + r2 + t[2:] + (0.0, 0.0, 0.0, 1.0)).reshape(4, 4)
        self._camera_parts = (r0, r1, r2), t
        self._u = self._u + d[6:]

    def _state(self):
        return self._C, self._u, self._P

    def _restart_walk(self) -> None:
        """The calibration in use is the live estimate again: no walk since it."""
        m = self._columns
        if self._u[m - 6:].any() or self._P[m:].any():
            u, P = self._u.copy(), self._P.copy()         # new arrays: the window's states hold the old ones
            u[m - 6:] = 0.0
            P[m:] = 0.0
            P[:, m:] = 0.0
            self._u, self._P = u, P

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
        r, H, R = self._innovation(s)
        PHt = self._P[:, :self._columns].dot(H.T)
        (a, b, c), (_, d, e), (_, _, f) = H.dot(PHt[:self._columns]).tolist()
        S_inv = inv_sym3_floats(a + R[0], b + R[1], c + R[2], d + R[3], e + R[4], f + R[5])
        r0, r1, r2 = r
        i0, i1, i2, i3, i4, i5 = S_inv
        nis = ((r0 * i0 + r1 * i1 + r2 * i2) * r0 + (r0 * i1 + r1 * i3 + r2 * i4) * r1
               + (r0 * i2 + r1 * i4 + r2 * i5) * r2)
        if not self._moved and nis < NIS_GATE:
            self._follow_noise(nis)
        verify = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2) * 1e3   # |R_C r|: the prediction error in C's parent frame
        r = np.array(r)
        if self._moved:
            self._relearn_set.append(s)
            del self._relearn_set[:-self.settings.relearn_samples]
            alarm, statistic, message = "", 0.0, self._relearn()
        else:
            alarm, statistic, message = self._test(s, r, H, R, PHt, sym3(S_inv))
        return self._figures(s, self._next_state(), alarm, message, r, nis, verify, statistic)

    def _model_at(self, pose, factor):
        """`sample_floats` at the live state for a flange pose (``A[:3]`` flat) and kinematic-error factor."""
        u = self._u
        k0, k1, k2, s0, s1, s2 = u.tolist()[:6]
        return sample_floats(self._camera_parts, (k0, k1, k2), pose, (s0, s1, s2), self._eye_to_hand, factor,
                             u[6:6 + self._nf])

    def _against_stop(self, i: int, s: Stop, r) -> tuple:
        """Sample ``s``'s marker point against its stop ``i``'s earlier visits (3 floats), ``r`` its innovation.

        Exact repeats (within `SAME_POSE_TOL`: a robot's encoders): the
        point's change from their mean. A stop repeated only roughly
        (vision-guided picks, a pallet's pattern: each visit a few mm or cm off
        the last) has its mean point carried from the visits' mean pose to this
        one by the model at the live state: the innovation less the stop's mean
        innovation there. What the visits share (the systematic errors at that
        place) still cancels."""
        m0, m1, m2 = self._stops.mean[i]
        pose = self._stops.pose_mean[i]
        if max(abs(a - b) for a, b in zip(pose, s.pose)) <= SAME_POSE_TOL:
            p0, p1, p2 = s.point
            return p0 - m0, p1 - m1, p2 - m2
        (h0, h1, h2), _, _ = self._model_at(pose, s.factor)
        r0, r1, r2 = r
        return r0 - (m0 - h0), r1 - (m1 - h1), r2 - (m2 - h2)

    def _innovation(self, s: Stop):
        """`_linearize` at the live state on floats: innovation ``r`` (3 floats), ``H`` (3, 12 + P) (the model's
        columns: not the walk states'), and the noise ``R``'s upper triangle (6 floats)."""
        h, H, cof = self._model_at(s.pose, s.factor)
        scale = self._noise_scale
        k, m = scale * self._point_scale, scale * self._robot_var
        (p0, p1, p2), (h0, h1, h2) = s.point, h
        (a0, a1, a2, a3, a4, a5), (b0, b1, b2, b3, b4, b5) = s.shape_upper, cof
        return ((p0 - h0, p1 - h1, p2 - h2), H,
                (k * a0 + m * b0, k * a1 + m * b1, k * a2 + m * b2, k * a3 + m * b3, k * a4 + m * b4, k * a5 + m * b5))

    def _follow_noise(self, nis: float) -> None:
        """The arming noise levels come from a few dozen samples: their scale follows the innovations (a running
        mean of the NIS at unit scale, with the arming's level worth `NOISE_SCALE_PRIOR` samples).

        The state covariance follows it too, from the next sample on: it is
        the inverse information at the noise level of the data it came from,
        and scales with that level."""
        keep = 1.0 - 1.0 / NOISE_SCALE_SAMPLES
        self._scale_sum = keep * self._scale_sum + nis * self._noise_scale / 3.0
        self._scale_n = keep * self._scale_n + 1.0
        old = self._noise_scale
        self._noise_scale = min(max((NOISE_SCALE_PRIOR + self._scale_sum) / (NOISE_SCALE_PRIOR + self._scale_n),
                                    NOISE_SCALE_RANGE[0]), NOISE_SCALE_RANGE[1])
        self._pending_scale *= self._noise_scale / old

    def _test(self, s: Stop, r, H, R, PHt, S_inv) -> tuple[str, float, str]:
        """The *moved* test of a sample: ``(alarm, statistic, message)``; fused if it passes, else the re-learn starts."""
        stops = self._stops
        i = stops.lookup(s)
        r_test, S_test_inv, offset_var = r, S_inv, None
        Hc = H[:, :6]
        baseline = i is not None and stops.n[i] >= MIN_BASELINE
        if baseline:
            # Against the stop's own earlier visits: what they share (unmodelled errors of the robot or the
            # camera at that pose, the estimate's own error) is no change; only the camera moving is.
            r_test = self._against_stop(i, s, r)
            # A drifting camera has moved since those visits by the same for every stop: the long window's
            # test is for a move beyond the random walk over that time.
            offset_var = self._walk_per_h * ((s.t - stops.t[i]) / self._hour_s)
            k = 1.0 + 1.0 / stops.n[i]
            (a, b, c), (_, d, e), (_, _, f) = (Hc * offset_var).dot(Hc.T).tolist()
            S_test_inv = sym3(inv_sym3_floats(a + k * R[0], b + k * R[1], c + k * R[2], d + k * R[3], e + k * R[4],
                                              f + k * R[5]))
        # While a re-learnt camera settles the stops still refine it: that is not a move.
        fired = not self._settle and self.detector.update(r_test, S_test_inv, Hc, offset_var, shared=not baseline)
        statistic = self.detector.statistic
        if not fired:
            self._window.append(Visit(s, (self._C, self._u, self._P)))
            self._gain(PHt, S_inv, r)
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
            self._restart_walk()
            ref.sigma_mm = self._workspace.sigma(self._C, ref.theta, self._P) * 1e3
            return "settling"
        return "armed" if self.detector.count >= 3 else "warming"

    def _sample(self, t, T_base_flange, point_cam, point_cov, robot_factor) -> Stop:
        if self.reference is None:
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
        factor = None
        n_factor = self._nf
        if n_factor:
            if robot_factor is None:
                raise CalibrationError("the engine was armed with the robot's kinematic error: every sample "
                                       "needs its robot_factor (6, P)")
            factor = robot_factor.copy() if is_plain(robot_factor, (6, n_factor)) else tf.as_real_array(
                robot_factor, "robot_factor")
            if factor.shape != (6, n_factor):
                raise CalibrationError(f"robot_factor must have shape (6, {n_factor}), got {factor.shape}")
        if not math.isfinite(t) or t < self._t - 1e-9:
            raise CalibrationError(f"t must be finite and not before the previous sample's ({self._t}), got {t}")
        return Stop(A, p, shape, factor, float(t), pose, point, upper)

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
        self._restart_walk()
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

        Weighted least squares of ``p_i - mean_stop = H_i delta`` (the marker
        point's change at its stop, `_against_stop`) at the estimate from
        before the move; ``ok`` when the fit's chi-square agrees with the noise
        (else the oldest sample is from before the move).
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
            r, H, R = self._linearize(self._C, self._u, s)
            W = np.linalg.inv(R * (1.0 + 1.0 / stops.n[i]))
            rows.append((np.array(self._against_stop(i, s, r)), H[:, :6], W))
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

    def _parent_point(self, s: Stop) -> np.ndarray:
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

    def _figures(self, s: Stop, state, alarm, message, r, nis, verify, statistic) -> MonitorUpdate:
        ref, cfg = self.reference, self.settings
        if ref.C is not self._in_use[0] or ref.theta is not self._in_use[1]:     # once per change of it
            self._in_use = ref.C, ref.theta, None
        factor = self._in_use[2]
        # The drift: the camera's walk since the calibration in use, not what the samples have refined since.
        w0, w1, w2, w3, w4, w5 = self._u[-6:].tolist()
        delta = (w0, w1, w2, w3, w4, w5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        if any(delta):
            if factor is None:               # once per calibration in use, when it is first drifted from
                factor = self._workspace.drift_factor(ref.C, ref.theta)
                self._in_use = ref.C, ref.theta, factor
            moved = tuple(factor.dot(delta).tolist())
        else:
            moved = (0.0,) * 12
        drift_m = math.hypot(*moved)
        drift_deg = math.degrees(math.sqrt(w0 * w0 + w1 * w1 + w2 * w2))
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
