"""``handeye replay``: re-solve a recorded session (or an imported file) with one, several or all solvers, and advise.

The replay is `handeye.app.runs.replay` (``--monitor``: `handeye.app.monitor_replay`); this module parses and prints.
"""

from __future__ import annotations

import argparse
import re
import shlex
from pathlib import Path

import numpy as np

from handeye.app import devices, exit_status
from handeye.app.calibration_in_use import FILE_NAME as IN_USE_FILE
from handeye.app.commands.calibrate import print_statistics
from handeye.app.commands.common import (add_report_options, cell_command, marker_offset, next_steps, program,
                                 report_overrides, tolerance, transform_lines, verdict_lines)
from handeye.app.errors import SessionError
from handeye.app.runs.replay import replay_settings, replay_source, write_outputs
from handeye.calib.setup import Setup


NAME = "replay"
HELP = "re-solve a recorded session or an imported file, compare solvers"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", type=Path, help="session directory, or a file/dir to import (easy_handeye, "
                   "industrial_calibration, pose-stream CSV, ViSP, image folder, OpenCV FileStorage YAML, "
                   "MoveIt Calibration samples, ROS 2 bag)")
    p.add_argument("-m", "--method", action="append", dest="methods",
                   help="solver (repeatable); default 'auto', as calibrate; 'all' for every solver")
    p.add_argument("--refine", action="store_true", help="refine each solution (nonlinear least squares)")
    p.add_argument("--robust", action="store_true", help="reject outliers")
    p.add_argument("--setup", choices=[s.value for s in Setup], help="setup of an imported file")
    p.add_argument("--seed", type=int, default=0, help="seed for randomised (robust) solvers and the folds")
    p.add_argument("--frames", help="ROS 2 bag: tf frames as base=NAME,flange=NAME[,camera=NAME] "
                   "(default: the config's [frames])")
    p.add_argument("--topics", help="ROS 2 bag: color=TOPIC,depth=TOPIC,info=TOPIC,marker=TOPIC where it has several")
    p.add_argument("-c", "--config", type=Path, help="config whose calibrate.tolerance_mm/_deg the verdict "
                   "judges against (default 2 mm, 1 deg), whose robot's kinematic_error auto adds as shared by the "
                   "samples (sessions with joints), and whose session.exports and [frames] --out uses")
    add_report_options(p)
    p.add_argument("--tolerance", type=tolerance, metavar="MM,DEG",
                   help="the error the cell accepts, for the verdict (overrides calibrate.tolerance_mm/_deg)")
    p.add_argument("--out", type=Path, metavar="DIR", help="write the result files, exports and report.html "
                   "of the recommended solver into DIR, as calibrate writes them into its session; with --monitor: "
                   "monitor_trace.csv, alarms.yaml, monitor_trace.png and calibration_in_use.yaml (default "
                   "<session>/monitor_replay)")
    p.add_argument("--marker-offset", type=marker_offset, metavar="X,Y,Z",
                   help="where the marker is, in mm, when known (overrides the config's [marker] offset_m): "
                   "eye-to-hand its centre in the flange frame (a measured TCP), eye-in-hand the static marker's "
                   "centre in the base frame; auto holds it, which completes a recording whose tool never turned "
                   "about two axes (a grid at one orientation)")
    p.add_argument("--marker-offset-sigma", type=float, metavar="MM",
                   help="1-sigma of --marker-offset per axis, mm (default 0: held as given)")
    p.add_argument("--monitor", action="store_true", help="stream the session through the monitoring engine "
                   "(alarms, monitor_trace.csv and a plot into --out); needs --reference")
    p.add_argument("--reference", type=Path, help="--monitor: calibration session (or its result.yaml) that arms "
                   "the engine, or a previous monitoring run (a monitor session or a --monitor --out directory) to "
                   "continue from")


