"""Synthetic calibration data with known truth, for tests and benchmarks.

Two generators:

- `paper_setup`: the simulation of sec. V of the paper (random X, A, B within
  distance intervals, A's orientation within +-30 deg, multiplicative noise
  transforms N_A, N_B with bounded angle and translation).
- `realistic_cell`: the real-world experiment of sec. V as a simulation: a
  static camera about 0.7 m from the flange, the flange moved +-0.15 m and
  +-40 deg around a start pose, the marker center measured with anisotropic
  noise (lateral / along the viewing ray).

Both return eye-to-hand data (``A = T_base_flange``, ``B = T_cam_marker``,
``X = T_flange_marker``, ``Y = T_base_cam``) unless ``setup="eye_in_hand"``
is asked of `realistic_cell`, which then moves a camera on the flange in front
of a static marker (``X = T_flange_cam``, ``Y = T_base_marker``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from handeye.calib import transforms as tf
from handeye.calib.robot_error import UR10_DH, ur_dh_error_factor, ur_forward
from handeye.calib.setup import Setup, check_setup


@dataclass(frozen=True)
class SimulatedData:
    """Noisy measurements and the truth behind them.

    Attributes
    ----------
    A : ndarray, shape (N, 4, 4)
        Measured ``T_base_flange`` (noisy where the generator adds robot noise).
    B : ndarray, shape (N, 4, 4)
        Measured ``T_cam_marker`` (noisy).
    points : ndarray, shape (N, 3)
        Measured marker center in the camera frame (eye-to-hand) or marker
        center seen from the flange camera (eye-in-hand), m.
    point_cov : ndarray, shape (N, 3, 3)
        Covariance of the point noise actually applied, m^2.
    X, Y : ndarray, shape (4, 4)
        The truth.
    A_true, B_true : ndarray, shape (N, 4, 4)
        Noise-free poses, satisfying ``A_true[i] @ X == Y @ B_true[i]``.
    setup : str
    """

    A: np.ndarray
    B: np.ndarray
    points: np.ndarray
    point_cov: np.ndarray
    X: np.ndarray
    Y: np.ndarray
    A_true: np.ndarray
    B_true: np.ndarray
    setup: Setup = Setup.EYE_TO_HAND


def random_directions(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` unit vectors (n, 3) in random directions."""
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _random_translation(n: int, center: float, half_width: float, rng) -> np.ndarray:
    return random_directions(n, rng) * rng.uniform(center - half_width, center + half_width, size=(n, 1))


def noise_transforms(n: int, max_angle: float, max_translation: float, rng) -> np.ndarray:
    """``n`` noise transforms (n, 4, 4) with angle <= max_angle (rad) and |t| <= max_translation (m).

    Angle and translation length are uniform in their ranges, directions uniform
    on the sphere (the paper's "|N_alpha| < ..., |N_t| < ...").
    """
    R = tf.random_rotations(n, max_angle, rng)
    t = random_directions(n, rng) * rng.uniform(0.0, max_translation, size=(n, 1))
    return tf.make_transform(R, t)


def paper_setup(
    n: int,
    rng: np.random.Generator,
    *,
    noise_A: tuple[float, float] = (np.deg2rad(15.0), 0.02),
    noise_B: tuple[float, float] = (np.deg2rad(10.0), 0.01),
) -> SimulatedData:
    """The paper's simulated eye-to-hand round (sec. V-A).

    ``|t_X| = 0.2 +- 0.1 m``, ``|t_A| = 1.25 +- 0.75 m``, ``|t_B| = 0.8 +- 0.3 m``,
    ``Y = A X B^-1`` from one random draw, then ``n`` samples of A at the same
    distance with orientation within +-30 deg of the first draw and
    ``B = Y^-1 A X``; measured ``A N_A`` and ``B N_B``. Noise is
    ``(max angle rad, max translation m)``; the default is experiment 1's.
    """
    X = tf.make_transform(tf.random_rotations(1, np.pi, rng)[0], _random_translation(1, 0.2, 0.1, rng)[0])
    R_A0 = tf.random_rotations(1, np.pi, rng)[0]
    A0 = tf.make_transform(R_A0, _random_translation(1, 1.25, 0.75, rng)[0])
    B0 = tf.make_transform(tf.random_rotations(1, np.pi, rng)[0], _random_translation(1, 0.8, 0.3, rng)[0])
    Y = A0 @ X @ tf.invert(B0)

    R_A = tf.random_rotations(n, np.deg2rad(30.0), rng) @ R_A0
    A_true = tf.make_transform(R_A, _random_translation(n, 1.25, 0.75, rng))
    B_true = tf.invert(Y) @ A_true @ X
    A = A_true @ noise_transforms(n, *noise_A, rng)
    B = B_true @ noise_transforms(n, *noise_B, rng)
    # The paper's point-only variant uses the translation of the noisy B.
    points = B[:, :3, 3].copy()
    cov = np.broadcast_to(np.eye(3) * (noise_B[1] ** 2 / 5.0), (n, 3, 3)).copy()
    return SimulatedData(A, B, points, cov, X, Y, A_true, B_true)


