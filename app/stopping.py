"""After the Ctrl-C that stops a run, the next one hurries its end instead of losing what was measured.

The first Ctrl-C (SIGINT, a KeyboardInterrupt) stops a run where it is: the
robot stopped, the samples kept. The run then calls `winding_down`, and until
the command returns (`command`) a second Ctrl-C does not interrupt: it cuts
short only the work marked `skippable` (a final refined solve), and the
summary and the files still come. A third quits at once without them (exit
130), so that an end that hangs on a device never traps anyone. Outside
`command` (the library called directly) nothing changes: every Ctrl-C is a
KeyboardInterrupt where it lands.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading

log = logging.getLogger(__name__)

#: The press that quits at once, the summary and files not yet written.
QUIT_PRESS = 3


class _WindDown:
    """The SIGINT handler while a stopped run ends: counts the presses, raises only where it may."""

    def __init__(self):
        self.presses = 1          # the one that stopped the run
        self.skippable = False

    def __call__(self, signum, frame):
        self.presses += 1
        if self.skippable or self.presses >= QUIT_PRESS:
            raise KeyboardInterrupt
        log.warning("stopping: what was measured is being summarised and written; Ctrl-C once more to quit "
                    "without it")


_scope: dict = {}


@contextlib.contextmanager
def command():
    """Around a command of the CLI: where `winding_down` takes effect; the SIGINT handler is restored at exit."""
    if threading.current_thread() is not threading.main_thread() or _scope:
        yield
        return
    _scope["previous"] = signal.getsignal(signal.SIGINT)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, _scope.pop("previous"))
        _scope.clear()


def winding_down() -> None:
    """Called by a run once a Ctrl-C stopped it: from now until the command returns, a second Ctrl-C only
    hurries the end (module docstring). No-op outside `command`, and when already winding down."""
    if "previous" in _scope and "handler" not in _scope and threading.current_thread() is threading.main_thread():
        _scope["handler"] = _WindDown()
        signal.signal(signal.SIGINT, _scope["handler"])


@contextlib.contextmanager
def skippable():
    """Work a second Ctrl-C may cut short while the run winds down (a KeyboardInterrupt inside the block)."""
    handler = _scope.get("handler")
    if handler is None:
        yield
        return
    handler.skippable = True
    try:
        yield
    finally:
        handler.skippable = False
