"""``python -m bench`` (or ``make bench``): the benchmarks (markdown tables on stdout, PNGs in out/bench/).

They are not part of the installed product: they run from a checkout, on top of everything else (nothing
in app/, calib/, drivers/ or mocks/ imports them). Arguments a benchmark's flag does not know go on to the
benchmark it runs; with no flag, the solver benchmark (bench.solvers) runs.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from handeye.app import exit_status
from handeye.calib.errors import HandeyeError

def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vision", action="store_true", help="also run the vision benchmark")
    p.add_argument("--robot", action="store_true", help="also run the robot benchmark")
    p.add_argument("--faults", action="store_true",
                   help="run only the fault campaign (bench.faults: robot and simulator faults, minutes)")
    p.add_argument("--fuzz", action="store_true",
                   help="run only the input fuzz campaign (bench.fuzz: solver API, configs, sessions, imports; minutes)")
    p.add_argument("--plan", action="store_true", help="run only the pose-planning benchmark (bench.plan; "
                   "other arguments go to it)")
    p.add_argument("--shift", action="store_true",
                   help="only the production-shift benchmark of the monitoring engine (bench.shift; --seeds, --hours)")
    p.add_argument("--month", action="store_true",
                   help="only the month-long benchmark of the monitoring engine: live error against its stated "
                   "1-sigma day by day (bench.month; --seeds, --days, --jobs; minutes)")
    p.add_argument("--detection", action="store_true",
                   help="only the smallest bump flagged beside the derived detection limit (bench.detection; "
                   "--seeds, --programs; minutes)")
    p.add_argument("--verify", action="store_true",
                   help="only the handeye verify benchmark on the simulated cell (bench.verify; about a minute)")
    p.add_argument("--cross-session", action="store_true",
                   help="only the cross-session prediction on the real recordings (bench.crosssession)")
    p.add_argument("--model", action="store_true",
                   help="only the measurement-model / solve('auto') benchmark (bench.model; --quick passes through)")
    p.add_argument("--bag", action="store_true",
                   help="run only the ROS 2 bag import benchmark (bench.ros2_bag: a 2-minute demo bag "
                   "per storage, 5.5 GB each, written and removed; other arguments go to it)")
    p.add_argument("--grids", action="store_true",
                   help="only the benchmark of recordings that leave part of the answer open (bench.grids: a grid "
                   "at one tool orientation, rotations about one axis; --cells, --n)")
    p.add_argument("--realsense", action="store_true",
                   help="run only the RealSense path benchmark (bench.realsense: librealsense's software device)")
    p.add_argument("--ros2", action="store_true",
                   help="run only the ROS 2 camera latency benchmark (bench.ros2: a publisher process, real DDS)")


#: The flags that run one benchmark alone (``args.<flag>`` -> ``bench.<module>``), in the order they are checked.
ALONE = {"fuzz": "fuzz", "faults": "faults", "plan": "plan", "shift": "shift", "month": "month",
         "detection": "detection", "cross_session": "crosssession", "verify": "verify", "model": "model",
         "bag": "ros2_bag", "grids": "grids", "realsense": "realsense", "ros2": "ros2"}


def chosen(args) -> str | None:
    """The module of the benchmark a flag runs alone, or None (the solver benchmark, maybe with vision/robot)."""
    return next((module for flag, module in ALONE.items() if getattr(args, flag)), None)


def run(args) -> int:
    """Run the benchmark the flags choose, with ``args.extra`` as its arguments; its exit status."""
    alone = chosen(args)
    if alone is not None:
        return int(importlib.import_module(f"bench.{alone}").main(args.extra) or 0)
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__.splitlines()[0],
                                     epilog=exit_status.help_text(), add_help=False,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-h", "--help", action="store_true",
                        help="this help; after a benchmark's flag (--month --help), that benchmark's own options")
    add_arguments(parser)
    args, args.extra = parser.parse_known_args(argv)
    if args.help:
        if chosen(args) is None:
            parser.print_help()
            return exit_status.PASS
        args.extra = ["--help", *args.extra]
    try:
        return run(args)
    except HandeyeError as e:
        print(f"bench: error: {e}", file=sys.stderr)
        return exit_status.ERROR
    except KeyboardInterrupt:
        print("bench: interrupted", file=sys.stderr)
        return exit_status.INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
