import numpy as np
import pytest

from handeye.calib import CalibrationError
from handeye.calib import transforms as tf


@pytest.fixture
def rng():
    return np.random.default_rng(0)


def random_T(n, rng):
    return tf.make_transform(tf.random_rotations(n, np.pi, rng), rng.normal(size=(n, 3)))


def test_invert_is_inverse(rng):
    T = random_T(5, rng)
    np.testing.assert_allclose(T @ tf.invert(T), np.broadcast_to(np.eye(4), T.shape), atol=1e-12)


@pytest.mark.parametrize("to_fn,from_fn", [
    (tf.to_ur_pose, tf.from_ur_pose),
])
def test_pose_vector_round_trip(rng, to_fn, from_fn):
    T = random_T(7, rng)
    np.testing.assert_allclose(from_fn(to_fn(T)), T, atol=1e-12)


def test_quaternion_round_trip_scalar_last(rng):
    T = random_T(7, rng)
    xyz, q = tf.to_xyz_quat(T)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(tf.from_xyz_quat(xyz, q), T, atol=1e-12)
    # identity rotation is (0, 0, 0, 1) in scalar-last order
    np.testing.assert_allclose(tf.to_xyz_quat(np.eye(4))[1], [0, 0, 0, 1])


def test_pose_error_measures_known_offset():
    T = np.eye(4)
    T2 = tf.from_rotvec_translation([0, 0, 0.1], [0.003, 0.004, 0])
    dr, dt = tf.pose_error(T2, T)
    assert dr == pytest.approx(0.1)
    assert dt == pytest.approx(0.005)


def test_project_to_so3_fixes_noise(rng):
    R = tf.random_rotations(3, np.pi, rng)
    R_noisy = R + 1e-3 * rng.normal(size=R.shape)
    Rp = tf.project_to_so3(R_noisy)
    np.testing.assert_allclose(Rp @ Rp.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    assert np.all(np.linalg.det(Rp) > 0)


@pytest.mark.parametrize("bad,msg", [
    (np.zeros((3, 4, 4)), "last row"),
    (np.full((2, 4, 4), np.nan), "NaN"),
    (np.diag([2.0, 1, 1, 1])[None], "not a proper rotation"),
    (np.eye(3)[None], "shape"),
])
def test_check_transforms_names_the_problem(bad, msg):
    with pytest.raises(CalibrationError, match=msg):
        tf.check_transforms(bad, "A")


def test_check_transforms_rejects_reflection():
    T = np.eye(4)
    T[0, 0] = -1
    with pytest.raises(CalibrationError, match=r"A\[0\] rotation"):
        tf.check_transforms(T[None], "A")


def test_check_points_names_index():
    p = np.zeros((4, 3))
    p[2, 1] = np.inf
    with pytest.raises(CalibrationError, match=r"B\[2\]"):
        tf.check_points(p, "B")


def test_check_transforms_names_first_bad_index_in_a_stack(rng):
    T = random_T(6, rng)
    assert tf.check_transforms(T, "A") is not None
    bad = T.copy()
    bad[4, :3, :3] *= 1.001  # scaled rotation
    bad[5, 0, 0] = -bad[5, 0, 0]
    with pytest.raises(CalibrationError, match=r"A\[4\] rotation is not a proper rotation"):
        tf.check_transforms(bad, "A")
    bad[2, 3, 1] = 0.1
    with pytest.raises(CalibrationError, match=r"A\[2\] last row"):
        tf.check_transforms(bad, "A")
    reflected = T.copy()
    reflected[3, :3, :3] = -reflected[3, :3, :3]
    with pytest.raises(CalibrationError, match=r"A\[3\].*det = -1"):
        tf.check_transforms(reflected, "A")


def test_rotation_angle_small_and_half_turn():
    R = tf.from_rotvec_translation(np.array([[1e-9, 0, 0], [0, 0, np.pi], [0, 2.0, 0]]), np.zeros((3, 3)))[:, :3, :3]
    np.testing.assert_allclose(tf.rotation_angle(R), [1e-9, np.pi, 2.0], rtol=1e-9)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-6, 1e-4, 0.3, 2.0, np.pi - 1e-6, np.pi])
def test_so3_exp_and_log_agree_with_scipy_at_every_angle(rng, angle):
    """The written-out SO(3) exp/log (Rodrigues, quaternion log) match scipy's Rotation, near 0 and pi too."""
    from scipy.spatial.transform import Rotation

    axes = rng.normal(size=(50, 3))
    v = axes / np.linalg.norm(axes, axis=1, keepdims=True) * angle
    R = Rotation.from_rotvec(v).as_matrix()
    np.testing.assert_allclose(tf.so3_exp(v), R, atol=1e-15)
    # At pi the rotation vector's sign is ambiguous: compare the rotations it gives.
    np.testing.assert_allclose(Rotation.from_rotvec(tf.so3_log(R)).as_matrix(), R, atol=2e-15)
    if angle < 3.0:
        np.testing.assert_allclose(tf.so3_log(R), v, atol=1e-15)


def test_register_points_recovers_a_rigid_transform():
    rng = np.random.default_rng(7)
    T = tf.from_rotvec_translation(rng.normal(size=3), rng.normal(size=3))
    p = rng.normal(size=(6, 3))
    assert np.allclose(tf.register_points(p, tf.transform_points(T, p)), T, atol=1e-9)
    with pytest.raises(CalibrationError, match="N >= 3"):
        tf.register_points(p[:2], p[:2])
    with pytest.raises(CalibrationError, match="one shape"):
        tf.register_points(p, p[:4])
