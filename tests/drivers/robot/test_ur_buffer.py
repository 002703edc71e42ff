import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from handeye.drivers.errors import DeviceError
from handeye.calib.transforms import make_transform
from handeye.drivers.robot.base import RobotState
from handeye.drivers.robot.buffer import ClockMapper, StateBuffer


def _state(t, T):
    return RobotState(t, t, T, np.zeros(6), np.zeros(6), 7, 1)


def test_pose_at_interpolates_linear_and_slerp_and_refuses_outside():
    buf = StateBuffer(5.0)
    T0 = make_transform(np.eye(3), [0.0, 0.0, 0.0])
    T1 = make_transform(Rotation.from_euler("z", 90, degrees=True).as_matrix(), [1.0, 2.0, 0.0])
    buf.append(_state(10.0, T0))
    buf.append(_state(11.0, T1))
    T = buf.pose_at(10.25)
    np.testing.assert_allclose(T[:3, 3], [0.25, 0.5, 0.0])
    np.testing.assert_allclose(Rotation.from_matrix(T[:3, :3]).as_euler("xyz", degrees=True), [0, 0, 22.5], atol=1e-9)
    np.testing.assert_allclose(buf.pose_at(11.0), T1)
    with pytest.raises(DeviceError, match="100.0 ms after"):
        buf.pose_at(11.1)
    with pytest.raises(DeviceError, match="before"):
        buf.pose_at(9.0)


def test_ring_buffer_keeps_only_the_last_seconds():
    buf = StateBuffer(2.0)
    for t in np.arange(0.0, 5.01, 0.5):
        buf.append(_state(float(t), np.eye(4)))
    buf.append(_state(4.0, np.eye(4)))  # stale re-read: ignored
    assert buf.span() == (3.0, 5.0) and len(buf) == 5


def test_clock_mapper_removes_poll_jitter():
    rng = np.random.default_rng(0)
    offset = 1_700_000_000.0
    t_ctrl = np.arange(0.0, 2.0, 0.002)
    latency = 0.0003 + rng.exponential(0.002, size=t_ctrl.size)
    latency[::50] = 0.0003  # now and then a package is read right away
    mapper = ClockMapper(window=1.0)
    est = np.array([mapper.update(tc, tc + offset + lat) for tc, lat in zip(t_ctrl, latency)])
    err = est[100:] - (t_ctrl[100:] + offset)
    assert np.all(np.abs(err - 0.0003) < 1e-6)