def monitor_next_steps(rep, config: Path | None) -> list[str]:
    """`handeye.app.shift_record.ShiftRecord.next_steps` of a replayed monitoring run: the commands that go on with the
    cell (monitor live from the replay's calibration in use, verify it, recalibrate) only when its config is
    given."""
    if config is None:
        return rep.record.next_steps(rep.out / IN_USE_FILE, continue_with=None)
    return rep.record.next_steps(rep.out / IN_USE_FILE,
                                 continue_with=cell_command("monitor", config, "--reference", rep.out),
                                 verify_with=cell_command("verify", config),
                                 calibrate=cell_command("calibrate", config, "--yes-move"))


def print_lines(lines: list[str]) -> None:
    if lines:
        print("\n" + "\n".join(lines))


def run(args) -> int:
    methods = args.methods or ["auto"]
    settings = replay_settings(args.config, marker_offset=args.marker_offset,
                               marker_offset_sigma_mm=args.marker_offset_sigma)
    if args.monitor:
        from handeye.app.monitor_replay import replay_monitor, summary

        if args.reference is None:
            raise SessionError("replay --monitor needs --reference: the calibration session (or its result.yaml) "
                               "the production session is judged against")
        rep = replay_monitor(args.source, args.reference, args.out or args.source / "monitor_replay",
                             settings=None if settings.config is None else settings.config.monitor.engine,
                             shared_error=settings.shared_error, rng=np.random.default_rng(args.seed),
                             frames=settings.frames)
        print(summary(rep))
        print_lines(monitor_next_steps(rep, args.config))
        return exit_status.ALARM if any(a["alarm"] == "moved" for a in rep.alarms) else exit_status.PASS
    outcome = replay_source(args.source, methods, refine=args.refine, robust=args.robust, setup=args.setup,
                            rng=np.random.default_rng(args.seed), tolerance=args.tolerance or settings.tolerance,
                            shared_error=settings.shared_error, marker_offset=settings.marker_offset,
                            marker_offset_sigma=settings.marker_offset_sigma,
                            import_options=devices.import_options(settings.config, frames=args.frames,
                                                                  topics=args.topics))
    report = {**(settings.config.report.model_dump() if settings.config is not None else {}), **report_overrides(args)}
    files = {} if args.out is None else write_outputs(outcome, args.out, settings.exports, settings.frames, report)
    print_replay(outcome, files, settings.frames, verbose=args.verbose > 0, config=args.config)
    return exit_status.of_verdict(outcome.best.result.verdict.level)


def print_replay(outcome, files: dict, frames: dict | None = None, *, verbose: bool = False,
                 config: Path | None = None) -> None:
    """The verdict of the result replay recommends (and ``--out`` writes), its transform, the solvers'
    comparison when several ran (or ``verbose``), the statistics (``verbose``) and what to do next."""
    from handeye.app.formats import ros2_command

    res = outcome.best.result
    print(outcome.header.rstrip("\n") + f"; result of {outcome.best.method}:\n")
    for line in verdict_lines(res.verdict.to_dict()):
        print(line)
    print()
    for line in transform_lines(res, truth=outcome.truth):
        print(line)
    if verbose or len(outcome.rows) > 1:
        print("\n" + outcome.table)
        if outcome.advice:
            print("\n" + "\n".join(outcome.advice))
    if verbose:
        print_statistics(res, files)
    print()
    if not files:
        name = outcome.best.method
        method = "" if name == "auto" else f' -m "{name}"' if re.fullmatch(r"[\w'*+.-]+", name) else \
            f" -m {shlex.quote(name)}"
        print(f"next: write the result files and report.html: {program()} replay "
              f"{shlex.quote(str(outcome.source))}{method} --out DIR")
        return
    # Without -c the cell is not known here: a placeholder to fill in, the rest quoted for a shell.
    tail = ["--result", str(files.get("yaml")), "--yes-move"]
    verify = None if "yaml" not in files else cell_command("verify", config, *tail) if config is not None else \
        f"{shlex.join([program(), 'verify'])} -c <cell.toml> {shlex.join(tail)}"
    for line in next_steps(res.verdict.level, report=files["report"], ros2=ros2_command(res, frames), verify=verify):
        print(line)
    if not verbose:
        print(f"  files: {', '.join(str(p) for p in files.values())}")
