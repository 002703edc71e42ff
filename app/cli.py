"""``handeye`` command line: a thin layer over library calls that return results.

Known errors (``calib.errors.HandeyeError``) print one line and exit 1; usage
errors exit 2; ``monitor`` exits 3 when it raised a camera-moved alarm.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import time
from pathlib import Path

import numpy as np

from calib.errors import HandeyeError
from calib.setup import Setup

log = logging.getLogger("handeye")

EXIT_ALARM = 3


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("-c", "--config", type=Path, help="TOML config (default: the embedded simulated cell)")
    p.add_argument("--session-root", type=Path, help="directory for sessions (overrides session.root)")
    p.add_argument("--no-viz", action="store_true", help="disable rerun logging")
    p.add_argument("--viewer", action="store_true", help="open a live rerun viewer")
    p.add_argument("--viewer-bind", help="address the live viewer listens on (default 127.0.0.1, loopback only)")
    p.add_argument("--no-frames", action="store_true", help="do not store color/depth PNGs in the session")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="handeye", description="Hand-eye calibration from 3D marker points "
                                     "(Grossmann & Krueger: YKronT', YQuatT').")
    parser.add_argument("-v", "--verbose", action="count", default=0)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("calibrate", help="active run: move the robot through random poses and calibrate")
    _common(p)
    p.add_argument("--yes-move", action="store_true", help="allow robot motion without the confirmation prompt")
    p.add_argument("--samples", type=int, help="number of samples (overrides calibrate.samples)")
    p.add_argument("--seed", type=int, help="seed of the random poses (overrides calibrate.seed)")
    p.add_argument("--method", help="solver, paper name (overrides calibrate.method), e.g. \"YKronT'\"")
    p.add_argument("--resume", type=Path, help="continue this session (e.g. after a crash or Ctrl-C)")

    p = sub.add_parser("monitor", help="passive: sample while the robot works, alarm when the camera moved")
    _common(p)
    p.add_argument("--reference", type=Path, help="session whose samples give the reference calibration")
    p.add_argument("--duration", type=float, help="seconds to run (overrides monitor.duration_s)")
    p.add_argument("--max-samples", type=int, help="stop after this many samples")
    p.add_argument("--hook", help="command to run on an alarm (overrides monitor.alarm_hook)")

    p = sub.add_parser("replay", help="re-solve a recorded session or an imported file, compare solvers")
    p.add_argument("source", type=Path, help="session directory, or a file/dir to import (easy_handeye, "
                   "industrial_calibration, pose-stream CSV)")
    p.add_argument("-m", "--method", action="append", dest="methods",
                   help="solver (repeatable); default YKronT' and YQuatT'; 'all' for every solver")
    p.add_argument("--refine", action="store_true", help="refine each solution (nonlinear least squares)")
    p.add_argument("--robust", action="store_true", help="reject outliers")
    p.add_argument("--setup", choices=[s.value for s in Setup], help="setup of an imported file")
    p.add_argument("--seed", type=int, default=0, help="seed for randomised (robust) solvers and the folds")
    p.add_argument("-c", "--config", type=Path, help="config whose calibrate.target_sigma_mm/_deg the 1-sigma "
                   "warnings use (default targets: 3 mm, 0.2 deg)")

    p = sub.add_parser("demo", help="simulated UR10 + rendered camera: calibrate and compare to the truth "
                       "(--monitor: watch a production program, bump the camera, alarm)")
    _common(p)
    p.add_argument("--samples", type=int, help="number of samples (default from the config)")
    p.add_argument("--seed", type=int, help="seed of the random poses")
    p.add_argument("--monitor", action="store_true", help="passive monitoring instead: the simulated robot runs a "
                   "looping production program, the camera is bumped partway; exit status 3 on the alarm")
    p.add_argument("--bump-mm", type=float, default=10.0, help="--monitor: camera shift, mm (default 10; 0 and "
                   "--bump-deg 0 for no bump)")
    p.add_argument("--bump-deg", type=float, default=0.5, help="--monitor: camera rotation, deg (default 0.5)")
    p.add_argument("--bump-after", type=int, default=16, help="--monitor: samples before the bump (default 16)")
    p.add_argument("--reference", type=Path, help="--monitor: session that arms the change detector at once")
    p.add_argument("--max-samples", type=int, help="--monitor: stop after this many samples")

    sub.add_parser("sim-robot", help="run the simulated UR controller (RTDE) in the foreground; "
                   "other arguments go to mocks.ur_sim (--host 127.0.0.x, --model ur10, --controller 5.11)")

    p = sub.add_parser("bench", help="run the benchmarks (markdown tables, PNGs in out/bench/); "
                       "other arguments go to bench.solvers")
    p.add_argument("--vision", action="store_true", help="also run the vision benchmark")
    p.add_argument("--robot", action="store_true", help="also run the robot benchmark")
    return parser


def _apply_overrides(cfg, args):
    """Copy CLI overrides into the config, re-validating the touched sections."""
    cal = {}
    if getattr(args, "samples", None) is not None:
        cal["samples"] = args.samples
        cal["min_samples"] = min(cfg.calibrate.min_samples, args.samples)
    if getattr(args, "seed", None) is not None:
        cal["seed"] = args.seed
    if getattr(args, "method", None) is not None:
        cal["method"] = args.method
    mon = {}
    if getattr(args, "duration", None) is not None:
        mon["duration_s"] = args.duration
    if getattr(args, "max_samples", None) is not None:
        mon["max_samples"] = args.max_samples
    if getattr(args, "hook", None) is not None:
        mon["alarm_hook"] = args.hook
    viz = {}
    if getattr(args, "no_viz", False):
        viz["enabled"] = False
    if getattr(args, "viewer", False):
        viz["viewer"] = True
    if getattr(args, "viewer_bind", None) is not None:
        viz["viewer_bind"] = args.viewer_bind
    ses = {}
    if getattr(args, "session_root", None) is not None:
        ses["root"] = str(args.session_root)
    if getattr(args, "no_frames", False):
        ses["save_frames"] = False
    return dataclasses.replace(
        cfg,
        calibrate=dataclasses.replace(cfg.calibrate, **cal),
        monitor=dataclasses.replace(cfg.monitor, **mon),
        viz=dataclasses.replace(cfg.viz, **viz),
        session=dataclasses.replace(cfg.session, **ses),
    )


def confirm_motion(yes_move: bool, *, stdin=None) -> None:
    """Require ``--yes-move`` or a "y" at a TTY prompt before any robot motion.

    Raises
    ------
    HandeyeError
        When refused, or when there is no TTY to ask and no flag.
    """
    if yes_move:
        return
    stdin = stdin or sys.stdin
    if not stdin.isatty():
        raise HandeyeError("refusing to move the robot: no terminal to confirm on; pass --yes-move")
    answer = input("The robot will move to random poses around its current pose. Continue? [y/N] ")
    if answer.strip().lower() not in ("y", "yes"):
        raise HandeyeError("robot motion not confirmed; nothing moved")


def _load(args):
    """Config file (or the embedded simulated cell) + CLI overrides, every section validated."""
    from app import devices
    from app.config import load_config

    cfg = _apply_overrides(load_config(args.config), args)
    devices.validate(cfg)
    return cfg


def cmd_calibrate(args) -> int:
    from app.runner import calibrate, print_calibration_summary

    cfg = _load(args)
    confirm_motion(args.yes_move)
    out = calibrate(cfg, resume=args.resume)
    print_calibration_summary(out)
    return _exit_code(out)


def _exit_code(out) -> int:
    """130 after Ctrl-C (samples kept), 1 without a calibration, else 0."""
    if out.report.stopped_by == "interrupted":
        return 130
    return 0 if out.report.result is not None else 1


def cmd_monitor(args) -> int:
    from app.runner import monitor, print_monitor_summary

    cfg = _load(args)
    report = monitor(cfg, reference=args.reference)
    print_monitor_summary(report, cfg.setup)
    return EXIT_ALARM if report.alarms else 0


def cmd_replay(args) -> int:
    from app.runner import replay_source

    methods = args.methods or ["YKronT'", "YQuatT'"]
    target = (0.0, 0.0)
    if args.config is not None:
        from app.config import load_config

        cal = load_config(args.config).calibrate
        target = (cal.target_sigma_mm, cal.target_sigma_deg)
    print(replay_source(args.source, methods, refine=args.refine, robust=args.robust, setup=args.setup,
                        rng=np.random.default_rng(args.seed), target_mm=target[0], target_deg=target[1]))
    return 0


def cmd_demo(args) -> int:
    from app.runner import demo, print_demo_summary

    if args.monitor:
        return _demo_monitor(args)
    cfg = _load(args)
    out = demo(cfg)
    print_demo_summary(out)
    return _exit_code(out)


def _demo_monitor(args) -> int:
    from app.production import Bump
    from app.runner import demo_monitor, print_monitor_summary

    if args.bump_after < 1:
        raise HandeyeError(f"--bump-after must be >= 1, got {args.bump_after}")
    cfg = _load(args)
    bump = Bump(args.bump_after, args.bump_mm, args.bump_deg) if (args.bump_mm or args.bump_deg) else None
    report = demo_monitor(cfg, bump=bump, reference=args.reference, max_samples=args.max_samples)
    print_monitor_summary(report, cfg.setup)
    return EXIT_ALARM if report.alarms else 0


def cmd_sim_robot(args) -> int:
    from mocks import ur_sim

    return int(ur_sim.main(args.extra) or 0)


def cmd_bench(args) -> int:
    from bench import solvers

    rc = int(solvers.main(args.extra) or 0)
    if rc == 130:  # Ctrl-C: the finished sections are printed and saved; skip the other benchmarks
        return rc
    if args.vision:
        from bench import vision

        rc = rc or int(vision.main([]) or 0)
    if args.robot:
        from bench import robot

        rc = rc or int(robot.main([]) or 0)
    return rc


# Commands whose unknown arguments are handed on to the program they delegate to.
PASSTHROUGH = ("sim-robot", "bench")

COMMANDS = {"calibrate": cmd_calibrate, "monitor": cmd_monitor, "replay": cmd_replay, "demo": cmd_demo,
            "sim-robot": cmd_sim_robot, "bench": cmd_bench}


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra and args.command not in PASSTHROUGH:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    args.extra = extra
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    t0 = time.monotonic()
    try:
        rc = COMMANDS[args.command](args)
    except HandeyeError as e:
        print(f"handeye {args.command}: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"handeye {args.command}: interrupted", file=sys.stderr)
        return 130
    log.info("%s finished in %.1f s", args.command, time.monotonic() - t0)
    return rc


if __name__ == "__main__":
    sys.exit(main())
