"""Arming the monitoring engine (`handeye.calib.monitor.MonitorEngine`) from what the app has: shared by
``handeye monitor``, ``demo --monitor`` and ``replay --monitor``.

The engine is armed from a calibration and the samples it was solved from:
a reference session (or the ``result.yaml`` inside one) solved with ``auto``
as ``calibrate`` solves it, or, without a reference, the monitor's own first
samples once ``auto`` determines the camera from them. A previous monitoring
run (its session, a ``replay --monitor --out`` directory, or its
``calibration_in_use.yaml``) is continued from where it left off
(`handeye.app.calibration_in_use`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from handeye.app import calibration_in_use, devices
from handeye.app.errors import SessionError
from handeye.app.session import read_session
from handeye.calib.api import solve_observations
from handeye.calib.errors import CalibrationError
from handeye.calib.monitor import MonitorEngine
from handeye.calib.problem import CalibrationProblem
from handeye.calib.result import CalibrationResult
from handeye.calib.setup import Setup


def reference_observations(path: Path, setup: Setup) -> list:
    """The samples with a marker point of a reference: a session directory, or the ``result.yaml`` inside one.

    Raises
    ------
    SessionError
        Not a session, another setup, or no sample with a marker point.
    """
    path = Path(path)
    if not (path.parent if path.is_file() else path).joinpath("session.json").exists():
        raise SessionError(f"reference {path}: neither a calibration session (no session.json) nor a monitoring run "
                           f"(no {calibration_in_use.FILE_NAME})")
    ref = read_session(path.parent if path.is_file() else path)
    if ref.setup != setup:
        raise SessionError(f"reference {path} is {ref.setup}, the config is {setup}")
    usable = [o for o in ref.observations if o.point_cam is not None]
    if not usable:
        raise SessionError(f"reference {path}: no sample has a marker point")
    return usable


def arm_from(engine: MonitorEngine, result: CalibrationResult, observations: list, factor, *, t: float):
    """Arm ``engine`` from ``result`` and the ``observations`` it was solved from (``factor``: their robot
    kinematic-error factor (N, 6, P) or None); returns `handeye.calib.monitor.Reference`. Raises `CalibrationError`
    as `MonitorEngine.arm`."""
    problem = CalibrationProblem.from_observations(observations, Setup(result.setup), measurements="points",
                                                   robot_shared_error=factor)
    return engine.arm(result, problem, t=t)


def arm_engine(engine: MonitorEngine, reference: list, setup: Setup, shared_error=None, *, rng=None,
               t: float = 0.0) -> CalibrationResult:
    """Solve the reference samples with ``auto`` and arm ``engine`` from the result; returns the result.

    ``shared_error``: the robot's `Robot.shared_error_factor` (the kinematic
    error joins the engine's state when every sample has its joints).

    Raises
    ------
    SessionError
        The reference cannot be solved or does not determine the camera.
    """
    factor = devices.robot_shared_error("auto", reference, shared_error)
    try:
        result = solve_observations("auto", reference, setup, rng=rng or np.random.default_rng(0),
                                    robot_shared_error=factor)
        arm_from(engine, result, reference, factor, t=t)
    except CalibrationError as e:
        raise SessionError(f"reference: cannot arm the monitoring engine: {e}") from None
    return result


def shared_error_note(engine: MonitorEngine) -> str | None:
    """Plain words for the calibration error that nearby poses share, which the armed engine's *moved* test
    allows for (`handeye.calib.monitor.shared_error_var`), or None when there is none."""
    shared = engine.reference.shared_var if engine.reference is not None else 0.0
    if not shared:
        return None
    return (f"the moved test allows for {math.sqrt(shared) * 1e3:.2f} mm per axis of calibration error that nearby "
            "poses share (the reference's blocked folds)")


def sample_factor(engine: MonitorEngine, obs, shared_error):
    """The robot kinematic-error factor (6, P) of one sample for an engine that carries it, else None."""
    if not engine.n_factor:
        return None
    F = devices.robot_shared_error("auto", [obs], shared_error)
    return None if F is None else F[0]


def arm_from_path(engine: MonitorEngine, path: Path, setup: Setup, shared_error=None, *, rng=None,
                  t: float = 0.0) -> str:
    """Arm ``engine`` from what ``path`` holds; returns one line saying what.

    A previous monitoring run (a directory holding ``calibration_in_use.yaml``,
    or the file): continued from its calibration in use (`MonitorEngine.resume`;
    without ``shared_error`` the robot's kinematic error is marginalised out of
    the state). Else a calibration session or its ``result.yaml``, solved with
    ``auto`` (`arm_engine`).

    Raises
    ------
    SessionError
        Nothing to arm from there, another setup, or a file that cannot be read (named).
    """
    found = calibration_in_use.find(path)
    if found is None:
        reference = reference_observations(path, setup)
        arm_engine(engine, reference, setup, shared_error, rng=rng, t=t)
        shared = shared_error_note(engine)
        return (f"reference {path}: {len(reference)} samples solved with auto, monitoring engine armed from its "
                "estimate, camera correction and covariance" + (f"; {shared}" if shared else ""))
    snapshot = calibration_in_use.read(found, setup)
    if shared_error is None:
        snapshot = snapshot.without_factor()
    engine.resume(snapshot, t=t)
    since = calibration_in_use.local_time(snapshot.filter.t) if snapshot.filter.t > 1e9 else \
        f"t = {snapshot.filter.t:.0f} s"
    relearnt = f", re-learnt {snapshot.relearns} time{'s' if snapshot.relearns != 1 else ''}" if snapshot.relearns \
        else ""
    return (f"continuing from {found}: the calibration in use at the end of that run ({since}{relearnt}), with its "
            "covariance and camera correction")
