"""``handeye replay --monitor``: stream a recorded production session through the monitoring engine.

"When did the camera move last night?": the session's samples go through
`handeye.calib.monitor.MonitorEngine` in order, as fast as the CPU allows, armed from
a reference calibration (``--reference``: a calibration session, solved with
``auto`` as ``calibrate`` solves it, or the ``result.yaml`` in one, whose
session's samples give the engine its covariance). Written into the output
directory (``replay --out``):

- ``monitor_trace.csv``: one row per sample (`TRACE_COLUMNS`; the camera
  transform is ``T_base_cam`` eye-to-hand, ``T_flange_cam`` eye-in-hand);
- ``alarms.yaml``: every alarm with its sample, local time, message and, for a move, its re-learn
  (`handeye.app.shift_record`);
- ``monitor_trace.png`` and ``report.html``: the timeline (the move since the cell's first calibration, the
  drift since the calibration in use, the verification, the 1-sigma, the alarms) and the shift report;
- ``calibration_in_use.yaml`` (`handeye.app.calibration_in_use`): the calibration in use, written at arming, at every
  re-learn, when a re-learnt camera has settled and at the end; another ``replay --monitor`` or ``monitor``
  continues from it with ``--reference <out>``.

``--reference`` may also be a previous monitoring run (its session or
``--out`` directory): the engine continues from its calibration in use.

Samples without a marker point are skipped and counted; a malformed one is
skipped with a log line naming it (`handeye.calib.errors.CalibrationError`). A
session whose samples lack their joints (another program's) is monitored
without the robot's kinematic error in the engine's state, even when the
config models it and the reference has joints.
"""

from __future__ import annotations

import csv
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from handeye.app import calibration_in_use, devices
from handeye.app.errors import MonitorError, SessionError
from handeye.app.monitoring import arm_from_path
from handeye.app.session import read_session
from handeye.app.shift_record import ShiftRecord
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError
from handeye.calib.monitor import MonitorEngine, MonitorSettings, MonitorUpdate
from handeye.calib.monitor.filter import is_sound
from handeye.calib.result import worst_axis_sigma
from handeye.calib.setup import Setup

log = logging.getLogger(__name__)

TRACE_COLUMNS = ("index", "sample", "t", "alarm", "level", "state", "x_mm", "y_mm", "z_mm", "qx", "qy", "qz", "qw",
                 "depth_scale", "depth_offset_mm", "focal_scale", "sigma_mm", "sigma_deg", "drift_mm", "drift_deg",
                 "drift_rate_mm_h", "drift_rate_deg_h", "verify_mm", "error_mm", "hours_to_tolerance", "nis",
                 "statistic")


@dataclass
class MonitorReplay:
    """What a replay saw: counts, the shift record (alarms, outcome, timeline), the last update, where the
    files went."""

    setup: Setup
    record: ShiftRecord
    n_samples: int = 0
    n_skipped: int = 0
    last: MonitorUpdate | None = None
    verify_mm: list = field(default_factory=list)
    out: Path | None = None
    notes: list = field(default_factory=list)

    @property
    def alarms(self) -> list[dict]:
        return list(self.record.alarms)


def trace_row(obs_index: int, upd: MonitorUpdate, correction) -> dict:
    xyz, quat = tf.to_xyz_quat(upd.camera_transform)
    s_rot, s_t = worst_axis_sigma(upd.cov)
    s, d, f = correction.as_array()

    def opt(v, fmt):
        return "" if v is None else fmt.format(v)

    return {
        "index": upd.index, "sample": obs_index, "t": f"{upd.t:.3f}", "alarm": str(upd.alarm),
        "level": str(upd.level), "state": str(upd.state),
        **{k: f"{v * 1e3:.3f}" for k, v in zip(("x_mm", "y_mm", "z_mm"), xyz)},
        **{k: f"{v:.6f}" for k, v in zip(("qx", "qy", "qz", "qw"), quat)},
        "depth_scale": f"{s:.6f}", "depth_offset_mm": f"{d * 1e3:.3f}", "focal_scale": f"{f:.6f}",
        "sigma_mm": f"{upd.sigma_mm:.3f}", "sigma_deg": f"{np.rad2deg(s_rot):.4f}",
        "drift_mm": f"{upd.drift_mm:.3f}", "drift_deg": f"{upd.drift_deg:.4f}",
        "drift_rate_mm_h": opt(upd.drift_rate_mm_h, "{:.3f}"), "drift_rate_deg_h": opt(upd.drift_rate_deg_h, "{:.4f}"),
        "verify_mm": f"{upd.verify_mm:.3f}", "error_mm": f"{upd.error_mm:.3f}",
        "hours_to_tolerance": opt(upd.hours_to_tolerance, "{:.2f}"), "nis": f"{upd.nis:.3f}",
        "statistic": f"{upd.statistic:.3f}",
    }


