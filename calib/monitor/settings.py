"""The monitoring engine's settings (`MonitorSettings`), what each update reports (`MonitorUpdate`), and its
state and alarm levels (`EngineState`, `AlarmLevel`)."""

from __future__ import annotations

from handeye.calib.compat import StrEnum
from typing import Annotated, NamedTuple

import numpy as np
from pydantic import Field

from handeye.calib.change import DetectorConfig
from handeye.calib.params import NonNegativeFloat, Params, PositiveFloat


class EngineState(StrEnum):
    """Where the engine is: ``warming`` (the detector's first samples after arming), ``armed`` (every sample
    tested), ``relearning`` (after a move, until the production stops determine the camera) or ``settling``
    (the detector's window after a re-learn: the calibration in use follows the estimate as the stops refine
    it; the *moved* test runs against the model while the stops' baselines are learnt again)."""

    WARMING = "warming"
    ARMED = "armed"
    RELEARNING = "relearning"
    SETTLING = "settling"


class AlarmLevel(StrEnum):
    """An alarm, or the standing condition: none (``""``, false), ``drifting`` or ``moved``."""

    NONE = ""
    DRIFTING = "drifting"
    MOVED = "moved"


class MonitorSettings(Params):
    """Settings of `MonitorEngine` (``[monitor]`` of the app's config).

    Attributes
    ----------
    walk_mm_per_sqrt_h, walk_deg_per_sqrt_h : float
        Random walk of the camera transform: 1-sigma of its change after one
        hour (it grows with the square root of time). Sized for a thermally
        drifting mount: a few tenths of a mm per hour of steady drift is
        followed within a few dozen samples.
    tolerance_mm : float
        How far the camera may move from the calibration in use, over the
        workspace, mm, before a plant must act: reaching it is a *drifting*
        alarm. The predicted error of that calibration (the drift with its own
        1-sigma) is reported beside it.
    horizon_h : float
        A *drifting* alarm also fires when the current drift rate reaches the
        tolerance within this many hours.
    rate_window_h : float
        Time constant of the drift-rate regression, h.
    stop_translation_m, stop_rotation_deg : float
        Two samples closer than both are the same stop: only distinct stops
        widen the set a re-learn registers (repeated stops are fused, and
        tested, like any other).
    stop_error_mm : float
        1-sigma per axis, mm, of the error a production stop repeats at
        every visit beyond the robot noise the arming calibration measured:
        the camera's own at that view (colour/depth misregistration, the
        marker's tilt) and the arm's that its kinematic model leaves
        (thermal growth, deflection under load). It bounds what repeated
        visits of the same stops can teach the live estimate
        (`handeye.calib.monitor.filter`). 0.5: a UR10's error beyond its
        kinematic model is 0.1-0.5 mm, and a 2 px colour/depth
        misregistration reads a tilted marker's depth up to 0.5 mm off at
        a metre; with 0.3 the month benchmark's stops pulled the camera
        until its error was 1.5-2x its stated 1-sigma (docs/benchmarks.md).
    robot_accuracy_mm : float
        1-sigma per axis, mm, of the robot's pose error that nearby stops
        share, for a source without joints (with joints the state holds the
        robot's kinematic error): the arm's absolute accuracy. The
        calibration cannot see it (it shifts the camera it solves for), and a
        program's stops, all off by about the same, cannot tell it from the
        camera; taken as each stop's own, the stops pulled a pose-only
        camera up to 5 mm off while its stated 1-sigma said 2.5 (mean
        (error/sigma)^2 4.95 over a month). 1.0: a UR10's DH error puts a
        program's stops 0.5-2.3 mm off in common. 0: none.
    relearn_samples : int
        Samples held for a re-learn (the newest).
    min_spread_m : float
        The stops' spread across their best-fit line below which a re-learn
        counts them as collinear.
    detector : DetectorConfig
        The *moved* test (GLR windows, false-alarm rate per sample).
    walk_max_gap_h : float
        The random walk over a gap between two samples counts at most this
        many hours: a mount drifts while the cell works and warms, not
        without bound while it stands idle over a weekend, so that a camera
        knocked while the monitor was off is a move, not a walk.
    time_scale : float
        Seconds of the camera's world per second of the samples' clock: 1 on
        a real cell; a compressed simulation's mount ``time_scale``
        (config/sim_shift.toml: 30). The random walk, the drift rates, the
        rate window and the horizon are per hour of that world.
    """

    walk_mm_per_sqrt_h: NonNegativeFloat = 0.5
    walk_deg_per_sqrt_h: NonNegativeFloat = 0.02
    tolerance_mm: PositiveFloat = 2.0
    horizon_h: NonNegativeFloat = 2.0
    rate_window_h: PositiveFloat = 1.0
    stop_translation_m: NonNegativeFloat = 0.03
    stop_rotation_deg: NonNegativeFloat = 5.0
    stop_error_mm: NonNegativeFloat = 0.5
    robot_accuracy_mm: NonNegativeFloat = 1.0
    relearn_samples: Annotated[int, Field(strict=True, ge=3)] = 40
    min_spread_m: PositiveFloat = 0.02
    detector: DetectorConfig = Field(default_factory=DetectorConfig)
    walk_max_gap_h: PositiveFloat = 2.0
    time_scale: PositiveFloat = 1.0


class MonitorUpdate(NamedTuple):
    """What one `MonitorEngine.update` saw and did (a NamedTuple: cheap at every sample).

    Attributes
    ----------
    index : int
        Samples given to the engine so far (this one included).
    t : float
        The sample's time, s.
    state : EngineState
        After this sample.
    alarm : AlarmLevel
        Raised at this sample (``AlarmLevel.NONE``, false, for none).
    level : AlarmLevel
        The standing condition: moved holds until the re-learn, drifting while it lasts.
    camera_transform : ndarray (4, 4)
        Live ``T_base_cam`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand).
    cov : ndarray (6, 6)
        Its covariance (`handeye.calib.result` convention), consider terms included.
    innovation : ndarray (3,)
        Measured minus predicted marker point in the camera frame, m, before fusing.
    nis : float
        Its normalised square (chi-square, 3 dof, when consistent).
    verify_mm : float
        The prediction error in C's parent frame, mm: a verification on a pose
        the estimate had not seen.
    statistic : float
        The GLR statistic (0 while the detector does not run).
    drift_mm, drift_deg : float
        How far the camera has walked since the calibration in use (the filter's
        random-walk states, not what the samples refined): RMS displacement of
        the workspace points, mm, and rotation angle, deg.
    drift_rate_mm_h, drift_rate_deg_h : float or None
        Rates of that drift (None until the regression covers enough time).
    error_mm : float
        Predicted error of the calibration in use over the workspace, mm
        (drift and its own 1-sigma).
    hours_to_tolerance : float or None
        At the current rate (None: not heading there).
    sigma_mm : float
        Live 1-sigma over the workspace, mm (camera correction included).
    message : str
        Plain words for an alarm, a re-learn, or why a re-learn is not possible yet.
    """

    index: int
    t: float
    state: EngineState
    alarm: AlarmLevel
    level: AlarmLevel
    camera_transform: np.ndarray
    cov: np.ndarray
    innovation: np.ndarray
    nis: float
    verify_mm: float
    statistic: float
    drift_mm: float
    drift_deg: float
    drift_rate_mm_h: float | None
    drift_rate_deg_h: float | None
    error_mm: float
    hours_to_tolerance: float | None
    sigma_mm: float
    message: str
