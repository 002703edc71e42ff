"""A month of a realistic production cell, for the monitoring engine's long-run benchmark and tests.

What the shift simulation (`handeye.calib.simulate.shift_stream`) does not model, and
a real cell has:

- the robot's error beyond its DH parameters (thermal growth of the arm,
  deflection under load): fixed per stop, so it repeats at every visit of it
  (``stop_error_m``), on top of the DH error and the repeatability;
- a camera mount that breathes with the day's temperature: a bounded, mean-
  reverting daily cycle (``thermal_mm``, ``thermal_deg``) beside a slow random
  walk of the mount (``walk_mm_per_sqrt_h``);
- bumps at any hour of the month;
- both setups with a realistic robot and camera (`handeye.calib.simulate.realistic_profile`),
  and sources that report poses without joints (the caller arms the engine
  without the robot's kinematic-error factor).

Frames: eye-to-hand the camera transform is ``T_base_cam`` (bumps and the
mount's breathing move it in the base frame, turning it about its centre);
eye-in-hand it is ``T_flange_cam`` (the camera slips on the flange: moves in
its own frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from handeye.calib import transforms as tf
from handeye.calib.robot_error import UR10_DH, ur_forward
from handeye.calib.setup import Setup
from handeye.calib.simulate import (RealisticData, RealisticProfile, production_stops, random_directions, seen_points)

#: Seconds per day.
DAY_S = 86400.0


@dataclass(frozen=True)
class Month:
    """A month of production (`month_stream`).

    ``stops`` tool stops visited in turn, one sample every ``sample_s``. With
    ``programs`` > 1 the cell runs one of that many programs per shift of
    ``program_h`` hours, drawn at random, each its own ``stops`` stops (a
    composed production: new stops at each change, old ones back later).
    ``stop_error_m``: 1-sigma per axis of each stop's fixed flange position
    error beyond the DH error. The camera mount follows a daily cycle of
    amplitude ``thermal_mm`` (translation, along a random direction) and
    ``thermal_deg`` (about a random axis through its centre), each with a
    random phase, and a random walk of ``walk_mm_per_sqrt_h``; it is bumped at
    each ``(day, mm, deg)`` of ``bumps`` (random directions).
    """

    days: float = 30.0
    sample_s: float = 30.0
    stops: int = 4
    programs: int = 1
    program_h: float = 8.0
    max_tilt_deg: float = 10.0
    stop_error_m: float = 0.3e-3
    thermal_mm: float = 1.0
    thermal_deg: float = 0.01
    walk_mm_per_sqrt_h: float = 0.05
    bumps: tuple = ((3.4, 5.0, 0.3), (10.7, 5.0, 0.3), (17.2, 5.0, 0.3), (24.9, 5.0, 0.3))


@dataclass(frozen=True)
class MonthData:
    """`month_stream` output: what the monitor gets, per stop where it repeats, and the truth.

    ``t`` (n,) s; ``stop`` (n,) the stop of each sample; ``A_stops`` (S, 4, 4)
    the stops' flange poses as reported (nominal kinematics), ``A_true_stops``
    (S, 4, 4) as they are (the DH error and the stop's own error; each visit
    adds repeatability) and ``q_stops`` (S, 6) their joints; ``points`` (n, 3)
    measured marker centres, m, and
    ``point_cov`` (n, 3, 3); ``C`` (n, 4, 4) the true camera transform at each
    sample; ``bumped`` the index of the first sample after each bump.
    """

    t: np.ndarray
    stop: np.ndarray
    A_stops: np.ndarray
    A_true_stops: np.ndarray
    q_stops: np.ndarray
    points: np.ndarray
    point_cov: np.ndarray
    C: np.ndarray
    bumped: np.ndarray


def mount_motion(t: np.ndarray, month: Month, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, list]:
    """The camera mount's motion at times ``t`` (n,) s: rotation vectors (n, 3), rad, and translations (n, 3), m
    (the daily cycle, the random walk and the bumps), and the index of the first sample after each bump."""
    phase = rng.uniform(0.0, 2.0 * np.pi, size=2)
    cycle = np.sin(2.0 * np.pi * t[:, None] / DAY_S + phase)
    translation = month.thermal_mm * 1e-3 * cycle[:, :1] * random_directions(1, rng)[0]
    rotation = np.deg2rad(month.thermal_deg) * cycle[:, 1:] * random_directions(1, rng)[0]
    steps = rng.normal(size=(len(t), 3)) * np.sqrt(np.diff(t, prepend=t[0])[:, None] / 3600.0)
    translation += month.walk_mm_per_sqrt_h * 1e-3 * np.cumsum(steps, axis=0)
    bumped = []
    for day, mm, deg in month.bumps:
        after = t >= day * DAY_S
        if not after.any():
            continue
        bumped.append(int(np.argmax(after)))
        translation[after] += mm * 1e-3 * random_directions(1, rng)[0]
        rotation[after] += np.deg2rad(deg) * random_directions(1, rng)[0]
    return rotation, translation, bumped


def program_schedule(t: np.ndarray, month: Month, rng: np.random.Generator) -> np.ndarray:
    """The stop (an index into the programs' stops, ``stops`` per program) of each sample at times ``t`` (n,) s:
    one program per shift of ``program_h`` hours, drawn at random, its stops visited in turn from the shift's
    start; a single program's stops in turn."""
    k = np.arange(len(t))
    if month.programs == 1:
        return k % month.stops
    shift = np.floor(t / (month.program_h * 3600.0)).astype(int)
    program = rng.integers(month.programs, size=shift[-1] + 1)[shift]
    first = np.searchsorted(shift, shift)          # each sample's shift's first sample
    return program * month.stops + (k - first) % month.stops


def month_stream(real: RealisticData, month: Month, rng: np.random.Generator,
                 profile: RealisticProfile | None = None) -> MonthData:
    """A month of production samples on ``real``'s cell (either setup): its robot's DH error, each stop's own
    error beyond it, repeatability anew at every visit, the camera's systematic errors (`seen_points`), and the
    mount's motion (`mount_motion`)."""
    prof = profile if profile is not None else RealisticProfile()
    dh, kin, d = UR10_DH, real.kinematics, real.data
    q_stops = np.vstack([production_stops(real, month.stops, month.max_tilt_deg, rng) for _ in range(month.programs)])
    A_stops = ur_forward(q_stops, dh["d"], dh["a"], dh["alpha"], np.zeros(6))
    A_true_stops = ur_forward(q_stops, kin["d"], kin["a"], kin["alpha"], kin["offsets"])
    A_true_stops[:, :3, 3] += rng.normal(scale=month.stop_error_m, size=(len(q_stops), 3))
    n = int(month.days * DAY_S / month.sample_s)
    t = np.arange(n) * month.sample_s
    stop = program_schedule(t, month, rng)
    A_true = A_true_stops[stop] @ tf.from_rotvec_translation(rng.normal(scale=prof.repeatability_rad, size=(n, 3)),
                                                             rng.normal(scale=prof.repeatability_m, size=(n, 3)))
    rotation, translation, bumped = mount_motion(t, month, rng)
    if d.setup == Setup.EYE_TO_HAND:
        C = tf.make_transform(tf.so3_exp(rotation) @ d.Y[:3, :3], d.Y[:3, 3] + translation)
        B_true = tf.invert(C) @ A_true @ d.X
    else:
        C = d.X @ tf.from_rotvec_translation(rotation, translation)
        B_true = tf.invert(A_true @ C) @ d.Y
    points, cov = seen_points(B_true, prof, real.camera, rng)
    return MonthData(t, stop, A_stops, A_true_stops, q_stops, points, cov, C, np.array(bumped, dtype=int))
