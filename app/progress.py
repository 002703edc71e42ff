"""The console progress of a run: a tqdm bar on a terminal, status lines off one.

On a terminal, log records written while the bar is shown go through
``tqdm.write`` (via ``tqdm.contrib.logging.logging_redirect_tqdm``), so a
warning never lands on the bar's line, and the live 1-sigma sits beside it.

Off a terminal (a service's journal, CI, a pipe) a bar's carriage-return
redraws are noise: 150 monitor samples wrote 40 kB of them. There each event
is one line (`say`, log records) and `LineProgress` prints one status line
every ``status_every`` samples (``[console]``, `handeye.app.config.ConsoleConfig`).
"""

from __future__ import annotations

import contextlib
import logging
import sys

import numpy as np

#: Console settings of this process: the ``[console]`` table of the last loaded config (`configure`).
_settings = {"progress": "auto", "status_every": 20}


def configure(console) -> None:
    """Take the progress mode and status interval of a ``[console]`` table (`handeye.app.config.ConsoleConfig`)."""
    _settings.update(progress=console.progress, status_every=console.status_every)


def on_terminal(stream=None) -> bool:
    """True when a bar can redraw: stdout (or ``stream``) and stderr, where tqdm draws, are both TTYs."""
    streams = (sys.stdout, sys.stderr) if stream is None else (stream,)
    return all(getattr(s, "isatty", lambda: False)() for s in streams)


class LineProgress:
    """The bar's interface (`update`, `set_postfix_str`) as plain lines: a status line every ``every`` samples.

    Parameters
    ----------
    every : int
        Samples between status lines.
    total : int or None
        Planned samples, shown as ``n/total``.
    initial : int
        Samples already taken (a resumed run).
    desc : str
        Name of what is counted.
    write : callable(str)
        Where a line goes (default: stdout, flushed, so a journal shows it at once).
    """

    def __init__(self, every: int, *, total: int | None = None, initial: int = 0, desc: str = "samples",
                 write=None):
        self.every, self.total, self.n, self.desc = every, total, initial, desc
        self.postfix = ""
        self.write = write or (lambda text: print(text, flush=True))
        self.last_shown = initial
        self.due = False

    def status(self) -> str:
        count = f"{self.n}" if self.total is None else f"{self.n}/{self.total}"
        return f"{self.desc}: {count}" + (f" | {self.postfix}" if self.postfix else "")

    def update(self, n: int = 1) -> None:
        # The line is due now but told once the state of this sample is in (`set_postfix_str` follows
        # `update` in the runs), or at the next update / close.
        self._flush()
        self.n += n
        self.due = self.n // self.every > self.last_shown // self.every

    def set_postfix_str(self, text: str) -> None:
        self.postfix = text
        self._flush()

    def _flush(self) -> None:
        if self.due:
            self.write(self.status())
            self.last_shown, self.due = self.n, False

    def close(self) -> None:
        """A last status line unless the newest count was just shown."""
        if self.n != self.last_shown:
            self.write(self.status())
            self.last_shown, self.due = self.n, False


@contextlib.contextmanager
def progress_bar(*, total: int | None = None, initial: int = 0, desc: str = "samples", enabled: bool = True,
                 mode: str | None = None, status_every: int | None = None):
    """Progress of a run (``update(1)`` per sample): a tqdm bar with logging redirected through it on a
    terminal, a `LineProgress` off one.

    ``mode``: ``"auto"`` (bar only when stdout and stderr are TTYs), ``"bar"`` or ``"lines"``;
    ``status_every``: samples per status line in line mode. None: the ``[console]`` settings (`configure`).
    ``enabled=False`` shows nothing.
    """
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    mode = mode or _settings["progress"]
    if enabled and (mode == "lines" or (mode == "auto" and not on_terminal())):
        lines = LineProgress(status_every or _settings["status_every"], total=total, initial=initial, desc=desc)
        try:
            yield lines
        finally:
            lines.close()
        return
    bar = tqdm(total=total, initial=initial, desc=desc, unit="sample", disable=not enabled)
    # Only the root logger has handlers here (logging.basicConfig in the CLI); redirecting it covers every module.
    with bar, logging_redirect_tqdm(loggers=[logging.getLogger()], tqdm_class=tqdm):
        yield bar


def show_sigma(bar, result) -> None:
    """Put the estimate's 1-sigma (`CalibrationResult.sigma`, in mm and deg) beside the bar; no-op without one."""
    if bar is None or result.sigma is None or not hasattr(bar, "set_postfix_str"):
        return
    bar.set_postfix_str(sigma_text(result.sigma))


def sigma_text(sigma) -> str:
    """A worst-axis 1-sigma ``(rotation rad, translation m)`` for the console, in mm and deg."""
    s_rot, s_t = sigma
    return f"1σ {s_t * 1e3:.2f} mm {np.rad2deg(s_rot):.3f}°"


def say(text: str) -> None:
    """A status line for the user, above any open progress bar."""
    from tqdm import tqdm

    tqdm.write(text)


def show_monitor(bar, report) -> None:
    """Change detector state, live 1-sigma and drift beside the monitor's bar (``MonitorReport`` of `handeye.app.runs.monitor`)."""
    if bar is None or not hasattr(bar, "set_postfix_str"):
        return
    n = report.samples_until_armed
    parts = ["testing" if n == 0 else f"testing in {n}"]
    if report.estimate_sigma is not None:
        parts.append(sigma_text(report.estimate_sigma))
    if report.drift is not None:
        parts.append(f"drift {report.drift[0]:.1f} mm {report.drift[1]:.2f}°")
    if report.alarms:
        parts.append(f"ALARMS {len(report.alarms)}")
    bar.set_postfix_str(", ".join(parts))
