"""What one monitoring run leaves for the next (`Snapshot`), and its plain form for a file (`snapshot_to_dict`,
`snapshot_from_dict`).

A service restarted after a crash or a reboot, and the next shift's run,
continue from the calibration in use where the last run left it: the live
estimate with its covariance, the camera correction and the robot's
kinematic error it learnt, the drift since the calibration in use, the noise
level, and the arming's workspace points, instead of the calibration from
before any bump. What a run learns about the program's stops (their
baselines) is not carried: the next run tests its first samples against the
model, and a camera knocked in between is a move.

Frames as in `handeye.calib.monitor`: eye-to-hand the camera transform is
``T_base_cam`` and the marker-side transform ``T_flange_marker``;
eye-in-hand ``T_flange_cam`` and ``T_base_marker``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from handeye.calib import model
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError
from handeye.calib.monitor.filter import FilterState, NoiseTrack, clear_slots, filter_state, layout_of, relinearize
from handeye.calib.monitor.reference import InUse, Reference
from handeye.calib.result import AutoDetails, CalibrationResult, CameraParameter, Residuals
from handeye.calib.setup import Setup

#: Version of `snapshot_to_dict`'s layout.
SCHEMA = "handeye/monitor-state/1"


@dataclass(frozen=True)
class Snapshot:
    """The engine between two runs (`handeye.calib.monitor.MonitorEngine.snapshot`, ``resume``).

    Attributes
    ----------
    reference : Reference
        What the first run was armed from (the marker mount, noise levels and workspace points stay).
    origin : InUse
        The cell's first calibration (the total move is measured from it).
    in_use : InUse
        The calibration in use at the end of the run.
    filter : FilterState
        The live estimate at the end of the run.
    noise_track : NoiseTrack
    relearns : int
        Re-learns since the first calibration.
    settle : int
        Samples left of a re-learnt camera's settling (the calibration in use follows the estimate while the
        stops refine it).
    """

    reference: Reference
    origin: InUse
    in_use: InUse
    filter: FilterState
    noise_track: NoiseTrack
    relearns: int = 0
    settle: int = 0

    @property
    def n_factor(self) -> int:
        """Robot kinematic-error parameters in the state."""
        return layout_of(self.filter).n_factor

    def without_factor(self) -> Snapshot:
        """The same without the robot's kinematic error in the state (marginalised: its rows and columns
        dropped), for a run whose samples carry no joints."""
        n = self.n_factor
        if n == 0:
            return self
        f = self.filter
        keep = np.r_[0:12, 12 + n:len(f.P)]
        u = np.r_[f.u[:6], f.u[6 + n:]]
        return dataclasses.replace(self, filter=relinearize(f._replace(u=u, P=f.P[np.ix_(keep, keep)])))


def _matrix(x) -> list:
    return np.asarray(x, dtype=float).tolist()


def _in_use_dict(u: InUse) -> dict:
    return {"camera_transform": _matrix(u.C), "camera_correction": _matrix(u.theta), "sigma_mm": float(u.sigma_mm)}


def snapshot_to_dict(snapshot: Snapshot) -> dict:
    """Plain data (lists, floats, strings) of a snapshot, for YAML or JSON; `snapshot_from_dict` reads it back."""
    ref, f = snapshot.reference, snapshot.filter
    # The stops' own errors are not carried (marginalised), as their baselines are not: the next run learns them.
    kept = clear_slots(f)
    auto = ref.result.auto
    correction = auto.camera_correction if auto is not None else {}
    points = auto.correction_points if auto is not None else None
    return {
        "schema": SCHEMA,
        "setup": str(ref.setup),
        "reference": {
            "camera_transform": _matrix(ref.C), "marker_transform": _matrix(ref.K),
            "camera_correction": _matrix(ref.theta),
            "noise": {"camera_point_scale": float(ref.noise.point_scale), "robot_m": float(ref.noise.robot)},
            "sigma_mm": float(ref.sigma_mm), "shared_error_var_m2": float(ref.shared_var),
            "workspace_m": _matrix(ref.workspace),
            "estimated": [name for name in model.CAMERA_PARAMS if name in correction and correction[name].estimated],
            "correction_points_m": None if points is None else _matrix(points[::max(1, len(points) // 200)]),
            "marker_rotation_known": bool(ref.result.marker_rotation_known),
            "method": ref.result.method,
        },
        "origin": _in_use_dict(snapshot.origin),
        "in_use": _in_use_dict(snapshot.in_use),
        "filter": {"camera_transform": _matrix(f.C), "state": _matrix(kept.u), "covariance": _matrix(kept.P),
                   "t": f.t, "walk_t": f.walk_t,
                   "noise_scale": f.scale, "pending_scale": 1.0},
        "noise_track": {"total": snapshot.noise_track.total, "n": snapshot.noise_track.n},
        "relearns": int(snapshot.relearns),
        "settle": int(snapshot.settle),
    }


def _get(doc, path: str):
    node = doc
    for key in path.split("."):
        if not isinstance(node, dict) or key not in node:
            raise CalibrationError(f"monitor state: {path} is missing")
        node = node[key]
    return node


def _array(doc, path: str, shape) -> np.ndarray:
    try:
        a = np.array(_get(doc, path), dtype=float)
    except (TypeError, ValueError):
        raise CalibrationError(f"monitor state: {path} is not an array of numbers") from None
    if a.shape != shape or not np.isfinite(a).all():
        raise CalibrationError(f"monitor state: {path} must be finite numbers of shape {shape}, got {a.shape}")
    return a


def _float(doc, path: str, positive: bool = False) -> float:
    v = _get(doc, path)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or (positive and v <= 0):
        raise CalibrationError(f"monitor state: {path} must be a finite{' positive' if positive else ''} number, "
                               f"got {v!r}")
    return float(v)


def _transform(doc, path: str) -> np.ndarray:
    try:
        return tf.check_transform(_array(doc, path, (4, 4)), path)
    except CalibrationError as e:
        raise CalibrationError(f"monitor state: {e}") from None


def _in_use(doc, path: str) -> InUse:
    return InUse(_transform(doc, f"{path}.camera_transform"), _array(doc, f"{path}.camera_correction", (3,)),
                 _float(doc, f"{path}.sigma_mm"))


def snapshot_from_dict(doc) -> Snapshot:
    """The `Snapshot` of `snapshot_to_dict`'s output.

    Raises
    ------
    CalibrationError
        Another schema, or a field missing, malformed or not finite (named); a covariance that is not symmetric
        positive semi-definite.
    """
    if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
        raise CalibrationError(f"monitor state: not a {SCHEMA} document (schema: "
                               f"{doc.get('schema') if isinstance(doc, dict) else None!r})")
    try:
        setup = Setup(_get(doc, "setup"))
    except ValueError:
        raise CalibrationError(f"monitor state: setup must be eye_to_hand or eye_in_hand, got "
                               f"{doc.get('setup')!r}") from None
    C_ref, K = _transform(doc, "reference.camera_transform"), _transform(doc, "reference.marker_transform")
    theta = _array(doc, "reference.camera_correction", (3,))
    workspace = np.array(_get(doc, "reference.workspace_m"), dtype=float) if isinstance(
        _get(doc, "reference.workspace_m"), list) else None
    if workspace is None or workspace.ndim != 2 or workspace.shape[1:] != (3,) or len(workspace) == 0 \
            or not np.isfinite(workspace).all():
        raise CalibrationError("monitor state: reference.workspace_m must be finite points (W, 3)")
    noise = model.NoiseLevels(_float(doc, "reference.noise.camera_point_scale", positive=True),
                              _float(doc, "reference.noise.robot_m"))
    estimated = _get(doc, "reference.estimated")
    if not isinstance(estimated, list) or not set(estimated) <= set(model.CAMERA_PARAMS):
        raise CalibrationError(f"monitor state: reference.estimated must list some of {model.CAMERA_PARAMS}")
    u = np.array(_get(doc, "filter.state"), dtype=float) if isinstance(_get(doc, "filter.state"), list) else None
    if u is None or u.ndim != 1 or len(u) < 12 or not np.isfinite(u).all():
        raise CalibrationError("monitor state: filter.state must be finite numbers [t_K, theta, z, walk] (12 + P,)")
    n = len(u) + 6
    P = _array(doc, "filter.covariance", (n, n))
    if np.abs(P - P.T).max() > 1e-9 * max(np.abs(P).max(), 1e-300) or np.linalg.eigvalsh(
            0.5 * (P + P.T)).min() < -1e-9 * max(np.abs(P).max(), 1e-300):
        raise CalibrationError("monitor state: filter.covariance is not symmetric positive semi-definite")
    # Engines before the stops' own errors scaled the covariance with the noise level, with a change still to apply.
    P = P * _float(doc, "filter.pending_scale", positive=True)
    C = _transform(doc, "filter.camera_transform")
    f = filter_state(C, u, 0.5 * (P + P.T), _float(doc, "filter.t"), _float(doc, "filter.walk_t"),
                     _float(doc, "filter.noise_scale", positive=True))
    points = _get(doc, "reference.correction_points_m")
    points = None if points is None else np.array(points, dtype=float)
    if points is not None and (points.ndim != 2 or points.shape[1:] != (3,) or not np.isfinite(points).all()):
        raise CalibrationError("monitor state: reference.correction_points_m must be finite points (M, 3)")
    correction = {name: CameraParameter(value=float(theta[i]), sigma=0.0, estimated=name in estimated)
                  for i, name in enumerate(model.CAMERA_PARAMS)}
    X, Y = model.join(C_ref, K, setup)
    auto = AutoDetails(start="monitor", start_candidates={}, measurements=("points",), camera_correction=correction,
                       correction_points=points, noise=noise, robot_shared_error_m=None, blocked_folds=None, notes=(),
                       flips=None, cost=float("nan"))
    method = _get(doc, "reference.method")
    result = CalibrationResult(method=str(method), setup=setup, X=X, Y=Y, n_samples=0,
                               residuals=Residuals(translation=np.zeros(0)), cov=P[:6, :6].copy(),
                               marker_rotation_known=bool(_get(doc, "reference.marker_rotation_known")), auto=auto)
    ref = Reference(setup, C_ref, K, theta, noise, workspace, _float(doc, "reference.sigma_mm"), result,
                    _float(doc, "reference.shared_error_var_m2"))
    track = NoiseTrack(_float(doc, "noise_track.total"), _float(doc, "noise_track.n"))
    relearns, settle = _count(doc, "relearns"), _count(doc, "settle")
    return Snapshot(ref, _in_use(doc, "origin"), _in_use(doc, "in_use"), f, track, relearns, settle)


def _count(doc, path: str) -> int:
    v = _get(doc, path)
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise CalibrationError(f"monitor state: {path} must be a count, got {v!r}")
    return v
