"""The simulated arm's true kinematics: DH error and repeatability the controller does not know.

A real controller computes the flange pose it reports (``actual_TCP_pose``)
from the joint encoders through its *nominal* DH model. The real flange
follows the arm's *true* DH parameters, which differ by a little (joint zero
offsets of a few hundredths of a degree, link lengths and twists off by
tenths of a mm / hundredths of a degree: 1-3 mm at the flange of an
uncalibrated UR10), and each stop lands with a small random error the
encoders do not see (the datasheet repeatability, UR10 +-0.1 mm).

`SimRobotError` is the configuration (off unless given; the default
magnitudes are `handeye.calib.simulate.RealisticProfile`'s). `TrueArm` draws the
true DH parameters once per simulated cell from its seed and the per-stop
error from its own generator; the controller reports nominal poses and
exposes the true one (``sim truth`` on the dashboard port) for the rendered
camera, which sees the real flange.
"""

from __future__ import annotations

import numpy as np

from handeye.calib import transforms as tf
from handeye.calib.params import Int, NonNegativeFloat, Params
from handeye.calib.robot_error import UR_ALPHA, ur_forward
from handeye.drivers.robot import ur_kinematics as kin


class SimRobotError(Params):
    """Kinematic error and repeatability of the simulated arm (``[robot] sim_robot_error`` of ``type = "ur_sim"``).

    Attributes
    ----------
    joint_offset_deg : float
        1-sigma of each joint's zero offset, deg.
    link_length_m : float
        1-sigma of each DH length ``d`` and ``a``, m.
    twist_deg : float
        1-sigma of each DH twist ``alpha``, deg.
    repeatability_m, repeatability_deg : float
        1-sigma per axis of the flange pose error of each stop (translation m,
        rotation deg), drawn anew when a motion ends and held until the next one.
    seed : int
        Seed of the true DH parameters and of the stop errors.
    """

    joint_offset_deg: NonNegativeFloat = 0.03
    link_length_m: NonNegativeFloat = 0.0003
    twist_deg: NonNegativeFloat = 0.02
    repeatability_m: NonNegativeFloat = 0.1e-3 / 3
    repeatability_deg: NonNegativeFloat = 0.01 / 3
    seed: Int = 0


class TrueArm:
    """The arm as it really is: perturbed DH parameters and the error of the current stop.

    Parameters
    ----------
    model : str
        UR model whose nominal DH parameters are perturbed.
    error : SimRobotError

    Attributes
    ----------
    d, a, alpha, offsets : ndarray, shape (6,)
        True standard-DH parameters (`handeye.calib.robot_error.ur_forward`), m and rad.
    T_stop : ndarray, shape (4, 4)
        Flange-frame error of the current stop (identity before the first stop).
    """

    def __init__(self, model: str, error: SimRobotError):
        g = kin.geometry(model)
        self.error = error
        self.rng = np.random.default_rng(error.seed)
        self.offsets = self.rng.normal(scale=np.deg2rad(error.joint_offset_deg), size=6)
        self.d = g.d + self.rng.normal(scale=error.link_length_m, size=6)
        self.a = g.a + self.rng.normal(scale=error.link_length_m, size=6)
        self.alpha = UR_ALPHA + self.rng.normal(scale=np.deg2rad(error.twist_deg), size=6)
        self.T_stop = np.eye(4)

    def new_stop(self) -> None:
        """A motion ended: the arm settles with a fresh repeatability error."""
        e = self.error
        self.T_stop = tf.from_rotvec_translation(self.rng.normal(scale=np.deg2rad(e.repeatability_deg), size=3),
                                                 self.rng.normal(scale=e.repeatability_m, size=3))

    def flange(self, q) -> np.ndarray:
        """True ``T_base_flange`` (4, 4) at joints ``q`` (6,), rad: true DH, then the current stop's error."""
        return ur_forward(np.asarray(q, float)[None], self.d, self.a, self.alpha, self.offsets)[0] @ self.T_stop

    def state(self) -> dict:
        """The true parameters (JSON-serialisable), for tests and benchmarks."""
        return {"d": self.d.tolist(), "a": self.a.tolist(), "alpha": self.alpha.tolist(),
                "offsets": self.offsets.tolist()}