def point_covariance(points: np.ndarray, sigma_lateral: float, sigma_depth: float) -> np.ndarray:
    """Covariances (N, 3, 3) of points seen from the origin: ``sigma_depth`` along the ray, ``sigma_lateral`` across."""
    r = points / np.linalg.norm(points, axis=1, keepdims=True)
    outer = r[:, :, None] * r[:, None, :]
    return sigma_depth**2 * outer + sigma_lateral**2 * (np.eye(3) - outer)


def _look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_cam for an OpenCV camera (z forward, y down) at ``eye`` looking at ``target``."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return tf.make_transform(np.column_stack([x, y, z]), eye)


def realistic_cell(
    n: int,
    rng: np.random.Generator,
    *,
    setup: Setup = Setup.EYE_TO_HAND,
    distance: float = 0.7,
    translation_range: float = 0.15,
    angle_range: float = np.deg2rad(40.0),
    sigma_lateral: float = 0.001,
    sigma_depth: float = 0.003,
    pose_noise: tuple[float, float] = (np.deg2rad(1.0), 0.002),
    robot_noise: tuple[float, float] = (0.0, 0.0),
    rotation_axis=None,
) -> SimulatedData:
    """A UR10 cell like the paper's real experiment, with known truth.

    The flange starts ``distance`` m in front of the camera with the marker
    facing it; each sample moves the flange by up to ``translation_range`` m
    per axis and rotates it by up to ``angle_range`` rad about a random axis,
    or about ``rotation_axis`` (3,) of the flange frame only if given.
    ``angle_range=0`` gives a grid recording: the tool at one orientation.
    Points get Gaussian noise with ``sigma_lateral`` across and ``sigma_depth``
    along the viewing ray; poses B get Gaussian noise of ``pose_noise``
    (rad, m) standard deviation per axis; A gets ``robot_noise`` likewise.

    Eye-in-hand mirrors it: the camera rides on the flange ``distance`` m from
    a static marker, ``X = T_flange_cam``, ``Y = T_base_marker``.
    """
    setup = check_setup(setup)
    # Flange start pose: 0.9 m in front of the base, 0.5 m up, tool z axis horizontal.
    p0 = np.array([0.9, 0.1, 0.5])
    # A mounting offset of a few cm and tens of degrees, unknown to the solver.
    offset = tf.make_transform(
        Rotation.from_euler("xyz", rng.uniform(-0.3, 0.3, size=3)).as_matrix(),
        rng.uniform(-0.05, 0.05, size=3) + [0.0, 0.0, 0.03],
    )
    # The camera sits to the side and above, looking down at the flange.
    eye = p0 + np.array([-0.2, -distance, 0.35])
    T_base_cam = _look_at(eye, p0)
    # Flange frame whose z axis points at the camera, so the marker (z out of its face) faces the lens.
    R_flange0 = T_base_cam[:3, :3] @ Rotation.from_euler("y", np.pi).as_matrix()
    A0 = tf.make_transform(R_flange0, p0)

    if setup == Setup.EYE_TO_HAND:
        X = offset                                   # T_flange_marker
        Y = T_base_cam                               # T_base_cam
    else:
        # Camera on the flange looking along the flange z axis at a static marker.
        X = offset                                   # T_flange_cam
        T_base_marker = A0 @ X @ tf.make_transform(Rotation.from_euler("y", np.pi).as_matrix(), [0, 0, distance])
        Y = T_base_marker

    if rotation_axis is None:
        dR = tf.random_rotations(n, angle_range, rng)
    else:
        # About the flange axis u: R_flange0 Exp(a u) = Exp(a R_flange0 u) R_flange0.
        u = R_flange0 @ (np.asarray(rotation_axis, dtype=float) / np.linalg.norm(rotation_axis))
        dR = tf.so3_exp(rng.uniform(-angle_range, angle_range, size=(n, 1)) * u)
    dt = rng.uniform(-translation_range, translation_range, size=(n, 3))
    A_true = tf.make_transform(dR @ R_flange0, p0 + dt)
    if setup == Setup.EYE_TO_HAND:
        B_true = tf.invert(Y) @ A_true @ X           # T_cam_marker
    else:
        B_true = tf.invert(A_true @ X) @ Y           # T_cam_marker = (T_base_flange T_flange_cam)^-1 T_base_marker

    points_true = B_true[:, :3, 3]
    cov = point_covariance(points_true, sigma_lateral, sigma_depth)
    points = ray_noise(points_true, sigma_lateral, sigma_depth, rng)
    B = B_true @ pose_noise_transforms(n, pose_noise, rng)
    B[:, :3, 3] = points                              # one translation noise model for poses and points
    A = A_true @ pose_noise_transforms(n, robot_noise, rng)
    return SimulatedData(A, B, points, cov, X, Y, A_true, B_true, setup)


