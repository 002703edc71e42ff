"""Whether to use a result: a verdict (pass | warn | fail) with one plain reason per problem and its fix.

Computed once here and shown everywhere (result.yaml, the console, report.html).
A calibration (`judge`) is judged on what its user cares about:

- the predicted error over the workspace (`workspace_accuracy`: where the calibration
  samples put the marker, mm and deg) against the tolerance;
- the consistency of its residuals with the camera's noise and of its held-out
  self-check with what its model expects;
- the pose coverage (samples, rotation between them) and what the motions leave
  open (`CalibrationResult.undetermined`).

A verification (`judge_verification`) is judged on the calibration error it found on
fresh poses against the tolerance, the rigid export's, and poses that repeat the
calibration's.

Eye-to-hand the camera transform is ``Y = T_base_cam``, eye-in-hand ``X = T_flange_cam``
(paper eq. 1, ``A_i X = Y B_i``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from handeye.calib import model
from handeye.calib import transforms as tf
from handeye.calib.diagnostics import LOO_TOLERANCE
from handeye.calib.errors import CalibrationError
from handeye.calib.monitor.reference import WORKSPACE_POINTS, arm_reference, workspace_sigma
from handeye.calib.problem import CalibrationProblem
from handeye.calib.result import LEVELS, Accuracy, CalibrationResult, Verdict
from handeye.calib.verify import Verification

#: An error stays below this many times its RMS in 95 % of cases, whatever the shape of its Gaussian in 3D.
P95_FACTOR = 1.96
#: Residuals this many times what the camera's noise explains: the result does not fit the setup.
INCONSISTENT_RATIO = 2.0
#: Fewer samples than this: one bad sample can move the result unnoticed.
MIN_ADVISED_SAMPLES = 10
#: The flange turned less than this far from its mean orientation (deg): little to tell the rotations apart.
MIN_ROTATION_SPREAD_DEG = 10.0
#: More than this share of the samples rejected as outliers: something in the cell is off.
MAX_REJECTED_SHARE = 0.2

WORDS = {"pass": "PASS", "warn": "WARN", "fail": "FAIL"}


def worst(levels) -> str:
    """The worst of verdict levels (``"pass"`` for none)."""
    return max(levels, key=LEVELS.index, default="pass")


def workspace_accuracy(result: CalibrationResult, problem: CalibrationProblem) -> Accuracy | None:
    """The predicted error of ``result``'s camera transform where its samples put the marker.

    A marker point ``m`` the camera measures maps to ``C correct(m)`` in the camera's parent
    frame (``C``: ``T_base_cam`` or ``T_flange_cam``). For ``auto`` the error of that point comes
    from the joint covariance of the camera transform and its camera correction
    (`handeye.calib.monitor.arm_reference`, the covariance the monitor is armed with); for the paper's
    methods, which estimate no correction, from ``result.cov``. Both are evaluated over up to
    `handeye.calib.monitor.reference.WORKSPACE_POINTS` of the samples' points
    (`handeye.calib.monitor.workspace_sigma`).

    Parameters
    ----------
    result : CalibrationResult
    problem : CalibrationProblem
        The samples ``result`` was solved from (all of them: outliers it rejected are left out here).

    Returns
    -------
    Accuracy or None
        None when the result has no covariance or its samples do not determine it.
    """
    if result.cov is None:
        return None
    if result.inliers is not None and len(result.inliers) == problem.n:
        problem = problem.subset(result.inliers)
    try:
        if result.auto is not None:
            ref, cov = arm_reference(result, problem)
            C, theta, points = ref.C, ref.theta, ref.workspace
        else:
            C, theta = result.camera_transform, np.zeros(3)
            points = problem.points[::max(1, problem.n // WORKSPACE_POINTS)]
            cov = np.zeros((12, 12))
            cov[:6, :6] = result.cov
    except CalibrationError:
        return None
    sigma = np.array([workspace_sigma(C, theta, points[i:i + 1], cov) for i in range(len(points))])
    rms = float(np.sqrt(np.mean(sigma**2)))
    rot = float(np.sqrt(max(np.trace(cov[:3, :3]), 0.0)))
    return Accuracy(rms_mm=rms * 1e3, p95_mm=P95_FACTOR * float(sigma.max()) * 1e3, rms_deg=float(np.rad2deg(rot)),
                    p95_deg=P95_FACTOR * float(np.rad2deg(rot)))


def noise_ratio(result: CalibrationResult, problem: CalibrationProblem) -> tuple[float, float]:
    """``(ratio, expected_m)``: the residual RMS of ``result`` over the RMS the camera's noise explains
    (``expected_m``: from the samples' point covariances, else the depth model of `handeye.calib.noise`)."""
    shape, _ = model.point_shape(problem.B, problem.point_cov)
    expected = float(np.sqrt(np.mean(np.trace(shape, axis1=1, axis2=2))))
    return (result.residuals.rms_translation / expected if expected > 0 else 0.0), expected


def rotation_spread_deg(A) -> float:
    """Largest angle (deg) of a flange orientation from the mean orientation of ``A`` (N, 4, 4)."""
    R = np.asarray(A, dtype=float)[:, :3, :3]
    mean = tf.project_to_so3(R.mean(axis=0))
    return float(np.rad2deg(np.max(tf.rotation_angle(R @ mean.T))))


def accuracy_phrase(acc: Accuracy) -> str:
    """``predicted error over the workspace 0.26 mm RMS, at most 0.73 mm / 0.05 deg at 95 %``."""
    return (f"predicted error over the workspace {acc.rms_mm:.2f} mm RMS, at most {acc.p95_mm:.2f} mm / "
            f"{acc.p95_deg:.2f} deg at 95 %")


def judge(result: CalibrationResult, problem: CalibrationProblem, *, tolerance_mm: float,
          tolerance_deg: float, stopped_early: str | None = None) -> CalibrationResult:
    """``result`` with its `Accuracy` and `Verdict` against the tolerance (module docstring).

    Parameters
    ----------
    result : CalibrationResult
    problem : CalibrationProblem
        The samples it was solved from.
    tolerance_mm, tolerance_deg : float
        The error the cell accepts (``[calibrate] tolerance_mm / tolerance_deg``), > 0.
    stopped_early : str, optional
        Why the samples end before the run that took them reached its target (a sentence with what to do):
        the first reason, a warning whatever the samples show.

    Returns
    -------
    CalibrationResult
        The same result with ``accuracy`` and ``verdict`` set.
    """
    for name, v in (("tolerance_mm", tolerance_mm), ("tolerance_deg", tolerance_deg)):
        if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
            raise CalibrationError(f"{name} must be a positive number, got {v!r}")
    # With part of the answer open (held at a guess), no error over the workspace can be stated: the reason
    # that names the open part says what to do instead.
    acc = None if result.undetermined else workspace_accuracy(result, problem)
    reasons = [("warn", stopped_early)] if stopped_early else []
    reasons += [] if result.undetermined else _accuracy_reasons(acc, tolerance_mm, tolerance_deg, result.method)
    reasons += _consistency_reasons(result, problem)
    reasons += _coverage_reasons(result, problem)
    level = worst(lv for lv, _ in reasons)
    tolerance = f"{tolerance_mm:g} mm / {tolerance_deg:g} deg"
    what = (accuracy_phrase(acc) if acc is not None else "its error over the workspace is unknown while part of "
            "the answer is open" if result.undetermined else "no predicted error")
    summary = {"pass": f"within the tolerance {tolerance}: {what}",
               "warn": f"check the reasons below before use: {what} (tolerance {tolerance})",
               "fail": f"do not use as it is: {what} (tolerance {tolerance})"}[level]
    verdict = Verdict(level, summary, tuple(text for _, text in reasons))
    return dataclasses.replace(result, accuracy=acc, verdict=verdict)


def _accuracy_reasons(acc: Accuracy | None, tolerance_mm: float, tolerance_deg: float, method: str) -> list:
    if acc is None:
        return [("warn", f"{method} states no uncertainty for these samples, so its error over the workspace is "
                         "unknown: verify the result on fresh poses (handeye verify) before use")]
    more = ("take more samples spread over the whole workspace, with more rotation between them (tilt the flange "
            "20-40 deg about different axes)")
    if acc.rms_mm > tolerance_mm or acc.rms_deg > tolerance_deg:
        return [("fail", f"the predicted error over the workspace, {acc.rms_mm:.2f} mm / {acc.rms_deg:.2f} deg RMS, "
                         f"is above the tolerance {tolerance_mm:g} mm / {tolerance_deg:g} deg: {more}")]
    if acc.p95_mm > tolerance_mm or acc.p95_deg > tolerance_deg:
        return [("warn", f"the error may exceed the tolerance {tolerance_mm:g} mm / {tolerance_deg:g} deg in places: "
                         f"at most {acc.p95_mm:.2f} mm / {acc.p95_deg:.2f} deg at 95 %: {more}")]
    return []


def _consistency_reasons(result: CalibrationResult, problem: CalibrationProblem) -> list:
    reasons = []
    ratio, expected = noise_ratio(result, problem)
    if ratio > INCONSISTENT_RATIO:
        # auto searches for outliers itself, as does a robust solve: then rejecting more is no fix.
        searched = result.auto is not None or result.robust is not None
        outliers = ("; the outliers the solver could find are rejected already" if searched else
                    ", or reject outliers (replay --robust, [calibrate] robust = true)")
        reasons.append(("warn", f"residuals are {ratio:.0f}x what the camera's noise explains "
                                f"({result.residuals.rms_translation * 1e3:.2f} mm RMS against {expected * 1e3:.2f} "
                                "mm): check the setup (eye-in-hand or eye-to-hand?), the clock offset between robot "
                                f"and camera, a camera or marker that moved during the recording{outliers}"))
    check = result.self_check
    if check is not None and check.loo_ratio > LOO_TOLERANCE:
        reasons.append(("warn", f"samples left out of the fit are predicted to {check.loo_observed_m * 1e3:.2f} mm, "
                                f"{check.loo_ratio:.1f}x the {check.loo_predicted_m * 1e3:.2f} mm the model expects: "
                                "the stated accuracy is optimistic; take more samples, or check for a loose marker or "
                                "camera mount"))
    return reasons


def _coverage_reasons(result: CalibrationResult, problem: CalibrationProblem) -> list:
    reasons = [("warn", text) for text in result.undetermined]
    n = result.n_samples
    if n < MIN_ADVISED_SAMPLES:
        reasons.append(("warn", f"only {n} samples: one bad sample would move the result unnoticed; take at least "
                                f"{MIN_ADVISED_SAMPLES}"))
    spread = rotation_spread_deg(problem.A)
    # A known marker offset stands in for the rotation the motions lack (`handeye.calib.problem.CalibrationProblem`).
    if not result.undetermined and problem.marker_offset is None and spread < MIN_ROTATION_SPREAD_DEG:
        reasons.append(("warn", f"the flange turned at most {spread:.1f} deg from its mean orientation: the camera's "
                                "rotation rests on little motion; add poses tilted 20-40 deg about different axes"))
    rejected = len(result.rejected)
    if rejected > MAX_REJECTED_SHARE * n:
        reasons.append(("warn", f"{rejected} of {n} samples were rejected as outliers: check the marker detection and "
                                "the clock offset between robot and camera (the report lists the samples)"))
    return reasons


def bounded(value: float, ci: tuple[float, float], unit: str, digits: int, floor: float | None = None) -> str:
    """A verified error in words: ``0.53 mm (at most 0.90 mm at 95 %)``, or when the noise hides it
    entirely ``below the noise floor: at most 0.62 deg at 95 %``; the bound is never below ``floor``, the
    smallest error the poses tell from their noise (`handeye.calib.verify.Verification.noise_floor_mm`)."""
    hi = f"at most {max(ci[1], floor or 0.0):.{digits}f} {unit} at 95 %"
    return f"below the noise floor: {hi}" if value <= 0 else f"{value:.{digits}f} {unit} ({hi})"


def verified_error_phrase(v: Verification) -> str:
    """The calibration error a verification found, in mm and (with orientations) deg, noise floor said."""
    text = bounded(v.calibration_mm, v.calibration_ci_mm, "mm", 2, v.noise_floor_mm)
    if v.calibration_deg is not None:
        text += "; " + bounded(v.calibration_deg, v.calibration_ci_deg, "deg", 3, v.noise_floor_deg)
    return text


def per_pose_phrase(v: Verification) -> str:
    """Why each pose's error is larger than the calibration error: a measured error is the measurement's
    noise plus the calibration's own error, and the noise model says how much of it is noise."""
    e = v.errors_mm
    text = f"per pose: {e.min():.2f}-{e.max():.2f} mm"
    if v.rotation_deg is not None:
        r = v.rotation_deg[np.isfinite(v.rotation_deg)]
        text += f" and {r.min():.2f}-{r.max():.2f} deg"
    text += ", the measurement's noise plus the calibration's own error"
    noise = []
    if v.noise_rms_mm is not None:
        noise.append(f"{v.noise_rms_mm:.2f} mm")
    if v.rotation_deg is not None and v.noise_rms_deg is not None:
        noise.append(f"{v.noise_rms_deg:.2f} deg")
    if not noise:
        return text + "; the samples carry no noise model, so the calibration error above includes the noise"
    why = " (a marker's orientation is measured far less precisely than its centre)" if len(noise) == 2 else ""
    return (text + f". The noise alone is expected at {' and '.join(noise)} RMS per pose{why}, so errors of that "
            "size do not mean the calibration is off by as much: the calibration error above is what is left once "
            "the noise is removed")


def _unresolved(v: Verification) -> list[tuple[str, str]]:
    """``(tolerance, sentence)`` per quantity (mm, deg) whose tolerance is below the noise floor of the poses
    (`handeye.calib.verify.Verification.noise_floor_mm`): whatever the estimate, they cannot show it within."""
    out = []
    for what, unit, digits, floor, noise, tol in (
            ("position", "mm", 2, v.noise_floor_mm, v.noise_rms_mm, v.tolerance_mm),
            ("rotation", "deg", 3, v.noise_floor_deg, v.noise_rms_deg, v.tolerance_deg)):
        if floor is None or noise is None or floor <= tol:
            continue
        # The floor falls as the fourth root of the number of poses.
        needed = int(np.ceil(8.0 / 3.0 * (noise / tol) ** 4))
        out.append((f"{what} tolerance {tol:g} {unit}",
                    f"the {what} error cannot be shown within {tol:g} {unit}: the measurement noise of these "
                    f"{v.n_poses} poses ({noise:.{digits}f} {unit} per pose) hides any error below "
                    f"{floor:.{digits}f} {unit}; verify on about {needed} poses to resolve {tol:g} {unit}"))
    return out


def judge_verification(v: Verification, *, rigid: Verification | None = None, repeated: int = 0,
                       warnings=()) -> Verdict:
    """The verdict of a verification (`handeye.calib.verify.verify`) on ``v.n_poses`` poses.

    ``rigid``: the same for the rigid export (``camera_transform_raw_points`` on uncorrected
    points); ``repeated``: how many of the poses repeat a calibration pose
    (`handeye.calib.verify.repeated_poses`); ``warnings``: other sentences to pass on as ``warn``
    reasons (e.g. `handeye.calib.verify.FrameSafety`'s).
    """
    reasons = []
    tolerance = f"{v.tolerance_mm:g} mm / {v.tolerance_deg:g} deg"
    if not v.passed:
        reasons.append(("fail", "the calibration misses the tolerance on poses it did not see: recalibrate (more "
                                "samples, more rotation between them), or check that the camera and the marker did "
                                "not move since the calibration"))
    if rigid is not None and not rigid.passed:
        reasons.append(("warn", f"the ROS/URDF transform (for the camera driver's uncorrected points) is off "
                                f"by {rigid.calibration_mm:.2f} mm, above the tolerance: a consumer without the camera "
                                "correction sees larger errors; correct the points as result.yaml's model says, or "
                                "recalibrate with more of the image and depth range covered"))
    if repeated:
        reasons.append(("warn", f"{repeated} of {v.n_poses} verification poses repeat calibration poses (within "
                                "a few mm and tenths of a degree): there the result was fitted, not tested; verify "
                                "on fresh poses (the active mode picks them)"))
    reasons += [("warn", w) for w in warnings]
    unresolved = _unresolved(v) if v.passed else []
    reasons += [("warn", text) for _, text in unresolved]
    level = worst(lv for lv, _ in reasons)
    lead = {"pass": f"within the tolerance {tolerance}", "warn": f"within the tolerance {tolerance}, but check the "
            "reasons below", "fail": f"outside the tolerance {tolerance}"}[level]
    if unresolved:
        lead = (f"the {' and '.join(t for t, _ in unresolved)} {'is' if len(unresolved) == 1 else 'are'} finer than "
                "these poses can resolve")
    summary = f"{lead}: calibration error on {v.n_poses} poses {verified_error_phrase(v)}"
    return Verdict(level, summary, tuple(text for _, text in reasons))
