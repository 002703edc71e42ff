"""Judge a calibration on samples it did not see: the marker it predicts against the marker measured.

Everything is in the robot's base frame. Eye-to-hand (``X = T_flange_marker``,
``Y = T_base_cam``): the marker measured is ``Y @ correct(p_cam)`` and the one
predicted ``A_i t_X``; eye-in-hand (``X = T_flange_cam``, ``Y = T_base_marker``):
measured ``A_i X correct(p_cam)``, predicted ``t_Y`` (paper eq. 1 either way,
``A_i = T_base_flange``). ``correct`` undoes the camera correction the result
estimated (`handeye.calib.model.CameraCorrection`; identity for the paper's methods),
so the measured raw points pair with ``camera_transform``; a consumer that
takes the points uncorrected (ROS, URDF) carries ``camera_transform_raw_points``
instead, which `VerifiedModel.rigid_export` models.

A measured error holds the calibration's own error and the measurement noise.
`verify` reports both the observed errors (per pose, mean, p95, max) and the
calibration's error with the noise removed: ``sqrt(mean |e|^2 - mean E|n|^2)``
with ``E|n|^2`` from the result's noise model (`handeye.calib.model.NoiseLevels`: the
camera point covariance scale times each sample's covariance, the robot
error), with a bootstrap 95 % interval over the poses. Pass/fail compares that
estimate with the tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError, InsufficientDataError
from handeye.calib.model import CameraCorrection, NoiseLevels
from handeye.calib.result import CalibrationResult
from handeye.calib.setup import Setup, check_setup

#: Largest camera correction a model may carry (depth and focal scale as fractions, depth offset in m).
MAX_CORRECTION = 0.5
#: Fewest poses a verification judges (a p95 and an interval need a handful).
MIN_POSES = 3
#: Bootstrap resamples of the 95 % interval of the calibration error.
N_BOOTSTRAP = 2000
#: Distance from a rough prior (tape measure, CAD) beyond which the frame-safety check warns, m.
PRIOR_TOLERANCE_M = 0.10


@dataclass(frozen=True)
class VerifiedModel:
    """What a verification needs of a result: the transforms, the camera correction, the noise model.

    Attributes
    ----------
    setup : Setup
        Eye-to-hand: ``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand:
        ``X = T_flange_cam``, ``Y = T_base_marker``.
    X, Y : ndarray (4, 4)
    correction : CameraCorrection
        Applied (undone) on the measured points before the camera transform.
    point_scale : float
        Factor on each sample's point covariance (the noise model's camera scale; 1 = as measured).
    robot_sigma_m : float
        Flange translation error per axis, m.
    rotation_sigma_rad : float or None
        Marker orientation noise per axis, rad (None: unknown, not removed).
    marker_rotation_known : bool
        False for point-only results: no orientation error is judged.
    method : str
    """

    setup: Setup
    X: np.ndarray
    Y: np.ndarray
    correction: CameraCorrection = field(default_factory=CameraCorrection)
    point_scale: float = 1.0
    robot_sigma_m: float = 0.0
    rotation_sigma_rad: float | None = None
    marker_rotation_known: bool = True
    method: str = ""

    def __post_init__(self):
        object.__setattr__(self, "setup", check_setup(self.setup, "setup"))
        object.__setattr__(self, "X", tf.check_transform(self.X, "X"))
        object.__setattr__(self, "Y", tf.check_transform(self.Y, "Y"))
        for name in ("point_scale", "robot_sigma_m"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise CalibrationError(f"{name} must be a finite number >= 0, got {v!r}")
        c = self.correction.as_array()
        # A scale of -100 % would divide by zero; no camera is off by half its range.
        if not (np.isfinite(c).all() and np.all(np.abs(c) < MAX_CORRECTION)):
            raise CalibrationError(f"correction (depth scale, depth offset m, focal scale) must be finite and "
                                   f"within +-{MAX_CORRECTION}, got {c.tolist()}")

    @property
    def camera_transform(self) -> np.ndarray:
        """``T_base_cam`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand)."""
        return self.Y if self.setup == Setup.EYE_TO_HAND else self.X

    def with_camera_transform(self, T) -> "VerifiedModel":
        """The same model with another camera transform (4, 4)."""
        T = tf.check_transform(T, "camera transform")
        return replace(self, Y=T) if self.setup == Setup.EYE_TO_HAND else replace(self, X=T)

    def rigid_export(self, T_raw) -> "VerifiedModel":
        """The model a rigid-only consumer uses: ``T_raw`` (``camera_transform_raw_points``) on uncorrected points."""
        return replace(self.with_camera_transform(T_raw), correction=CameraCorrection())

    @classmethod
    def from_result(cls, result: CalibrationResult) -> "VerifiedModel":
        """From a solver's result: its correction and, for ``auto``, its fitted noise levels."""
        noise = result.auto.noise if result.auto is not None else NoiseLevels()
        return cls(result.setup, result.X, result.Y, result.camera_correction,
                   point_scale=float(noise.point_scale), robot_sigma_m=float(noise.robot),
                   rotation_sigma_rad=noise.rotation, marker_rotation_known=result.marker_rotation_known,
                   method=result.method)


@dataclass(frozen=True)
class PoseErrors:
    """Prediction errors of a model at each verification pose.

    Attributes
    ----------
    translation : ndarray (N, 3)
        Measured minus predicted marker center, base frame, m.
    rotation : ndarray (N,) or None
        Angle between measured and predicted marker orientation, rad (NaN where a
        sample has no orientation; None when the model knows none).
    noise_var : ndarray (N,)
        Expected ``|noise|^2`` of each translation error from the noise model, m^2 (NaN: unknown).
    rotation_noise_var : float or None
        Expected ``angle^2`` of the orientation noise, rad^2 (None: unknown).
    """

    translation: np.ndarray
    rotation: np.ndarray | None
    noise_var: np.ndarray
    rotation_noise_var: float | None = None


def prediction_errors(model: VerifiedModel, A, points, point_cov=None, T_cam_marker=None) -> PoseErrors:
    """Errors of ``model`` at flange poses ``A`` (N, 4, 4) where the camera measured ``points`` (N, 3), m.

    ``point_cov`` (N, 3, 3) m^2 or None (noise unknown); ``T_cam_marker``: a
    list of (4, 4) or None per sample (measured marker orientations).
    """
    A = tf.check_transforms(A, "A")
    p = tf.check_points(points, "points")
    if len(p) != len(A):
        raise CalibrationError(f"points: {len(p)} rows for {len(A)} poses")
    pc = model.correction.correct(p)
    if model.setup == Setup.EYE_TO_HAND:
        T_base_cam = np.broadcast_to(model.Y, A.shape)
        predicted = np.einsum("nij,j->ni", A[:, :3, :3], model.X[:3, 3]) + A[:, :3, 3]
        R_pred = A[:, :3, :3] @ model.X[:3, :3]
    else:
        T_base_cam = A @ model.X
        predicted = np.broadcast_to(model.Y[:3, 3], p.shape)
        R_pred = np.broadcast_to(model.Y[:3, :3], (len(A), 3, 3))
    measured = np.einsum("nij,nj->ni", T_base_cam[:, :3, :3], pc) + T_base_cam[:, :3, 3]
    if point_cov is None:
        noise = np.full(len(A), np.nan)
    else:
        cov = np.asarray(point_cov, dtype=float)
        if cov.shape != (len(A), 3, 3):
            raise CalibrationError(f"point_cov must have shape ({len(A)}, 3, 3), got {cov.shape}")
        # The trace is the same in any frame: no rotation into the base frame needed.
        noise = model.point_scale * np.trace(cov, axis1=1, axis2=2) + 3 * model.robot_sigma_m**2
    rotation = None
    if model.marker_rotation_known and T_cam_marker is not None:
        rotation = np.full(len(A), np.nan)
        for i, B in enumerate(T_cam_marker):
            if B is not None:
                R_meas = T_base_cam[i, :3, :3] @ np.asarray(B, dtype=float)[:3, :3]
                rotation[i] = float(tf.rotation_angle(R_meas @ R_pred[i].T))
        if np.isnan(rotation).all():
            rotation = None
    rot_var = None if model.rotation_sigma_rad is None else 3 * float(model.rotation_sigma_rad) ** 2
    return PoseErrors(measured - predicted, rotation, noise, rot_var)


def _noise_removed(sq: np.ndarray, noise: float) -> float:
    return float(np.sqrt(max(float(np.mean(sq)) - noise, 0.0)))


@dataclass(frozen=True)
class Verification:
    """A verification's statistics and verdict (mm and deg, as labelled).

    ``errors_mm`` / ``rotation_deg``: per pose, observed (measurement noise
    included); ``calibration_mm`` / ``calibration_deg``: RMS error of the
    calibration itself, the noise model's share removed, with its bootstrap
    95 % interval ``calibration_ci_mm`` / ``_deg``; ``noise_removed``: False
    when the samples carry no covariance (then the observed RMS stands in).
    ``noise_rms_deg``: the RMS angle the noise model expects of each pose's orientation
    measurement (None: unknown). ``passed``: ``calibration_mm <= tolerance_mm`` and, with
    orientations, ``calibration_deg <= tolerance_deg``.
    """

    errors_mm: np.ndarray
    rotation_deg: np.ndarray | None
    calibration_mm: float
    calibration_ci_mm: tuple[float, float]
    noise_rms_mm: float | None
    calibration_deg: float | None
    calibration_ci_deg: tuple[float, float] | None
    tolerance_mm: float
    tolerance_deg: float
    noise_removed: bool
    noise_rms_deg: float | None = None

    @property
    def n_poses(self) -> int:
        return len(self.errors_mm)

    @property
    def passed(self) -> bool:
        ok = self.calibration_mm <= self.tolerance_mm
        if self.calibration_deg is not None:
            ok = ok and self.calibration_deg <= self.tolerance_deg
        return bool(ok)

    @staticmethod
    def _floor(noise_rms: float | None, n: int) -> float | None:
        # The smallest calibration error the poses can tell from the noise: the one that raises the mean
        # squared error by two standard errors of the noise's own (3 n squared Gaussian components).
        return None if noise_rms is None else float(noise_rms * np.sqrt(2.0 * np.sqrt(2.0 / (3 * n))))

    @property
    def noise_floor_mm(self) -> float | None:
        """The smallest calibration error (mm) these poses tell from their noise (None: noise unknown)."""
        return self._floor(self.noise_rms_mm, self.n_poses)

    @property
    def noise_floor_deg(self) -> float | None:
        """The same for the rotation, deg."""
        r = self.rotation_deg
        return None if r is None else self._floor(self.noise_rms_deg, int(np.isfinite(r).sum()))

    def stats_mm(self) -> dict:
        e = self.errors_mm
        return {"mean": float(e.mean()), "rms": float(np.sqrt(np.mean(e**2))), "p95": float(np.percentile(e, 95)),
                "max": float(e.max())}

    def stats_deg(self) -> dict | None:
        if self.rotation_deg is None:
            return None
        r = self.rotation_deg[np.isfinite(self.rotation_deg)]
        return {"mean": float(r.mean()), "rms": float(np.sqrt(np.mean(r**2))), "p95": float(np.percentile(r, 95)),
                "max": float(r.max())}

    def to_dict(self) -> dict:
        """JSON-ready, units in the keys."""
        return {
            "passed": self.passed,
            "n_poses": self.n_poses,
            "tolerance_mm": self.tolerance_mm,
            "tolerance_deg": self.tolerance_deg,
            "calibration_error_mm": self.calibration_mm,
            "calibration_error_ci95_mm": list(self.calibration_ci_mm),
            "calibration_error_deg": self.calibration_deg,
            "calibration_error_ci95_deg": None if self.calibration_ci_deg is None else list(self.calibration_ci_deg),
            "measurement_noise_rms_mm": self.noise_rms_mm,
            "measurement_noise_rms_deg": self.noise_rms_deg,
            "noise_floor_mm": self.noise_floor_mm,
            "noise_floor_deg": self.noise_floor_deg,
            "noise_removed": self.noise_removed,
            "observed_mm": self.stats_mm(),
            "observed_deg": self.stats_deg(),
            "per_pose_mm": self.errors_mm.tolist(),
            "per_pose_deg": None if self.rotation_deg is None else
            [None if not np.isfinite(v) else float(v) for v in self.rotation_deg],
            "note": "observed: measured minus predicted marker, base frame (measurement noise included); "
                    "calibration_error: RMS with the noise model's share removed, bootstrap 95 % interval over the "
                    "poses; noise_floor: the smallest calibration error these poses tell from their noise; "
                    "passed: calibration_error within both tolerances",
        }


def verify(errors: PoseErrors, *, tolerance_mm: float, tolerance_deg: float,
           rng: np.random.Generator) -> Verification:
    """Statistics and verdict of `prediction_errors` (see the module docstring).

    Raises
    ------
    InsufficientDataError
        Fewer than `MIN_POSES` poses.
    CalibrationError
        A tolerance that is not a positive number.
    """
    for name, v in (("tolerance_mm", tolerance_mm), ("tolerance_deg", tolerance_deg)):
        if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
            raise CalibrationError(f"{name} must be a positive number, got {v!r}")
    e = np.linalg.norm(errors.translation, axis=1)
    n = len(e)
    if n < MIN_POSES:
        raise InsufficientDataError(f"verification needs at least {MIN_POSES} poses with a measurement, got {n}")
    sq = e**2
    known = bool(np.isfinite(errors.noise_var).all())
    noise = errors.noise_var if known else np.zeros(n)
    idx = rng.integers(0, n, size=(N_BOOTSTRAP, n))
    boot = np.sqrt(np.maximum(sq[idx].mean(axis=1) - noise[idx].mean(axis=1), 0.0))
    calib_mm = _noise_removed(sq, float(noise.mean())) * 1e3
    ci_mm = tuple(float(v) * 1e3 for v in np.percentile(boot, [2.5, 97.5]))
    rot_deg = cal_deg = ci_deg = None
    if errors.rotation is not None:
        rot = errors.rotation
        r = rot[np.isfinite(rot)]
        rn = errors.rotation_noise_var or 0.0
        cal_deg = float(np.rad2deg(_noise_removed(r**2, rn)))
        ridx = rng.integers(0, len(r), size=(N_BOOTSTRAP, len(r)))
        rboot = np.sqrt(np.maximum((r[ridx] ** 2).mean(axis=1) - rn, 0.0))
        ci_deg = tuple(float(v) for v in np.rad2deg(np.percentile(rboot, [2.5, 97.5])))
        rot_deg = np.rad2deg(rot)
    noise_deg = None if errors.rotation is None or errors.rotation_noise_var is None else \
        float(np.rad2deg(np.sqrt(errors.rotation_noise_var)))
    return Verification(e * 1e3, rot_deg, calib_mm, ci_mm,
                        float(np.sqrt(noise.mean())) * 1e3 if known else None, cal_deg, ci_deg,
                        float(tolerance_mm), float(tolerance_deg), known, noise_deg)


#: A verification pose this close to a calibration pose repeats it (m, deg): a robot returning to a
#: taught pose lands within a few tenths of a millimetre; planned fresh poses are centimetres apart.
REPEAT_M, REPEAT_DEG = 0.005, 0.5


def repeated_poses(A, A_calibration, *, translation_m: float = REPEAT_M, rotation_deg: float = REPEAT_DEG
                   ) -> np.ndarray:
    """Indices of the flange poses ``A`` (N, 4, 4) within ``translation_m`` and ``rotation_deg`` of a pose of
    ``A_calibration`` (M, 4, 4): there a verification repeats the calibration instead of testing it."""
    A = tf.check_transforms(A, "A")
    C = tf.check_transforms(A_calibration, "A_calibration")
    if len(A) == 0 or len(C) == 0:
        return np.zeros(0, dtype=int)
    near = np.linalg.norm(A[:, None, :3, 3] - C[None, :, :3, 3], axis=2) <= translation_m
    hits = []
    for i, js in enumerate(near):
        js = np.flatnonzero(js)
        if len(js) and np.min(tf.rotation_angle(A[i, :3, :3] @ np.swapaxes(C[js, :3, :3], 1, 2))) \
                <= np.deg2rad(rotation_deg):
            hits.append(i)
    return np.array(hits, dtype=int)


@dataclass(frozen=True)
class FrameSafety:
    """How the camera transform compares with a rough prior of its translation (m).

    ``distance_m``: of the camera origin from the prior; ``inverse_distance_m``: of the
    inverse transform's origin (what an inverted-direction mistake would have given);
    ``warnings``: plain sentences, empty when the result sits near the prior.
    """

    expected_m: np.ndarray
    distance_m: float
    inverse_distance_m: float
    warnings: list

    def to_dict(self) -> dict:
        return {"expected_xyz_mm": (self.expected_m * 1e3).tolist(), "distance_mm": self.distance_m * 1e3,
                "inverse_distance_mm": self.inverse_distance_m * 1e3, "warnings": list(self.warnings)}


def frame_safety(camera_transform, setup: str, expected_xyz, *, tolerance_m: float = PRIOR_TOLERANCE_M) -> FrameSafety:
    """Compare the camera transform (``T_base_cam`` eye-to-hand, ``T_flange_cam`` eye-in-hand) with a prior.

    ``expected_xyz`` (3,) m: where the user measured the camera origin (in the
    base frame eye-to-hand, in the flange frame eye-in-hand). Warns when the
    result is farther than ``tolerance_m`` from it, and says so plainly when the
    inverse transform fits the prior better: the classic inverted-direction mistake.
    """
    setup = check_setup(setup, "setup")
    T = tf.check_transform(camera_transform, "camera transform")
    prior = np.asarray(expected_xyz, dtype=float)
    if prior.shape != (3,) or not np.isfinite(prior).all():
        raise CalibrationError(f"expected_xyz must be 3 finite numbers (m), got {expected_xyz!r}")
    d = float(np.linalg.norm(T[:3, 3] - prior))
    d_inv = float(np.linalg.norm(tf.invert(T)[:3, 3] - prior))
    name = Setup(setup).camera_name
    warnings = []
    if d > tolerance_m and d_inv < d:
        warnings.append(f"the inverse of {name} fits the expected position better ({d_inv * 1e3:.0f} mm against "
                        f"{d * 1e3:.0f} mm): the transform is probably inverted (a tool that wants the other "
                        "direction, e.g. T_cam_base instead of T_base_cam)")
    elif d > tolerance_m:
        warnings.append(f"{name} is {d * 1e3:.0f} mm from the expected position (more than "
                        f"{tolerance_m * 1e3:.0f} mm): check the prior, the setup (eye_to_hand/eye_in_hand) and "
                        "the frames the poses are given in")
    return FrameSafety(prior, d, d_inv, warnings)


#: Metres of flange travel one radian of flange rotation counts as when spreading poses (a 10 cm lever).
ROTATION_WEIGHT_M = 0.1


def spread_poses(planner, T_start, k: int, rng: np.random.Generator, *, avoid=None, min_separation_m: float = 0.03,
                 reachable=None, q_start=None) -> list[np.ndarray]:
    """``k`` flange poses (4, 4) spread over the planner's candidate region around ``T_start``.

    Candidates are `handeye.calib.planner.candidate_poses`; those the planner's
    ``screen`` rejects (marker out of view or range, keep-out boxes) and those
    within ``min_separation_m`` of a pose of ``avoid`` (N, 4, 4; the
    calibration's) are dropped; then farthest-point selection (translation
    plus `ROTATION_WEIGHT_M` per radian of rotation, starting farthest from
    ``avoid``), each pose checked with ``reachable(T, q_from) -> q or None`` (the
    robot's limit check) from the previous one's joints.
    """
    from handeye.calib.planner import candidate_poses

    A = candidate_poses(T_start, planner.config, rng)
    ok = planner.screen(A)[0]
    A = A[ok]
    if avoid is not None and len(A):
        avoid = tf.check_transforms(avoid, "avoid")
        d = np.linalg.norm(A[:, None, :3, 3] - avoid[None, :, :3, 3], axis=2)
        A = A[d.min(axis=1) >= min_separation_m]
    if len(A) == 0:
        return []
    t = A[:, :3, 3]
    rot = tf.so3_log(A[:, :3, :3] @ np.swapaxes(A[:1, :3, :3], 1, 2).repeat(len(A), 0)) * ROTATION_WEIGHT_M

    def distance(i):
        return np.linalg.norm(t - t[i], axis=1) + np.linalg.norm(rot - rot[i], axis=1)

    if avoid is not None:
        nearest = np.linalg.norm(t[:, None] - avoid[None, :, :3, 3], axis=2).min(axis=1)
    else:
        nearest = np.linalg.norm(t - t.mean(axis=0), axis=1)
    chosen, q = [], q_start
    alive = np.ones(len(A), bool)
    while len(chosen) < k and alive.any():
        i = int(np.argmax(np.where(alive, nearest, -np.inf)))
        alive[i] = False
        if reachable is not None:
            q_i = reachable(A[i], q)
            if q_i is None:
                continue
            q = q_i
        chosen.append(A[i])
        nearest = np.minimum(nearest, distance(i))
    return chosen


def perturbed(T, rotation_deg: float, translation_mm: float, rng: np.random.Generator, *, axis=None) -> np.ndarray:
    """``T`` moved by ``translation_mm`` and turned by ``rotation_deg`` about its origin, in random directions
    (the `handeye.calib.result` convention: ``R' = Exp(d) R``, ``t' = t + dt``): a result known to be that far off.

    ``axis`` (3,), parent frame: the rotation axis instead of a random one (a turn about the camera's
    viewing axis does not move the marker center it predicts; one across it does)."""
    T = tf.check_transform(T, "T")
    shift = rng.normal(size=3)
    axis = rng.normal(size=3) if axis is None else np.asarray(axis, dtype=float)
    out = T.copy()
    out[:3, :3] = tf.so3_exp(axis / np.linalg.norm(axis) * np.deg2rad(rotation_deg)) @ T[:3, :3]
    out[:3, 3] = T[:3, 3] + shift / np.linalg.norm(shift) * translation_mm * 1e-3
    return out
