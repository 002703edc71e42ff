"""The simulated cell at work: a looping production program and a camera bump, for `handeye monitor`.

On a real cell the robot runs its own program while ``handeye monitor``
watches. On a simulated cell (the ``ur_sim`` robot) nothing would move
the robot, so `start_production` gives its simulated controller a looping
program (`mocks.ur_sim.program`): waypoints around the start pose, a tool stop
at each. `Bump` knocks the rendered camera partway through a run, as a
forklift would: eye-to-hand the camera center shifts along base x and the
camera turns about base y about its own center; eye-in-hand the same in the
camera frame (``T_flange_cam <- T_flange_cam @ bump``, the camera slips on
its mount). Either way the camera moves by exactly the bump's mm and deg.

This module knows the simulator only through the robot's ``sim`` handle
(`mocks.ur_sim.SimProcess`) and the rendered camera's config; a real robot
has neither, and `start_production` then does nothing.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from app.planning import random_pose
from app.config import CalibrateConfig
from calib import transforms as tf
from calib.setup import Setup

log = logging.getLogger(__name__)

#: The jobs of the program's tool stops, in turn (only names, logged by the simulator).
TOOL_JOBS = ("pick", "inspect", "glue", "place")


def production_program(T_start: np.ndarray, q_start, model: str, cal: CalibrateConfig, rng: np.random.Generator,
                       *, n_waypoints: int = 14, pause_s: float = 0.6, speed: float = 2.0,
                       acceleration: float = 8.0) -> dict:
    """A looping program (JSON form of `mocks.ur_sim.program`) through random poses around ``T_start``.

    Poses are drawn like the active calibration's (`app.calibrate.random_pose`,
    ``cal.translation_range_m`` and ``cal.tilt_deg``), so the marker stays in
    view. More waypoints than the monitor's diversity window keeps each
    lap's poses worth sampling again.
    """
    from drivers.robot import ur_kinematics as kin

    waypoints, q = [], np.asarray(q_start, dtype=float)
    for _ in range(50 * n_waypoints):
        if len(waypoints) == n_waypoints:
            break
        q_next = kin.inverse_nearest(random_pose(T_start, cal, rng), q, model)
        if q_next is None:
            continue
        waypoints.append({"q": q_next.tolist(), "pause_s": pause_s, "tool": TOOL_JOBS[len(waypoints) % len(TOOL_JOBS)]})
        q = q_next
    return {"waypoints": waypoints, "speed": speed, "acceleration": acceleration}


def start_production(robot, cfg, rng: np.random.Generator, *, say=log.info) -> bool:
    """Start a looping production program on a simulated robot; False (nothing done) on a real one."""
    sim = getattr(robot, "sim", None)
    if sim is None:
        return False
    state = robot.read()
    cal = cfg.calibrate.model_copy(update={"tilt_deg": min(cfg.calibrate.tilt_deg, 30.0)})
    program = production_program(state.T_base_flange, state.q, getattr(cfg.robot, "model", "ur10"), cal, rng)
    sim.start_program(program)
    say(f"simulated robot: running a looping production program ({len(program['waypoints'])} waypoints, "
        f"{program['waypoints'][0]['pause_s']} s tool stops) so that there is something to monitor")
    return True


@dataclass
class Bump:
    """A knock of the simulated camera after ``after`` samples: ``translation_mm`` along base x, ``rotation_deg`` about base y."""

    after: int
    translation_mm: float = 10.0
    rotation_deg: float = 0.5

    @property
    def transform(self) -> np.ndarray:
        return tf.from_rotvec_translation([0.0, np.deg2rad(self.rotation_deg), 0.0],
                                          [self.translation_mm * 1e-3, 0.0, 0.0])

    def apply(self, camera, setup: Setup) -> np.ndarray:
        """Move the rendered camera; returns its new true transform (``T_base_cam`` / ``T_flange_cam``)."""
        c = camera.config
        if Setup(setup) == Setup.EYE_TO_HAND:
            T, B = np.asarray(c.T_base_cam, dtype=float), self.transform
            c.T_base_cam = tf.make_transform(B[:3, :3] @ T[:3, :3], T[:3, 3] + B[:3, 3]).tolist()
            return np.asarray(c.T_base_cam)
        c.T_flange_cam = (np.asarray(c.T_flange_cam, dtype=float) @ self.transform).tolist()
        return np.asarray(c.T_flange_cam)
