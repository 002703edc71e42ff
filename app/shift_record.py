"""What a monitoring run leaves for the plant: ``alarms.yaml``, ``monitor_trace.png`` and a shift ``report.html``.

Shared by the live ``monitor`` (written into its session at every alarm and
at its end) and ``replay --monitor`` (into ``--out``). `ShiftRecord` keeps,
bounded, the per-sample figures the timeline needs, every alarm with what
became of it (a *moved* alarm's re-learn: when, and how far the camera
moved), and the device outages.

Times shown to people are local ISO 8601 (`handeye.app.calibration_in_use.local_time`).
The camera transform is ``T_base_cam`` eye-to-hand, ``T_flange_cam``
eye-in-hand. Two distances are kept apart: the *drift* is how far the camera
has walked since the calibration in use (the arming one, then each re-learnt
one), the *move since the first calibration* how far the live estimate is
from the cell's first calibration (it steps at a bump and stays).
"""

from __future__ import annotations

import collections
import datetime as _dt
import html
import re
import shlex
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from handeye.app.calibration_in_use import PENDING_FILE, local_time
from handeye.app.consumers import approve_command
from handeye.app.files import uninterrupted
from handeye.app.page import REPORT_STYLE, figure, svg_of, table
from handeye.calib.monitor import AlarmLevel, EngineState, MonitorEngine, MonitorUpdate
from handeye.calib.setup import Setup

#: Samples of the timeline kept (the newest; months of monitoring stay bounded).
MAX_ROWS = 20_000
#: Alarms and outages kept in the record (the newest).
MAX_EVENTS = 2_000
ALARMS_FILE = "alarms.yaml"
PLOT_FILE = "monitor_trace.png"
REPORT_FILE = "report.html"


