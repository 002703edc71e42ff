"""The simulated cell at work: a looping production program and a camera bump, for `handeye monitor`.

On a real cell the robot runs its own program while ``handeye monitor``
watches. On a simulated cell (the ``ur_sim`` robot) nothing would move
the robot, so `start_production` gives its simulated controller a looping
program (`handeye.mocks.ur_sim.program`) built from ``[production]``
(`handeye.app.config.ProductionConfig`: explicit waypoints, or random poses around the
start pose, or a pick-and-place of a few stops), a tool stop at each. `Bump`
knocks the rendered camera partway through a run, as a forklift would, through
the camera's scheduled mount bumps (``[camera.mount]``): eye-to-hand the camera
center shifts along base x and the camera turns about base y about its own
center; eye-in-hand the same in the camera frame (``T_flange_cam <-
T_flange_cam @ bump``, the camera slips on its mount). Either way the camera
moves by exactly the bump's mm and deg. `carried_knocks` gives a run that
continues from a monitoring run (or verifies its calibration in use) the
knocks that run's camera took; `knock_as_left` applies them and
`record_knocks` writes them to the new session.

This module knows the simulator only through what a robot declares
(`handeye.drivers.robot.base.Robot`: ``simulated``, ``kinematics``, ``start_program``)
and the rendered camera's ``add_bump``; on a real robot `start_production`
does nothing.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from handeye.app import calibration_in_use
from handeye.app.config import CalibrateConfig, ProductionConfig
from handeye.app.errors import ConfigError, SessionError
from handeye.app.planning import random_pose
from handeye.app.session import read_session
from handeye.calib import transforms as tf
from handeye.calib.setup import Setup
from handeye.drivers.robot.base import KinematicModel

log = logging.getLogger(__name__)

#: The jobs of the program's tool stops, in turn (only names, logged by the simulator).
TOOL_JOBS = ("pick", "inspect", "glue", "place")


def production_program(T_start: np.ndarray, q_start, kinematics: KinematicModel, cal: CalibrateConfig,
                       rng: np.random.Generator,
                       *, n_waypoints: int = 14, pause_s: float = 0.6, speed: float = 2.0,
                       acceleration: float = 8.0) -> dict:
    """A looping program (JSON form of `handeye.mocks.ur_sim.program`) through random poses around ``T_start``.

    Poses are drawn like the active calibration's (`handeye.app.planning.random_pose`,
    ``cal.translation_range_m`` and ``cal.tilt_deg``), so the marker stays in
    view. More waypoints than the monitor's diversity window keeps each
    lap's poses worth sampling again.
    """
    waypoints, q = [], np.asarray(q_start, dtype=float)
    for _ in range(50 * n_waypoints):
        if len(waypoints) == n_waypoints:
            break
        q_next = kinematics.inverse_nearest(random_pose(T_start, cal, rng), q)
        if q_next is None:
            continue
        waypoints.append({"q": q_next.tolist(), "pause_s": pause_s, "tool": TOOL_JOBS[len(waypoints) % len(TOOL_JOBS)]})
        q = q_next
    return {"waypoints": waypoints, "speed": speed, "acceleration": acceleration}


def pick_and_place_poses(T_start: np.ndarray, stops: int, radius_m: float, max_tilt_deg: float,
                         rng: np.random.Generator) -> np.ndarray:
    """``stops`` flange poses (stops, 4, 4) evenly spaced on a horizontal circle of ``radius_m`` around
    ``T_start``'s position (random phase), each turned by at most ``max_tilt_deg`` about its own origin."""
    phase = rng.uniform(0.0, 2 * np.pi)
    angles = phase + 2 * np.pi * np.arange(stops) / stops
    R = tf.random_rotations(stops, np.deg2rad(max_tilt_deg), rng)
    p = T_start[:3, 3] + radius_m * np.stack([np.cos(angles), np.sin(angles), np.zeros(stops)], axis=1)
    return tf.make_transform(R @ T_start[:3, :3], p)