def replay_monitor(session: Path, reference: Path, out: Path, *, settings: MonitorSettings | None = None,
                   shared_error=None, rng=None, frames: dict | None = None) -> MonitorReplay:
    """Stream ``session`` through the engine armed from ``reference``; write the trace into ``out``.

    Raises
    ------
    SessionError
        Unreadable session or reference, a reference that cannot arm the engine, or an ``out`` that cannot be
        created.
    MonitorError
        An unexpected error at a sample (named; the trace, the alarms and the calibration in use up to it are
        written).
    """
    prod = read_session(session)
    engine = MonitorEngine(settings)
    samples = [o for o in prod.observations]
    first_t = min((o.t for o in samples), default=0.0)
    rep = MonitorReplay(prod.setup, ShiftRecord(prod.setup, str(session), str(reference)), out=Path(out))
    factors = _factors(samples, shared_error)
    if shared_error is not None and all(F is None for F in factors):
        # Without joints no sample can feed the kinematic-error block: the engine is armed without it.
        shared_error = None
        rep.notes.append("the samples have no joints: monitored without the robot's kinematic error")
    rep.notes.append(arm_from_path(engine, Path(reference), prod.setup, shared_error, rng=rng, t=first_t))
    out = rep.out
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise SessionError(f"--out {out}: cannot create ({e.strerror})") from None
    in_use = calibration_in_use.InUseFile(out, frames)
    in_use.armed(engine, first_t)
    with open(out / "monitor_trace.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=TRACE_COLUMNS)
        writer.writeheader()
        for o, F in zip(samples, factors):
            if o.point_cam is None:
                rep.n_skipped += 1
                continue
            try:
                upd = engine.update(o.t, o.T_base_flange, o.point_cam, o.point_cov, F)
                in_use.update(engine, upd, o.t)
            except CalibrationError as e:
                log.warning("sample %d skipped: %s", o.index, e)
                rep.n_skipped += 1
                continue
            except Exception as e:        # noqa: BLE001 - one line naming the sample, what came before it written
                log.debug("sample %d", o.index, exc_info=True)
                rep.record.write(out)
                if is_sound(engine.filter):
                    in_use.write(engine, o.t, "before an unexpected error")
                raise MonitorError(f"sample {o.index}: unexpected error in the monitoring engine "
                                   f"({type(e).__name__}: {e}); the trace and alarms up to it are in {out}") from e
            rep.n_samples += 1
            rep.last = upd
            rep.verify_mm.append(upd.verify_mm)
            writer.writerow(trace_row(o.index, upd, engine.camera_correction))
            rep.record.add(o.index, upd, engine)
    in_use.end(engine, rep.last.t if rep.last is not None else first_t)
    rep.record.write(out)
    return rep


def _factors(samples, shared_error):
    """Each sample's kinematic-error factor (6, P), or None for all (no model, or a sample without joints)."""
    usable = [o for o in samples if o.point_cam is not None]
    F = devices.robot_shared_error("auto", usable, shared_error) if usable else None
    if F is None:
        return [None] * len(samples)
    it = iter(F)
    return [next(it) if o.point_cam is not None else None for o in samples]


def summary(rep: MonitorReplay) -> str:
    """The printed summary: the state at the end in plain words, every alarm with its local time and outcome,
    the live estimate, then the counts and the files."""
    cam = Setup(rep.setup).camera_name
    level, sentence = rep.record.status()
    lines = [f"{level.upper()}: {sentence}"]
    lines += rep.record.alarm_lines()
    if rep.last is not None:
        u = rep.last
        xyz, quat = tf.to_xyz_quat(u.camera_transform)
        v = np.array(rep.verify_mm)
        lines.append(f"  live {cam}: xyz [mm] = {np.round(xyz * 1e3, 2)}  quat (x,y,z,w) = {np.round(quat, 5)}")
        lines.append(f"  1-sigma over the workspace {u.sigma_mm:.2f} mm; drift since the calibration in use "
                     f"{u.drift_mm:.2f} mm / {u.drift_deg:.3f} deg; verification (prediction before fusing) "
                     f"median {np.median(v):.2f} mm, p95 {np.percentile(v, 95):.2f} mm")
    lines.append(f"  {rep.n_samples} samples, {rep.n_skipped} skipped")
    lines += [f"  note: {n}" for n in rep.notes]
    lines.append(f"  report: {rep.out / 'report.html'}  alarms: {rep.out / 'alarms.yaml'}  trace: "
                 f"{rep.out / 'monitor_trace.csv'}  the calibration in use: {rep.out / 'calibration_in_use.yaml'}")
    return "\n".join(lines)

