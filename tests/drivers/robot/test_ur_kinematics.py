import numpy as np
import pytest

from handeye.calib.errors import ParameterError
from handeye.drivers.robot import ur_kinematics as kin


def test_ur10_zero_pose_is_the_published_stretched_out_arm():
    # All joints 0: arm stretched along -x, flange at (a2 + a3, -(d4 + d6), d1 - d5).
    T = kin.forward(np.zeros(6), "ur10")
    np.testing.assert_allclose(T[:3, 3], [-1.1843, -0.256141, 0.0116], atol=1e-9)
    np.testing.assert_allclose(T[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)


@pytest.mark.parametrize("model", sorted(kin.UR_MODELS))
def test_inverse_kinematics_round_trip(model):
    rng = np.random.default_rng(3)
    for q in rng.uniform(-np.pi, np.pi, size=(40, 6)):
        T = kin.forward(q, model)
        sols = kin.inverse_all(T, model)
        assert len(sols) >= 1
        np.testing.assert_allclose(kin.forward(sols, model), np.broadcast_to(T, sols.shape[:1] + (4, 4)), atol=1e-7)
        np.testing.assert_allclose(kin.inverse_nearest(T, q, model), q, atol=1e-7)


def test_inverse_nearest_honours_joint_limits():
    q = np.array([0.3, -1.2, 1.6, -1.97, -1.5708, 0.2])
    T = kin.forward(q, "ur10")
    limits = kin.UR_JOINT_LIMITS.copy()
    limits[2] = [-np.pi, 0.0]  # forbid the elbow-up branch the arm is in
    other = kin.inverse_nearest(T, q, "ur10", limits)
    assert other is not None and other[2] <= 0.0
    np.testing.assert_allclose(kin.forward(other, "ur10"), T, atol=1e-7)
    limits[:, :] = [-0.01, 0.01]
    assert kin.inverse_nearest(T, q, "ur10", limits) is None


def test_out_of_reach_has_no_solution_and_unknown_model_is_config_error():
    T = np.eye(4)
    T[:3, 3] = [3.0, 0.0, 0.5]
    assert kin.inverse_all(T, "ur10").shape == (0, 6)
    with pytest.raises(ParameterError, match="model"):
        kin.geometry("ur99")