def program_from_config(prod: ProductionConfig, T_start: np.ndarray, q_start, kinematics: KinematicModel,
                        cal: CalibrateConfig, rng: np.random.Generator) -> dict:
    """The simulator's program (JSON form of `handeye.mocks.ur_sim.program`) that ``[production]`` describes.

    Raises
    ------
    ConfigError
        Naming ``production.waypoints[i]`` or the preset when a stop has no inverse kinematics solution.
    """
    rng = rng if prod.seed is None else np.random.default_rng(prod.seed)
    common = {"speed": prod.speed, "acceleration": prod.acceleration}
    if prod.waypoints:
        waypoints, q = [], np.asarray(q_start, dtype=float)
        for i, w in enumerate(prod.waypoints):
            if w.q is not None:
                q = np.asarray(w.q, dtype=float)
            else:
                q_next = kinematics.inverse_nearest(tf.from_ur_pose(w.pose), q)
                if q_next is None:
                    raise ConfigError(f"production.waypoints[{i}].pose: no inverse kinematics solution for "
                                      f"{kinematics.name}")
                q = q_next
            waypoints.append({"q": q.tolist(), "pause_s": prod.pause_s if w.pause_s is None else w.pause_s,
                              "tool": w.tool})
        return {"waypoints": waypoints, **common}
    if prod.preset == "random":
        tilt = min(cal.tilt_deg, 30.0) if prod.max_tilt_deg is None else prod.max_tilt_deg
        return production_program(T_start, q_start, kinematics, cal.model_copy(update={"tilt_deg": tilt}), rng,
                                  n_waypoints=14 if prod.stops is None else prod.stops, pause_s=prod.pause_s,
                                  **common)
    stops = 4 if prod.stops is None else prod.stops
    radius = min(0.15, cal.translation_range_m) if prod.radius_m is None else prod.radius_m
    tilt = 10.0 if prod.max_tilt_deg is None else prod.max_tilt_deg
    for _ in range(50):  # another phase and tilts when a stop is out of reach
        waypoints, q = [], np.asarray(q_start, dtype=float)
        for k, T in enumerate(pick_and_place_poses(T_start, stops, radius, tilt, rng)):
            q = kinematics.inverse_nearest(T, q)
            if q is None:
                break
            waypoints.append({"q": q.tolist(), "pause_s": prod.pause_s, "tool": ("pick", "place")[k % 2]})
        if len(waypoints) == stops:
            return {"waypoints": waypoints, **common}
    raise ConfigError(f"production.preset: no reachable pick_and_place program of {stops} stops within "
                      f"{radius} m of the start pose for {kinematics.name}; lower production.radius_m")


def start_production(robot, cfg, rng: np.random.Generator, *, say=log.info) -> bool:
    """Start the looping production program of ``cfg.production`` on a simulated robot; False (nothing
    done) on a real one."""
    if not robot.simulated:
        return False
    state = robot.read()
    program = program_from_config(cfg.production, state.T_base_flange, state.q, robot.kinematics, cfg.calibrate,
                                  rng)
    # The program takes the calibration in use from the RTDE registers when the cell gives it there.
    program["takes_calibration"] = cfg.consumers.robot_program
    robot.start_program(program)
    kind = "explicit" if cfg.production.waypoints else cfg.production.preset.replace("_", "-")
    say(f"simulated robot: running a looping production program ({len(program['waypoints'])} waypoints, {kind}, "
        f"{program['waypoints'][0]['pause_s']} s tool stops) so that there is something to monitor"
        + ("; it takes the calibration in use from the RTDE registers at every stop" if cfg.consumers.robot_program
           else ""))
    return True


@dataclass
class Bump:
    """A knock of the simulated camera after ``after`` samples: ``translation_mm`` along base x, ``rotation_deg`` about base y."""

    after: int
    translation_mm: float = 10.0
    rotation_deg: float = 0.5

    def apply(self, camera, setup: Setup) -> np.ndarray:
        """Knock the rendered camera's mount now (`handeye.mocks.render.camera.RenderedCamera.add_bump`: base x / base y
        eye-to-hand, camera x / y eye-in-hand); returns its new true transform (``T_base_cam`` / ``T_flange_cam``).

        ``setup`` is the run's; a camera configured for the other one is a `ConfigError`.
        """
        if Setup(setup) != camera.config.setup:
            raise ConfigError(f"setup is {Setup(setup).value} but the bumped camera is {camera.config.setup.value}")
        camera.add_bump(self.translation_mm, self.rotation_deg, direction=(1.0, 0.0, 0.0), axis=(0.0, 1.0, 0.0))
        return camera.camera_transform()


def carried_knocks(reference: Path | None) -> list[Bump]:
    """The simulated camera's knocks in the monitoring run ``reference`` names (its session's ``simulated_bump``
    events, the ones it carried over included), to knock a new run's simulated camera by at its start: a run that
    goes on from that one finds the camera where it left it, as on a real cell. None from a calibration session.

    Raises
    ------
    SessionError
        That run's session cannot be read (named).
    """
    if reference is not None and Path(reference).name == calibration_in_use.PENDING_FILE:
        reference = Path(reference).parent      # a run's pending version: that run's knocks
    found = calibration_in_use.find(reference) if reference is not None else None
    if found is None:
        return []
    knocks = []
    for e in read_session(found.parent).events:
        if e.get("event") != "simulated_bump":
            continue
        mm, deg = e.get("translation_mm"), e.get("rotation_deg")
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in (mm, deg)):
            raise SessionError(f"{found.parent}: a simulated_bump event needs numbers translation_mm and "
                               f"rotation_deg, got {mm!r} and {deg!r}")
        knocks.append(Bump(0, float(mm), float(deg)))
    return knocks


def knock_as_left(camera, setup: Setup, run: Path | None) -> list[Bump]:
    """Knock a simulated ``camera`` (one with ``add_bump``) by `carried_knocks` of ``run``; returns them (none for
    another camera)."""
    knocks = carried_knocks(run) if hasattr(camera, "add_bump") else []
    for knock in knocks:
        knock.apply(camera, setup)
    return knocks


def record_knocks(writer, knocks: list[Bump], t: float) -> None:
    """The knocks `knock_as_left` applied, as the new session's ``simulated_bump`` events (``carried``)."""
    for knock in knocks:
        writer.add_event(t, "simulated_bump", sample_index=0, translation_mm=knock.translation_mm,
                         rotation_deg=knock.rotation_deg, carried=True)
