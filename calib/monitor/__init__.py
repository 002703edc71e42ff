"""Continuous calibration for a production shift: one engine, armed from a calibration result.

The paper's promise is that a single marker point per robot stop keeps the
calibration alive while the robot works. `MonitorEngine` does that with the
measurement model of ``solve("auto")`` (`handeye.calib.model`): it starts from the
camera correction, the marker mount, the noise levels and the covariance of
the result it is armed from (and the robot's kinematic error shared by all
samples, when they carry its factor), and follows the camera transform.

Setups (paper eq. 1, ``A_i X = Y B_i``): eye-to-hand the followed camera
transform is ``Y = T_base_cam`` and the marker mount ``X =
T_flange_marker``; eye-in-hand it is ``X = T_flange_cam`` and the
base-marker pose ``Y = T_base_marker``.

Per sample (fixed work and memory, independent of the shift's length):

1. **Predict.** The camera transform is a random walk (rates
   `MonitorSettings.walk_mm_per_sqrt_h`, ``walk_deg_per_sqrt_h``), so the
   estimate follows a slowly drifting mount instead of alarming on it; in the
   directions the program's stops do not observe it holds its value
   (`handeye.calib.monitor.filter.observed_walk`).
2. **Verify.** The marker point is predicted before it is fused; the error of
   that prediction in C's parent frame is the running verification (``verify_mm``).
3. **Detect.** A windowed GLR test of "the camera jumped by some 6-dof delta"
   on the innovations (`handeye.calib.change.ChangeDetector`) raises the *moved*
   alarm; at a stop visited `MIN_BASELINE` times before it tests the marker
   point's change from the stop's earlier visits instead, allowing for the
   random walk since them. Innovations against the model at nearby poses
   share the calibration's systematic error (`shared_error_var`: what
   ``auto``'s blocked folds show beyond its single held-out samples); the
   test marginalises it, so that a real recording of a still camera is no
   move.
4. **Update.** A Kalman update of the state ``[camera transform, marker-side
   translation, camera parameters, kinematic error, each stop's own error]``
   from the arming calibration's joint covariance (`arm_reference`). What
   repeated stops share (the robot's kinematic error, the camera model, and
   the error each stop repeats at every visit beyond them) is state, not
   white noise, so a program that returns to the same few stops cannot make
   the estimate over-confident (`handeye.calib.monitor.filter`); the
   Jacobians are taken at the calibration in use, so that what the stops
   cannot separate stays as uncertain as the arming left it. The noise
   levels' scale follows the innovations; it weighs what each visit adds.
5. **Drift.** How far the camera has walked since the calibration in use
   (the arming one, or the last re-learnt one): six states that the random
   walk moves with the camera transform, so that what the samples refine of
   the estimate is not counted as drift; its RMS displacement of the points
   of the workspace the arming samples covered, and its rate (exponentially
   weighted regression over ``rate_window_h``, reported once it spans it). The *drifting* alarm fires when that distance
   reaches ``tolerance_mm`` or will within ``horizon_h`` at the current rate.

After a *moved* alarm the engine re-learns the camera transform from the
stops that follow, and re-arms; it never asks for robot motion. At stops
visited before the move, the change of their marker points measures the move
itself, the rest of the state held; otherwise 6 or more samples are
registered (the marker mount places the marker points in C's parent frame:
three stops not on one line determine the camera) and the filter runs over
them from there, the camera transform started afresh, the rest at its
arming covariance. Until the stops determine it, `MonitorUpdate.message`
says what is missing and which stop would fix it.
"""

from handeye.calib.monitor.engine import MonitorEngine
from handeye.calib.monitor.filter import FilterState
from handeye.calib.monitor.reference import (InUse, Reference, WorkspaceMoments, arm_reference, shared_error_var,
                                     workspace_distance, workspace_sigma)
from handeye.calib.monitor.settings import AlarmLevel, EngineState, MonitorSettings, MonitorUpdate

__all__ = ["AlarmLevel", "EngineState", "FilterState", "InUse", "MonitorEngine", "MonitorSettings", "MonitorUpdate",
           "Reference", "WorkspaceMoments", "arm_reference", "shared_error_var", "workspace_distance",
           "workspace_sigma"]