def ray_noise(points: np.ndarray, sigma_lateral: float, sigma_depth: float, rng: np.random.Generator) -> np.ndarray:
    """``points`` (N, 3) in the camera frame with Gaussian noise of ``sigma_depth`` along each viewing ray and
    ``sigma_lateral`` across it (m); white noise split into the two parts, no Cholesky: a sigma may be zero."""
    ray = points / np.linalg.norm(points, axis=1, keepdims=True)
    white = rng.normal(size=points.shape)
    along = np.sum(white * ray, axis=1, keepdims=True) * ray
    return points + sigma_depth * along + sigma_lateral * (white - along)


def pose_noise_transforms(n: int, sigma: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """``n`` transforms (n, 4, 4) of Gaussian pose noise, ``sigma`` = (rad, m) standard deviation per axis."""
    rv = rng.normal(scale=sigma[0], size=(n, 3)) if sigma[0] > 0 else np.zeros((n, 3))
    t = rng.normal(scale=sigma[1], size=(n, 3)) if sigma[1] > 0 else np.zeros((n, 3))
    return tf.from_rotvec_translation(rv, t)


def with_gross_outliers(points: np.ndarray, fraction: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Replace ``fraction`` of the points by gross outliers: half a wrong depth, half a wrong marker.

    Wrong depth scales the point along its ray by 1.05-1.3; a wrong marker
    shifts it by 5-20 cm per axis.

    Returns
    -------
    points : ndarray, shape (N, 3)
    bad : ndarray of int
        Sorted indices of the corrupted samples.
    """
    n = len(points)
    k = int(round(fraction * n))
    bad = rng.choice(n, size=k, replace=False)
    out = points.copy()
    half = k // 2
    out[bad[:half]] *= rng.uniform(1.05, 1.3, size=(half, 1))
    out[bad[half:]] += rng.uniform(0.05, 0.2, size=(k - half, 3)) * rng.choice([-1, 1], size=(k - half, 3))
    return out, np.sort(bad)


# --------------------------------------------------------------------------- realistic profile

@dataclass(frozen=True)
class RealisticProfile:
    """Error magnitudes of the ``realistic`` profile (`realistic_profile`); 1-sigma unless said.

    Robot: DH perturbation of an uncalibrated UR10, drawn once per cell
    (kinematic calibration studies of UR arms report joint zero offsets of a
    few hundredths of a degree and link-length errors of tenths of a mm, giving
    1-3 mm of flange position error; e.g. the 0.01-0.05 deg offsets quoted for
    UR5/UR10 identification), and the datasheet repeatability (UR10: +-0.1 mm,
    taken as 3 sigma). Camera: depth scale and offset of a structured-light
    sensor before an infield correction (1-2% of range, a few mm), a focal length
    error of 1%, a colour/depth misregistration of 2 px, the marker point noise
    of `handeye.calib.noise` (1 mm lateral, 3 mm along the ray at 0.7 m), marker
    orientation noise, and a share of half-turn flips of a symmetric board.
    ``pose_error_m``: the robot's error beyond what its DH parameters capture
    (thermal growth of the arm, deflection under load), 1-sigma per axis of
    the flange position, drawn once per pose: every visit of a pose repeats
    it (`handeye.calib.simulate_month`).
    """

    joint_offset_deg: float = 0.03
    link_length_m: float = 0.0003
    twist_deg: float = 0.02
    repeatability_m: float = 0.1e-3 / 3
    repeatability_rad: float = np.deg2rad(0.01) / 3
    depth_scale: float = 0.015
    depth_offset: float = 0.003
    focal_scale: float = 0.01
    misregistration_px: float = 2.0
    orientation_noise_rad: float = np.deg2rad(0.5)
    flip_fraction: float = 0.0
    board_center: tuple = (0.09, 0.06, 0.0)
    pose_error_m: float = 0.0

    def dh_error_factor(self, q: np.ndarray) -> np.ndarray:
        """`handeye.calib.robot_error.ur_dh_error_factor` of joints ``q`` (N, 6) at this profile's DH magnitudes."""
        return ur_dh_error_factor(q, np.deg2rad(self.joint_offset_deg), self.link_length_m, np.deg2rad(self.twist_deg))

    def repeatability_cov(self) -> np.ndarray:
        """The flange twist's covariance per visit (6, 6), ``[rotation, translation]`` (rad^2, m^2)."""
        return np.diag([self.repeatability_rad**2] * 3 + [self.repeatability_m**2] * 3)

    def bias_free(self) -> "RealisticProfile":
        """The same cell without systematic errors: exact kinematics and an ideal camera (random noise kept)."""
        return dataclasses.replace(self, joint_offset_deg=0.0, link_length_m=0.0, twist_deg=0.0, depth_scale=0.0,
                                   depth_offset=0.0, focal_scale=0.0, misregistration_px=0.0, flip_fraction=0.0)


#: Working pose of the realistic cell's UR10 (rad) and the span drawn around it: +-8 deg on the
#: shoulder/elbow joints, +-25 deg on the wrist.
_WORKING_JOINTS = np.deg2rad([10.0, -110.0, 100.0, -80.0, -90.0, 0.0])
_JOINT_SPAN = np.deg2rad([8.0, 8.0, 8.0, 25.0, 25.0, 25.0])


#: Half the field of view an eye-in-hand camera keeps the static marker within (tangent, x and y): the camera
#: turns with the wrist, so a pose may look away from the marker.
_FIELD_OF_VIEW_TAN = (0.5, 0.4)


def _camera_marker(A, X, Y, setup: Setup) -> np.ndarray:
    """``T_cam_marker`` (N, 4, 4) at flange poses ``A`` (N, 4, 4): ``Y^-1 A X`` eye-to-hand, ``(A X)^-1 Y``
    eye-in-hand (paper eq. 1)."""
    return tf.invert(Y) @ A @ X if setup == Setup.EYE_TO_HAND else tf.invert(A @ X) @ Y


def _visible_joints(n: int, rng: np.random.Generator, X, Y, setup: Setup = Setup.EYE_TO_HAND) -> np.ndarray:
    """``n`` joint configurations (n, 6) of the realistic cell's span that show the marker to the camera."""
    dh = UR10_DH
    q = np.empty((0, 6))
    while len(q) < n:
        cand = _WORKING_JOINTS + rng.uniform(-_JOINT_SPAN, _JOINT_SPAN, size=(4 * n, 6))
        Bc = _camera_marker(ur_forward(cand, dh["d"], dh["a"], dh["alpha"], np.zeros(6)), X, Y, setup)
        facing = -Bc[:, 2, 2] > np.cos(np.deg2rad(60.0))          # marker normal towards the camera
        seen = facing & (Bc[:, 2, 3] > 0.3)
        if setup == Setup.EYE_IN_HAND:
            ratio = np.abs(Bc[:, :2, 3] / Bc[:, 2:3, 3])
            seen &= (ratio[:, 0] < _FIELD_OF_VIEW_TAN[0]) & (ratio[:, 1] < _FIELD_OF_VIEW_TAN[1])
        q = np.vstack([q, cand[seen]])
    return q[:n]


@dataclass(frozen=True)
class RealisticData:
    """`realistic_profile` output: the measurements, the truth, and the systematic errors applied.

    ``data`` holds measured ``A`` (nominal kinematics at the joint angles),
    ``B``/``points`` (camera errors applied, flipped poses in ``B``), the true
    ``X = T_flange_marker``, ``Y = T_base_cam``, and ``A_true`` (actual flange
    poses). ``camera`` is the true `handeye.calib.model.CameraCorrection`; ``flipped``
    the indices of half-turned marker poses; ``robot_rms_m`` the RMS flange
    position error of the measured poses (kinematics + repeatability); ``q``
    the joint angles (N, 6), rad; ``kinematics`` the robot's actual standard-DH
    parameters (`ur_forward`: ``d``, ``a``, ``alpha``, ``offsets``, each (6,)),
    of which ``A`` uses the nominal `UR10_DH` with zero offsets.
    """

    data: SimulatedData
    camera: object
    flipped: np.ndarray
    robot_rms_m: float
    q: np.ndarray
    kinematics: dict


def seen_points(B_true, prof: RealisticProfile, camera, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """What the realistic camera reports (N, 3) for true marker poses ``B_true`` (N, 4, 4), and their covariance.

    Point noise of `handeye.calib.noise` (the covariance returned, (N, 3, 3)), colour/depth
    misregistration (the depth of the marker plane read ``misregistration_px``
    off), then the camera's systematic error ``camera`` (`handeye.calib.model.CameraCorrection`).
    """
    from handeye.calib.noise import FOCAL_PX, default_point_cov

    p_true = B_true[:, :3, 3]
    cov = default_point_cov(p_true)
    p = p_true + np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=(len(p_true), 3)))
    shift = prof.misregistration_px / FOCAL_PX * p[:, 2:3] * np.array([1.0, 0.0])
    nrm = B_true[:, :3, 2]
    dz = -(nrm[:, :2] * shift).sum(axis=1) / nrm[:, 2]
    p = p * ((p[:, 2] + dz) / p[:, 2])[:, None]
    return camera.measure(p), cov


def _cell_frames(rng: np.random.Generator, setup: Setup, distance: float) -> tuple[np.ndarray, np.ndarray]:
    """``X`` and ``Y`` of a realistic cell: a marker (eye-to-hand) or camera (eye-in-hand) mounted on the flange a
    few cm and tenths of a rad off, and the camera (``T_base_cam``) or marker (``T_base_marker``) ``distance`` m
    in front of it at the working pose, facing it."""
    dh = UR10_DH
    X = tf.make_transform(Rotation.from_euler("xyz", rng.uniform(-0.3, 0.3, size=3)).as_matrix(),
                          rng.uniform(-0.05, 0.05, size=3) + [0.0, 0.0, 0.03])
    A0 = ur_forward(_WORKING_JOINTS[None], dh["d"], dh["a"], dh["alpha"], np.zeros(6))[0] @ X
    if setup == Setup.EYE_IN_HAND:
        return X, A0 @ tf.make_transform(Rotation.from_euler("y", np.pi).as_matrix(), [0.0, 0.0, distance])
    return X, _look_at(A0[:3, 3] + distance * A0[:3, 2], A0[:3, 3])


def realistic_profile(n: int, rng: np.random.Generator, profile: RealisticProfile | None = None, *,
                      distance: float = 0.8, setup: Setup = Setup.EYE_TO_HAND) -> RealisticData:
    """A UR10 cell with the systematic errors of a real one (`RealisticProfile`), and the truth.

    Joint configurations are drawn around a working pose (+-8 deg on the
    shoulder/elbow joints, +-25 deg on the wrist); the actual flange pose is the
    forward kinematics with the perturbed DH parameters (plus repeatability
    noise), the reported one that of the nominal parameters. A static camera
    ``distance`` m in front of the marker sees it with the point noise of
    `handeye.calib.noise`, then the camera's systematic errors: colour/depth
    misregistration (the depth of the marker plane is read ``misregistration_px``
    off), depth scale and offset along the ray and the focal scale
    (`handeye.calib.model.CameraCorrection`). Marker poses get orientation noise and,
    for ``flip_fraction`` of the samples, a half turn about the board normal
    through ``board_center``.

    Eye-in-hand (``setup``) the same camera rides on the flange
    (``X = T_flange_cam``) and sees a static marker (``Y = T_base_marker``)
    ``distance`` m in front of it at the working pose; the poses keep the
    marker within the camera's field of view.
    """
    from handeye.calib.model import CameraCorrection

    prof = profile if profile is not None else RealisticProfile()
    dh = UR10_DH
    off_true = rng.normal(scale=np.deg2rad(prof.joint_offset_deg), size=6)
    d_true = dh["d"] + rng.normal(scale=prof.link_length_m, size=6)
    a_true = dh["a"] + rng.normal(scale=prof.link_length_m, size=6)
    al_true = dh["alpha"] + rng.normal(scale=np.deg2rad(prof.twist_deg), size=6)
    setup = check_setup(setup)
    X, Y = _cell_frames(rng, setup, distance)
    q = _visible_joints(n, rng, X, Y, setup)
    A = ur_forward(q, dh["d"], dh["a"], dh["alpha"], np.zeros(6))
    A_true = ur_forward(q, d_true, a_true, al_true, off_true)
    A_true = A_true @ tf.from_rotvec_translation(rng.normal(scale=prof.repeatability_rad, size=(n, 3)),
                                                 rng.normal(scale=prof.repeatability_m, size=(n, 3)))
    if prof.pose_error_m:
        A_true[:, :3, 3] += rng.normal(scale=prof.pose_error_m, size=(n, 3))
    B_true = _camera_marker(A_true, X, Y, setup)
    camera = CameraCorrection(prof.depth_scale, prof.depth_offset, prof.focal_scale)
    points, cov = seen_points(B_true, prof, camera, rng)
    B = B_true @ tf.from_rotvec_translation(rng.normal(scale=prof.orientation_noise_rad, size=(n, 3)), np.zeros((n, 3)))
    B[:, :3, 3] = points
    n_flip = int(round(prof.flip_fraction * n))
    flipped = np.sort(rng.choice(n, size=n_flip, replace=False)) if n_flip else np.zeros(0, dtype=int)
    if n_flip:
        F = tf.make_transform(tf.so3_exp(np.array([0.0, 0.0, np.pi])), 2 * np.asarray(prof.board_center))
        B[flipped] = B[flipped] @ F
    robot_rms = float(np.sqrt(np.mean(np.sum((A[:, :3, 3] - A_true[:, :3, 3]) ** 2, axis=1) / 3)))
    data = SimulatedData(A, B, points, cov, X, Y, A_true, B_true, setup)
    kinematics = {"d": d_true, "a": a_true, "alpha": al_true, "offsets": off_true}
    return RealisticData(data, camera, flipped, robot_rms, q, kinematics)


def workspace_points(real: RealisticData, m: int, rng: np.random.Generator) -> np.ndarray:
    """True marker centres (m, 3) in the camera transform's parent frame at ``m`` fresh visible poses of ``real``'s
    cell, m: the base frame eye-to-hand, the flange frame eye-in-hand (``A^-1 T_base_marker``).

    Drawn like the calibration samples (same joint span, marker in view), with
    the cell's actual kinematics: the points a camera calibrated on that cell
    is then used on (held out from the calibration).
    """
    d, kin = real.data, real.kinematics
    q = _visible_joints(m, rng, d.X, d.Y, d.setup)
    A = ur_forward(q, kin["d"], kin["a"], kin["alpha"], kin["offsets"])
    return (A @ d.X if d.setup == Setup.EYE_TO_HAND else tf.invert(A) @ d.Y)[:, :3, 3]


# --------------------------------------------------------------------------- production shift

@dataclass(frozen=True)
class Shift:
    """A production shift of the realistic cell (`shift_stream`).

    ``stops`` tool stops (tool tilt within ``max_tilt_deg`` of the working
    pose) visited in turn, one sample every ``sample_s``; the camera mount
    drifts ``drift_mm_h`` along a random direction, and is bumped at each
    ``(hour, mm, deg)`` of ``bumps`` (its center shifted, the camera turned
    about it, random directions). ``stop_jitter_deg`` varies each visit of a
    stop (every joint, 1-sigma, drawn anew per visit): a program whose stops
    repeat only roughly, such as vision-guided picks (0.5 deg moves the tool
    about 1 cm). `eye_in_hand_shift` turns the flange pose by it about each
    axis and shifts it by that angle times `JITTER_REACH_M` along each.
    """

    hours: float = 8.0
    sample_s: float = 30.0
    stops: int = 4
    max_tilt_deg: float = 10.0
    drift_mm_h: float = 0.5
    bumps: tuple = ((2.0, 5.0, 0.3), (4.5, 5.0, 0.3), (7.0, 5.0, 0.3))
    stop_jitter_deg: float = 0.0


#: Lever (m) that turns `Shift.stop_jitter_deg` into the flange's shift per axis in `eye_in_hand_shift`.
JITTER_REACH_M = 1.0


@dataclass(frozen=True)
class ShiftData:
    """`shift_stream` output: what the monitor gets, and the truth.

    ``t`` (n,) s; ``A`` (n, 4, 4) reported flange poses (nominal kinematics);
    ``points`` (n, 3) measured marker centers and ``point_cov`` (n, 3, 3);
    ``q`` (n, 6) joints; ``stop`` (n,) the stop visited; ``Y`` (n, 4, 4) the
    true camera transform at each sample (``T_base_cam``; ``T_flange_cam`` from
    `eye_in_hand_shift`); ``bumped`` the index of the first sample after each bump.
    """

    t: np.ndarray
    A: np.ndarray
    points: np.ndarray
    point_cov: np.ndarray
    q: np.ndarray
    stop: np.ndarray
    Y: np.ndarray
    bumped: np.ndarray


def production_stops(real: RealisticData, n: int, max_tilt_deg: float, rng: np.random.Generator) -> np.ndarray:
    """Joints (n, 6) of ``n`` tool stops of ``real``'s cell: marker in view, tool tilt within ``max_tilt_deg``.

    The tilt is the angle between the tool axis and the working pose's; the
    stops are spread out (each the farthest candidate from those chosen), so
    that three of them are never on one line.
    """
    dh = UR10_DH
    z0 = ur_forward(_WORKING_JOINTS[None], dh["d"], dh["a"], dh["alpha"], np.zeros(6))[0][:3, 2]
    cand = np.empty((0, 6))
    while len(cand) < 20 * n:
        q = _visible_joints(200, rng, real.data.X, real.data.Y, real.data.setup)
        A = ur_forward(q, dh["d"], dh["a"], dh["alpha"], np.zeros(6))
        tilt = np.rad2deg(np.arccos(np.clip(A[:, :3, 2] @ z0, -1.0, 1.0)))
        cand = np.vstack([cand, q[tilt <= max_tilt_deg]])
    pos = ur_forward(cand, dh["d"], dh["a"], dh["alpha"], np.zeros(6))[:, :3, 3]
    chosen = [int(rng.integers(len(cand)))]
    while len(chosen) < n:
        d = np.min(np.linalg.norm(pos[:, None] - pos[chosen][None], axis=2), axis=1)
        chosen.append(int(np.argmax(d)))
    return cand[chosen]


def shift_stream(real: RealisticData, shift: Shift, rng: np.random.Generator,
                 profile: RealisticProfile | None = None) -> ShiftData:
    """A shift of production samples on ``real``'s cell (its robot and camera errors), with drift and bumps.

    Each stop's reported pose is the nominal kinematics of its joints; the
    actual one follows the cell's DH parameters plus repeatability noise drawn
    anew at every visit. The camera sees the marker as `realistic_profile`'s
    does (`seen_points`).
    """
    prof = profile if profile is not None else RealisticProfile()
    dh, kin, d = UR10_DH, real.kinematics, real.data
    q_stops = production_stops(real, shift.stops, shift.max_tilt_deg, rng)
    n = int(shift.hours * 3600.0 / shift.sample_s)
    t = np.arange(n) * shift.sample_s
    stop = np.arange(n) % shift.stops
    q = q_stops[stop]
    if shift.stop_jitter_deg:
        q = q + rng.normal(scale=np.deg2rad(shift.stop_jitter_deg), size=q.shape)
    A = ur_forward(q, dh["d"], dh["a"], dh["alpha"], np.zeros(6))
    A_true = ur_forward(q, kin["d"], kin["a"], kin["alpha"], kin["offsets"])
    A_true = A_true @ tf.from_rotvec_translation(rng.normal(scale=prof.repeatability_rad, size=(n, 3)),
                                                 rng.normal(scale=prof.repeatability_m, size=(n, 3)))
    direction = random_directions(1, rng)[0]
    offset = np.outer(t / 3600.0 * shift.drift_mm_h * 1e-3, direction)
    R = np.broadcast_to(d.Y[:3, :3], (n, 3, 3)).copy()
    bumped = []
    for hour, mm, deg in shift.bumps:
        after = t >= hour * 3600.0
        if not after.any():
            continue
        bumped.append(int(np.argmax(after)))
        offset[after] += mm * 1e-3 * random_directions(1, rng)[0]
        R[after] = tf.so3_exp(np.deg2rad(deg) * random_directions(1, rng)[0]) @ R[after]
    Y = tf.make_transform(R, d.Y[:3, 3] + offset)
    points, cov = seen_points(tf.invert(Y) @ A_true @ d.X, prof, real.camera, rng)
    return ShiftData(t, A, points, cov, q, stop, Y, np.array(bumped, dtype=int))


def eye_in_hand_shift(cell: SimulatedData, stops: np.ndarray, shift: Shift, rng: np.random.Generator) -> ShiftData:
    """A shift of an eye-in-hand ``cell`` (`realistic_cell`): the camera slips on the flange.

    ``stops`` (S, 4, 4) are the program's flange poses, visited in turn every
    ``shift.sample_s``; the true ``T_flange_cam`` drifts ``shift.drift_mm_h``
    along a random direction of the camera frame and is bumped at each
    ``(hour, mm, deg)`` (``T_flange_cam <- T_flange_cam @ bump``, random
    directions). The camera sees the static marker with `realistic_cell`'s
    point noise. ``ShiftData.Y`` holds the true ``T_flange_cam`` per sample.
    """
    n = int(shift.hours * 3600.0 / shift.sample_s)
    t = np.arange(n) * shift.sample_s
    stop = np.arange(n) % len(stops)
    A = stops[stop]
    if shift.stop_jitter_deg:
        jitter = np.deg2rad(shift.stop_jitter_deg)
        A = A @ tf.from_rotvec_translation(rng.normal(scale=jitter, size=(n, 3)),
                                           rng.normal(scale=jitter * JITTER_REACH_M, size=(n, 3)))
    direction = random_directions(1, rng)[0]
    slip = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    slip[:, :3, 3] = np.outer(t / 3600.0 * shift.drift_mm_h * 1e-3, direction)
    bumped = []
    for hour, mm, deg in shift.bumps:
        after = t >= hour * 3600.0
        if not after.any():
            continue
        bumped.append(int(np.argmax(after)))
        bump = tf.from_rotvec_translation(np.deg2rad(deg) * random_directions(1, rng)[0],
                                          mm * 1e-3 * random_directions(1, rng)[0])
        slip[after] = slip[after] @ bump
    X = cell.X @ slip
    p_true = (tf.invert(A @ X) @ cell.Y)[:, :3, 3]
    cov = point_covariance(p_true, 0.001, 0.003)
    points = p_true + np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=(n, 3)))
    return ShiftData(t, A, points, cov, np.zeros((n, 6)), stop, X, np.array(bumped, dtype=int))


