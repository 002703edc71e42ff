"""handeye.drivers.camera.depth: the one m <-> 16-bit mm conversion used by OpenNI2, recordings and sessions."""

import numpy as np

from handeye.drivers.camera.depth import depth_from_mm, depth_to_mm


def test_round_trip_to_the_millimetre():
    depth = np.array([[0.0, 0.0004, 0.0006], [1.2344, 1.2346, 65.535]], dtype=np.float32)
    mm = depth_to_mm(depth)
    assert mm.dtype == np.uint16
    np.testing.assert_array_equal(mm, [[0, 0, 1], [1234, 1235, 65535]])
    back = depth_from_mm(mm)
    assert back.dtype == np.float32
    np.testing.assert_allclose(back, [[0.0, 0.0, 0.001], [1.234, 1.235, 65.535]], rtol=1e-6)


def test_no_reading_and_out_of_range():
    depth = np.array([np.nan, -0.5, 70.0, np.inf])
    np.testing.assert_array_equal(depth_to_mm(depth), [0, 0, 65535, 65535])
