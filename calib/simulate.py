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

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from calib import transforms as tf
from calib.setup import Setup, check_setup


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


def _random_direction(n: int, rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _random_translation(n: int, center: float, half_width: float, rng) -> np.ndarray:
    return _random_direction(n, rng) * rng.uniform(center - half_width, center + half_width, size=(n, 1))


def noise_transforms(n: int, max_angle: float, max_translation: float, rng) -> np.ndarray:
    """``n`` noise transforms (n, 4, 4) with angle <= max_angle (rad) and |t| <= max_translation (m).

    Angle and translation length are uniform in their ranges, directions uniform
    on the sphere (the paper's "|N_alpha| < ..., |N_t| < ...").
    """
    R = tf.random_rotations(n, max_angle, rng)
    t = _random_direction(n, rng) * rng.uniform(0.0, max_translation, size=(n, 1))
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
) -> SimulatedData:
    """A UR10 cell like the paper's real experiment, with known truth.

    The flange starts ``distance`` m in front of the camera with the marker
    facing it; each sample moves the flange by up to ``translation_range`` m
    per axis and rotates it by up to ``angle_range`` rad about a random axis.
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

    dR = tf.random_rotations(n, angle_range, rng)
    dt = rng.uniform(-translation_range, translation_range, size=(n, 3))
    A_true = tf.make_transform(dR @ R_flange0, p0 + dt)
    if setup == Setup.EYE_TO_HAND:
        B_true = tf.invert(Y) @ A_true @ X           # T_cam_marker
    else:
        B_true = tf.invert(A_true @ X) @ Y           # T_cam_marker = (T_base_flange T_flange_cam)^-1 T_base_marker

    points_true = B_true[:, :3, 3]
    cov = point_covariance(points_true, sigma_lateral, sigma_depth)
    # Split white noise into its along-ray and across-ray parts (no Cholesky: sigmas may be zero).
    ray = points_true / np.linalg.norm(points_true, axis=1, keepdims=True)
    white = rng.normal(size=(n, 3))
    along = np.sum(white * ray, axis=1, keepdims=True) * ray
    points = points_true + sigma_depth * along + sigma_lateral * (white - along)

    def gaussian_noise(sig):
        rv = rng.normal(scale=sig[0], size=(n, 3)) if sig[0] > 0 else np.zeros((n, 3))
        t = rng.normal(scale=sig[1], size=(n, 3)) if sig[1] > 0 else np.zeros((n, 3))
        return tf.from_rotvec_translation(rv, t)

    B = B_true @ gaussian_noise(pose_noise)
    B[:, :3, 3] = points                              # one translation noise model for poses and points
    A = A_true @ gaussian_noise(robot_noise)
    return SimulatedData(A, B, points, cov, X, Y, A_true, B_true, setup)


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


def moved_camera_points(data: SimulatedData, n_before: int, bump: np.ndarray) -> np.ndarray:
    """Points of an eye-to-hand ``data`` whose camera moves by ``bump`` (T_camold_camnew) after ``n_before`` samples.

    Each sample keeps its own measurement noise, so only the move differs.
    """
    noise = data.points - data.B_true[:, :3, 3]
    points = data.points.copy()
    points[n_before:] = tf.transform_points(tf.invert(bump), data.B_true[n_before:, :3, 3]) + noise[n_before:]
    return points