# --------------------------------------------------------------------------- production cell, sample by sample

class CellSample(NamedTuple):
    """One sample of a `ProductionCell`: the flange pose as reported, the measured marker centre, its
    covariance, the kinematic-error factor (6, P) or None, and the joints (6,) or None."""

    A: np.ndarray
    point: np.ndarray
    point_cov: np.ndarray
    factor: np.ndarray | None
    joints: np.ndarray | None


@dataclass(frozen=True)
class ProductionCell:
    """A simulated cell in production, for the monitoring engine: its calibration samples, its program's stops,
    and samples at those stops taken one at a time (`sample`) with whatever true camera transform the caller
    holds (bumped, drifted: `moved`).

    Eye-to-hand (`realistic_profile`: a UR10 with DH error and a camera with
    systematic errors) the camera transform is ``T_base_cam``; eye-in-hand
    (`realistic_cell`: point noise only) it is ``T_flange_cam``.

    Attributes
    ----------
    setup : Setup
    A, points, point_cov : ndarray (N, 4, 4), (N, 3), (N, 3, 3)
        The calibration samples (flange poses as reported, measured marker centres, their covariance).
    factor : ndarray (N, 6, P) or None
        Their kinematic-error factor (eye-to-hand with ``joints``), else None.
    C : ndarray (4, 4)
        The true camera transform.
    marker : ndarray (4, 4)
        The true marker-side transform (``T_flange_marker`` / ``T_base_marker``).
    stops : ndarray (S, 6) or (S, 4, 4)
        The program's stops: joints eye-to-hand, true flange poses eye-in-hand.
    real : RealisticData or None
        Eye-to-hand: the cell (kinematics, camera errors).
    """

    setup: Setup
    A: np.ndarray
    points: np.ndarray
    point_cov: np.ndarray
    factor: np.ndarray | None
    C: np.ndarray
    marker: np.ndarray
    stops: np.ndarray
    real: RealisticData | None
    profile: RealisticProfile

    def sample(self, stop: int, C: np.ndarray, rng: np.random.Generator, jitter_deg: float = 0.0) -> CellSample:
        """A sample at ``stop`` with the true camera transform ``C`` (factor and joints None without joints).
        ``jitter_deg`` (1-sigma) moves the robot off the stop, per joint eye-to-hand, per axis (and that angle
        times `JITTER_REACH_M` of shift) eye-in-hand."""
        prof = self.profile
        if self.setup == Setup.EYE_TO_HAND:
            kin, dh = self.real.kinematics, UR10_DH
            q = self.stops[stop] + (rng.normal(scale=np.deg2rad(jitter_deg), size=6) if jitter_deg else 0.0)
            A = ur_forward(q[None], dh["d"], dh["a"], dh["alpha"], np.zeros(6))[0]
            A_true = ur_forward(q[None], kin["d"], kin["a"], kin["alpha"], kin["offsets"])[0]
            A_true = A_true @ tf.from_rotvec_translation(rng.normal(scale=prof.repeatability_rad, size=3),
                                                         rng.normal(scale=prof.repeatability_m, size=3))
            p, cov = seen_points((tf.invert(C) @ A_true @ self.marker)[None], prof, self.real.camera, rng)
            if self.factor is None:
                return CellSample(A, p[0], cov[0], None, None)
            return CellSample(A, p[0], cov[0], prof.dh_error_factor(q[None])[0], q)
        A = self.stops[stop]
        if jitter_deg:
            jitter = np.deg2rad(jitter_deg)
            A = A @ tf.from_rotvec_translation(rng.normal(scale=jitter, size=3),
                                               rng.normal(scale=jitter * JITTER_REACH_M, size=3))
        p_true = (tf.invert(A @ C) @ self.marker)[:3, 3]
        cov = point_covariance(p_true[None], 0.001, 0.003)[0]
        return CellSample(A, p_true + np.linalg.cholesky(cov) @ rng.normal(size=3), cov, None, None)

    def moved(self, C: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
        """``C`` after a move by a rotation vector (rad) about the camera's centre and a translation (m): in the
        base frame eye-to-hand (a bumped mount), in the camera frame eye-in-hand (a camera slipping on the
        flange)."""
        if self.setup == Setup.EYE_TO_HAND:
            return tf.make_transform(tf.so3_exp(rotation) @ C[:3, :3], C[:3, 3] + translation)
        return C @ tf.from_rotvec_translation(rotation, translation)

    def displacement(self, C1: np.ndarray, C2: np.ndarray) -> float:
        """RMS over the stops (at their nominal poses) of how far the marker centre moves in the camera's view
        between true camera transforms ``C1`` and ``C2``, m: what the engine can see of a move."""
        if self.setup == Setup.EYE_TO_HAND:
            dh = UR10_DH
            A = ur_forward(self.stops, dh["d"], dh["a"], dh["alpha"], np.zeros(6))
            p1, p2 = ((tf.invert(C) @ A @ self.marker)[:, :3, 3] for C in (C1, C2))
        else:
            p1, p2 = ((tf.invert(self.stops @ C) @ self.marker)[:, :3, 3] for C in (C1, C2))
        return float(np.sqrt(np.mean(np.sum((p1 - p2) ** 2, axis=1))))


def production_cell(setup: Setup, n_calibration: int, n_stops: int, rng: np.random.Generator, *,
                    joints: bool = True, max_tilt_deg: float = 10.0,
                    profile: RealisticProfile | None = None) -> ProductionCell:
    """A `ProductionCell` calibrated from ``n_calibration`` samples with a program of ``n_stops`` stops.

    Eye-to-hand the stops are `production_stops` (tool tilt within
    ``max_tilt_deg``, spread out); eye-in-hand they are further poses of
    `realistic_cell`. ``joints``: the calibration samples (and `sample`) carry
    the robot's kinematic-error factor (eye-to-hand only).
    """
    setup = check_setup(setup)
    prof = profile if profile is not None else RealisticProfile()
    if setup == Setup.EYE_TO_HAND:
        real = realistic_profile(n_calibration, rng, prof)
        d = real.data
        stops = production_stops(real, n_stops, max_tilt_deg, rng)
        factor = prof.dh_error_factor(real.q) if joints else None
        return ProductionCell(setup, d.A, d.points, d.point_cov, factor, d.Y, d.X, stops, real, prof)
    cell = realistic_cell(n_calibration + n_stops, rng, setup=setup)
    n = n_calibration
    return ProductionCell(setup, cell.A[:n], cell.points[:n], cell.point_cov[:n], None, cell.X, cell.Y,
                          cell.A_true[n:], None, prof)
