"""The ``handeye`` commands, one module each.

A command module defines ``NAME`` (as typed), ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int`` (the exit status), and
sets ``PASSTHROUGH = True`` if it hands unknown arguments (``args.extra``) on
to the program it runs. It parses, calls a library function or a run of
`handeye.app.runs` (which opens the devices and loops) and prints the result it
returns; the work is done below it. Adding a command is one new module here plus its
name in `COMMANDS` (see docs/architecture.md).
"""

from __future__ import annotations

import importlib
from types import ModuleType

#: Command modules, in the order ``handeye --help`` lists them.
COMMANDS = ("calibrate", "plan", "monitor", "status", "approve", "replay", "verify", "demo", "sim_robot")


def command_modules() -> list[ModuleType]:
    """The command modules of `COMMANDS`, imported."""
    return [importlib.import_module(f"{__name__}.{name}") for name in COMMANDS]
