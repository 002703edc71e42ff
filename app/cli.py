"""``handeye`` command line: builds the parser from the command modules of `handeye.app.commands` and runs one.

Known errors (``handeye.calib.errors.HandeyeError``) print one line and exit 1; every
exit status is `handeye.app.exit_status`'s.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import time

from handeye.app import exit_status, stopping
from handeye.app.commands import command_modules

log = logging.getLogger("handeye")


def build_parser() -> tuple[argparse.ArgumentParser, dict]:
    """The parser and ``{command name: module}``."""
    parser = argparse.ArgumentParser(prog="handeye", description="Hand-eye calibration from 3D marker points "
                                     "(Grossmann & Krueger: YKronT', YQuatT').", epilog=exit_status.help_text(),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more detail: the statistics behind a verdict (chi-square, noise levels, ...), "
                        "info log lines")
    sub = parser.add_subparsers(dest="command", required=True)
    commands = {}
    for module in command_modules():
        command = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP,
                                 epilog=exit_status.help_text(), formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(command)
        if not getattr(module, "PASSTHROUGH", False):   # (a passthrough command's -v is its program's)
            # Also after the command (`handeye demo -v`); SUPPRESS keeps a -v given before it.
            command.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                                 help="more detail: the statistics behind a verdict (chi-square, noise levels, "
                                 "...), info log lines")
        commands[module.NAME] = module
    return parser, commands


def main(argv: list[str] | None = None) -> int:
    # A shell without job control starts a background command with SIGINT ignored; handeye's Ctrl-C is a clean
    # stop (the robot stopped, every sample kept, exit 130), so `handeye ... & kill -INT -- -PGID` must reach it.
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        # The first import of calib and the commands loads numpy, scipy and OpenCV (a second or two): a Ctrl-C
        # then is a stop too, not a traceback.
        from handeye.calib.errors import HandeyeError

        parser, commands = build_parser()
    except KeyboardInterrupt:
        print("handeye: interrupted", file=sys.stderr)
        return exit_status.INTERRUPTED
    args, extra = parser.parse_known_args(argv)
    command = commands[args.command]
    if extra and not getattr(command, "PASSTHROUGH", False):
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    args.extra = extra
    args.argv = list(sys.argv[1:] if argv is None else argv)  # as typed: the command a run prints to continue it
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    t0 = time.monotonic()
    try:
        with stopping.command():   # a second Ctrl-C hurries a stopped run's end, it does not lose its summary
            rc = command.run(args)
    except HandeyeError as e:
        print(f"handeye {args.command}: error: {e}", file=sys.stderr)
        return exit_status.ERROR
    except KeyboardInterrupt:
        print(f"handeye {args.command}: interrupted", file=sys.stderr)
        return exit_status.INTERRUPTED
    except BrokenPipeError:
        # The reader went away (`handeye status | head`): what it wanted was printed; no traceback at exit either.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return exit_status.PASS
    except ImportError as e:
        # A Ctrl-C inside a C extension's first import (open3d at the simulator's first render, a vendor SDK at
        # connect) comes out as "initialization failed" from that import: it was the stop.
        if not isinstance(e.__cause__ or e.__context__, KeyboardInterrupt):
            raise
        print(f"handeye {args.command}: interrupted", file=sys.stderr)
        if argv is None:
            # The half-initialised extension's C++ exit handlers would end the process with status 1.
            end_now(exit_status.INTERRUPTED)
        return exit_status.INTERRUPTED
    log.info("%s finished in %.1f s", args.command, time.monotonic() - t0)
    if argv is None:
        leave_cleanly_past_two_dds(rc)
    return rc


def leave_cleanly_past_two_dds(rc: int) -> None:
    """End the program now, everything written and closed, when both librealsense (pyrealsense2, which carries
    its own Fast DDS) and ROS 2 (rclpy, over Fast DDS) were loaded, pyrealsense2 first: the two copies crash in
    the C++ exit handlers (a segmentation fault after the run, exit status 139 instead of ``rc``, which a
    service would take for a failure). Else return (the normal exit)."""
    if {"pyrealsense2", "rclpy"} <= sys.modules.keys():
        end_now(rc)


def end_now(rc: int) -> None:
    """End the program with status ``rc`` now, its output flushed and its log closed, without the exit handlers
    of loaded C++ libraries (`leave_cleanly_past_two_dds`; an extension whose first import a Ctrl-C cut short)."""
    sys.stdout.flush()
    sys.stderr.flush()
    logging.shutdown()
    os._exit(rc)


if __name__ == "__main__":
    sys.exit(main())