@dataclass
class ShiftRecord:
    """The figures of a monitoring run for ``alarms.yaml``, the plot and the shift report (module docstring)."""

    setup: Setup
    source: str = ""
    reference: str = ""
    rows: collections.deque = field(default_factory=lambda: collections.deque(maxlen=MAX_ROWS))
    alarms: collections.deque = field(default_factory=lambda: collections.deque(maxlen=MAX_EVENTS))
    outages: collections.deque = field(default_factory=lambda: collections.deque(maxlen=MAX_EVENTS))
    n_samples: int = 0
    last: MonitorUpdate | None = None
    moved_total: tuple[float, float] = (0.0, 0.0)
    #: The versions of the calibration in use and its consumers (`handeye.app.consumers.CalibrationLoop`), if any.
    loop: object = None

    def add(self, sample: int, upd: MonitorUpdate, engine: MonitorEngine) -> None:
        """One engine update of session sample ``sample``."""
        self.n_samples += 1
        self.last = upd
        self.moved_total = engine.moved_since(engine.origin)
        self.rows.append((upd.t, upd.drift_mm, upd.verify_mm, upd.sigma_mm, self.moved_total[0], str(upd.alarm)))
        if upd.alarm:
            self.alarms.append({"sample": sample, "time": local_time(upd.t), "t": float(upd.t),
                                "alarm": str(upd.alarm), "message": upd.message})
        if "re-learnt the camera" in upd.message:
            moved = next((a for a in reversed(self.alarms) if a["alarm"] == AlarmLevel.MOVED), None)
            if moved is not None and "relearnt" not in moved:
                moved["relearnt"] = {"sample": sample, "time": local_time(upd.t),
                                     "message": upd.message.split("; ")[-1]}

    def outage(self, t: float, device: str, event: str, message: str) -> None:
        self.outages.append({"time": local_time(t), "t": float(t), "device": device, "event": event,
                             "message": message})

    # -------------------------------------------------------------- what it says

    def status(self, t: float | None = None) -> tuple[str, str]:
        """``(level, sentence)``: the cell's state now (``t``: default the last sample's time), for the report's
        first line: ``ok``, ``drifting``, ``moved`` (re-learning, or its re-learnt version not approved yet or
        not in use by every consumer: `handeye.app.consumers.CalibrationLoop.status`), ``warn`` (a consumer silent) or
        ``unknown`` (no sample)."""
        u = self.last
        loop = self.loop
        if u is None:
            if loop is not None and loop.history.in_use is not None:
                said = loop.status(time.time() if t is None else t)
                if said is not None:
                    return said
            return "unknown", "no sample reached the monitoring engine"
        mm, deg = self.moved_total
        since = f"the camera has moved {mm:.1f} mm / {deg:.2f} deg since the cell's first calibration"
        if loop is not None:
            said = loop.status(u.t if t is None else t, relearning=u.state == EngineState.RELEARNING)
            if said is not None:
                return said[0], said[1] + f" ({since})"
        if u.state == EngineState.RELEARNING:
            return "moved", f"the camera moved and is being re-learnt from the production stops: {u.message}"
        if u.level == AlarmLevel.DRIFTING:
            return "drifting", (f"the camera is drifting: {u.drift_mm:.2f} mm over the workspace since the "
                                f"calibration in use (predicted error {u.error_mm:.2f} mm); {since}")
        moved = [a for a in self.alarms if a["alarm"] == AlarmLevel.MOVED]
        relearnt = f"; re-learnt after {len(moved)} move{'s' if len(moved) != 1 else ''} this run" if moved else ""
        return "ok", (f"calibrated and quiet: {self.in_use_words()}predicted error {u.error_mm:.2f} mm over the "
                      f"workspace, last verification {u.verify_mm:.2f} mm; {since}{relearnt}")

    def in_use_words(self) -> str:
        """``version 2 in use by the robot program; `` (or that no consumer is configured), or ``""`` without
        versions."""
        loop = self.loop
        in_use = None if loop is None else loop.history.in_use
        if in_use is None:
            return ""
        if not loop.links:
            return (f"version {in_use.number} in use (no consumer is configured in [consumers]: hand "
                    "calibration_in_use.yaml on); ")
        return f"version {in_use.number} in use by {', '.join('the ' + link.name for link in loop.links)}; "

    def alarm_lines(self) -> list[str]:
        """One console line per alarm: kind, local time, sample, what, and for a move what became of it."""
        lines = []
        for a in self.alarms:
            if a["alarm"] == AlarmLevel.MOVED:
                then = a.get("relearnt")
                outcome = (f"; {then['message']} ({then['time']}, sample {then['sample']})" if then
                           else "; not re-learnt yet")
                lines.append(f"  ALARM camera moved at {a['time']} (sample {a['sample']}): {_what(a)}{outcome}")
            else:
                lines.append(f"  ALARM {a['message']} ({a['time']}, sample {a['sample']})")
        return lines

    def next_steps(self, in_use: Path, *, continue_with: str | None, verify_with: str | None = None,
                   calibrate: str | None = None) -> list[str]:
        """What to do after the run, as lines to paste (before any sample: only how to go on, if it was armed).

        After a move, the robot program, a ROS tf or anything else given the camera transform before still
        holds the old one: it is told to take the calibration in use (``in_use``, the run's
        ``calibration_in_use.yaml``), or, while the move is not re-learnt yet, to let the monitor go on or
        recalibrate; likewise for a drift the estimate followed. ``continue_with``: the command that continues
        monitoring from this run; ``verify_with``: ``handeye verify`` with the cell's config, to check the
        calibration in use on fresh poses; ``calibrate``: the command that recalibrates (None: not offered).
        """
        u = self.last
        if u is None:
            # Armed, no sample yet: the calibration in use is the one it was armed with.
            go_on = continue_with and in_use.exists()
            return ["next:", f"  go on monitoring from this calibration in use: {continue_with}"] if go_on else []
        mm, deg = self.moved_total
        moved = [a for a in self.alarms if a["alarm"] == AlarmLevel.MOVED]
        lines = []
        if u.state == EngineState.RELEARNING:
            lines.append("  the camera moved and the production stops have not re-learnt it yet: what uses the camera "
                         "transform (the robot program, a ROS tf) is off by about the move; let the monitor run on"
                         + (" (below)" if continue_with else "") + " to re-learn it from the stops"
                         + (f", or recalibrate when the cell is free: {calibrate}" if calibrate else ""))
        elif moved and self.loop is not None and self.loop.history.pending is not None:
            lines += self._pending_steps(verify_with)
        elif moved and self.loop is not None and self.loop.links and not self.loop.behind():
            names = ", ".join("the " + link.name for link in self.loop.links)
            lines.append(f"  the camera moved and was re-learnt: version {self.loop.history.in_use.number} is in use "
                         f"by {names}; anything else that holds a camera transform (a ROS tf, a vision PC) takes "
                         f"it from {in_use}")
            if verify_with:
                lines.append(f"  check it on fresh poses when the cell is free: {verify_with} --result "
                             f"{shlex.quote(str(in_use))} --yes-move")
        elif moved and in_use.exists():
            times = "once" if len(moved) == 1 else f"{len(moved)} times"
            lines.append(f"  the camera moved {times} and was re-learnt (the alarm lines above say how far; it is "
                         f"{mm:.1f} mm / {deg:.2f} deg from the cell's first calibration): whatever still holds a "
                         f"camera transform from before the move (the robot program, a ROS tf) is off by the move; "
                         f"give it the calibration in use: {in_use} (its ros2_static_transform_publisher line "
                         f"publishes it)")
            if verify_with:
                lines.append(f"  check it on fresh poses when the cell is free: {verify_with} --result "
                             f"{shlex.quote(str(in_use))} --yes-move")
        elif u.level == AlarmLevel.DRIFTING and in_use.exists():
            lines.append(f"  the camera is drifting: {in_use} holds where it is now; give it to what uses the camera "
                         f"transform, and find out what moves the mount")
        if continue_with:
            lines.append(f"  go on monitoring from this calibration in use: {continue_with}")
        return ["next:", *lines] if lines else []

    def _pending_steps(self, verify_with: str | None) -> list[str]:
        """What to do about a version pending: approve it (the command), or let it settle; check it on fresh poses
        first (``verify_with``)."""
        pending = self.loop.history.pending
        if pending.state == "settled" and self.loop.history.policy == "approve":
            lines = [f"  version {pending.number} (the re-learnt camera, predicted error {pending.error_mm:.2f} mm) "
                     f"waits for approval; check the move it was re-learnt from (handeye status), then: "
                     f"{approve_command(self.loop.run)}"]
        else:
            lines = [f"  version {pending.number} (the re-learnt camera) is settling: let the monitor run on; it is put "
                     "in use once settled" + (" and approved" if self.loop.history.policy == "approve" else "")]
        pending_file = None if self.loop.run is None else Path(self.loop.run) / PENDING_FILE
        if verify_with and pending_file is not None and pending_file.exists():
            lines.append(f"  check it on fresh poses when the cell is free: {verify_with} --result "
                         f"{shlex.quote(str(pending_file))} --yes-move")
        return lines

    def alarms_document(self) -> dict:
        level, sentence = self.status()
        doc = {"setup": str(self.setup), "camera_transform": Setup(self.setup).camera_name,
               "session": self.source, "reference": self.reference, "status": {"level": level, "message": sentence}}
        loop = self.loop
        if loop is not None and loop.history.in_use is not None:
            pending = loop.history.pending
            doc.update(calibration_version=loop.history.in_use.number, in_use_by=loop.in_use_by(),
                       pending=None if pending is None else {"version": pending.number, "state": pending.state})
        return {**doc, "alarms": list(self.alarms), "outages": list(self.outages)}

    # -------------------------------------------------------------- files

    def write(self, directory: Path) -> None:
        """``alarms.yaml``, and (when there are samples) the plot and the shift report, into ``directory``; a
        Ctrl-C meanwhile waits for the files (`handeye.app.files.uninterrupted`)."""
        directory = Path(directory)
        with uninterrupted():
            (directory / ALARMS_FILE).write_text(yaml.safe_dump(self.alarms_document(), sort_keys=False,
                                                                width=1000))
            if not self.rows:
                return
            fig = self._figure()
            fig.savefig(directory / PLOT_FILE, dpi=100)
            (directory / REPORT_FILE).write_text(self._report(svg_of(fig)), encoding="utf-8")

    def _version_parts(self) -> list[str]:
        """The report's calibration history: every version, and who uses which."""
        loop = self.loop
        if loop is None or not loop.history.versions:
            return []
        users = [[name, f"version {v}" if v else "no version reported"] for name, v in loop.in_use_by().items()]
        return ["<h2>Calibration versions</h2>",
                table(["version", "state", "why", "predicted error [mm]", "in use since", "by"],
                      _version_rows(loop), "log"),
                table(["consumer", "uses"], users, "log") if users else
                "<p>no consumer is configured ([consumers]): calibration_in_use.yaml is handed on by hand or by the "
                "calibration hook</p>"]

    def _figure(self):
        """The timeline, drawn once per write: the PNG beside the report and the report's SVG."""
        from matplotlib import dates

        t, drift, verify, sigma, total, alarm = zip(*self.rows)
        # The clock a plant's logbook uses, not hours since the first sample (0-0.012 h says nothing).
        t_h = [_dt.datetime.fromtimestamp(x).astimezone() for x in t]
        tz = t_h[0].tzinfo
        cam = Setup(self.setup).camera_name
        fig, ax = figure(figsize=(10, 4.2))
        locator = dates.AutoDateLocator(tz=tz)
        ax.xaxis.set_major_locator(locator)
        ax.xaxis.set_major_formatter(dates.ConciseDateFormatter(locator, tz=tz, show_offset=False))
        ax.plot(t_h, verify, ".", ms=2, color="0.6", label="verification: prediction error before fusing [mm]")
        ax.plot(t_h, total, lw=1.4, color="C3", label=f"{cam}: move since the cell's first calibration [mm]")
        ax.plot(t_h, drift, lw=1.2, color="C0", label="drift since the calibration in use [mm]")
        ax.plot(t_h, sigma, lw=1.0, color="C2", label="live 1-sigma over the workspace [mm]")
        for x, a in zip(t_h, alarm):
            if a:
                ax.axvline(x, color="r" if a == AlarmLevel.MOVED else "orange", ls="--", lw=0.8)
        for o in self.outages:
            if o["event"] == "outage_start":
                ax.axvline(_dt.datetime.fromtimestamp(o["t"]).astimezone(), color="0.3", ls=":", lw=0.8)
        ax.set_xlabel(f"local time ({time_axis_label(t[0], t[-1])})")
        ax.set_ylabel("mm")
        ax.set_title("monitoring (red: moved, orange: drifting, dotted: device outage)")
        ax.legend(fontsize=7)
        fig.tight_layout()
        return fig

    def _report(self, timeline_svg: str) -> str:
        """The shift report: the state now, the timeline, the alarms with their outcome, the outages, the live
        camera transform; self-contained, prints on A4 or Letter."""

        level, sentence = self.status()
        css = {"ok": "pass", "drifting": "warn", "moved": "fail", "unknown": "warn"}[level]
        t = [r[0] for r in self.rows]
        cam = Setup(self.setup).camera_name
        parts = [f'<div class="verdict {css}" id="verdict"><span class="level">{level.upper()}</span>'
                 f"{html.escape(sentence)}</div>",
                 "<h1>handeye monitoring report</h1>",
                 f'<p class="sub">{html.escape(str(self.setup).replace("_", "-"))} · {self.n_samples} samples '
                 "monitored (after arming) from "
                 f"{html.escape(local_time(t[0]))} to {html.escape(local_time(t[-1]))}"
                 + (f" · {html.escape(self.source)}" if self.source else "") + "</p>",
                 "<h2>Timeline</h2>", f'<figure class="plot">{timeline_svg}'
                 "<figcaption>the move since the cell's first calibration steps at a bump and stays; the drift "
                 "is the camera's walk since the calibration in use (back to zero at a re-learn)</figcaption>"
                 "</figure>"]
        rows = []
        for a in self.alarms:
            outcome = a.get("relearnt", {}).get("message", "") if a["alarm"] == AlarmLevel.MOVED else ""
            if a["alarm"] == AlarmLevel.MOVED and not outcome:
                outcome = "not re-learnt yet"
            rows.append([a["time"], a["sample"], a["alarm"], _what(a), outcome])
        parts += ["<h2>Alarms</h2>", table(["time", "sample", "alarm", "what", "then"], rows, "log") if rows
                  else "<p>none</p>"]
        parts += self._version_parts()
        stats = [[a["time"], a["sample"], a["message"]] for a in self.alarms]
        outages = [[o["time"], o["device"], o["event"].replace("_", " "), o["message"]] for o in self.outages]
        parts += ["<h2>Device outages</h2>", table(["time", "device", "event", "message"], outages, "log") if outages
                  else "<p>none</p>"]
        u = self.last
        if u is not None:
            from handeye.calib import transforms as tf

            xyz, quat = tf.to_xyz_quat(u.camera_transform)
            rate = "not yet measured" if u.drift_rate_mm_h is None else f"{u.drift_rate_mm_h:.2f} mm/h"
            kv = [[f"live {cam}: xyz [mm]", " ".join(f"{v * 1e3:.2f}" for v in xyz)],
                  ["quaternion (x, y, z, w)", " ".join(f"{v:.5f}" for v in quat)],
                  ["move since the cell's first calibration", f"{self.moved_total[0]:.2f} mm / "
                                                               f"{self.moved_total[1]:.3f} deg"],
                  ["drift since the calibration in use", f"{u.drift_mm:.2f} mm / {u.drift_deg:.3f} deg, {rate}"],
                  ["predicted error of the calibration in use", f"{u.error_mm:.2f} mm"],
                  ["live 1-sigma over the workspace", f"{u.sigma_mm:.2f} mm"],
                  ["last verification (prediction before fusing)", f"{u.verify_mm:.2f} mm"]]
            parts += ["<h2>The camera now</h2>", table(None, kv, "kv"),
                      "<p class=\"note\">the whole result with every export: calibration_in_use.yaml beside this "
                      "report</p>"]
        if stats:
            parts += ["<h2>Appendix: the change detector's statistics</h2>",
                      table(["time", "sample", "message (GLR: the test statistic of a move, against its threshold)"],
                            stats, "log")]
        title = "handeye monitoring report"
        return ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
                f"<title>{title}</title><style>{REPORT_STYLE}</style></head><body>" + "".join(parts)
                + "</body></html>\n")


def _version_rows(loop) -> list[list]:
    return [[v.number, v.state.replace("_", " "), v.why, f"{v.error_mm:.2f}",
             local_time(v.applied) if v.applied is not None else "",
             v.applied_by or (f"approved by {v.approved_by}" if v.approved_by else "")]
            for v in loop.history.versions]


def time_axis_label(t0: float, t1: float) -> str:
    """The day(s) and UTC offset of a local-time axis from ``t0`` to ``t1`` (s since the epoch):
    ``2026-12-06, UTC+01:00`` or ``2026-12-06 to 2026-12-07, UTC+01:00``."""
    a, b = (_dt.datetime.fromtimestamp(x).astimezone() for x in (t0, t1))
    offset = a.strftime("%z")
    days = f"{a:%Y-%m-%d}" + ("" if b.date() == a.date() else f" to {b:%Y-%m-%d}")
    return f"{days}, UTC{offset[:3]}:{offset[3:]}"


def _what(alarm: dict) -> str:
    """An alarm's message in plain words: without the re-learn's progress it was raised with (its outcome is
    told apart) and the detector's statistic (the appendix has it)."""
    return re.sub(r" \(GLR statistic [^)]*\)", "", alarm["message"].split("; re-learn")[0])
