"""The console progress bar of a run: tqdm with log lines routed above it and the live 1-sigma beside it.

Log records written while the bar is shown go through ``tqdm.write`` (via
``tqdm.contrib.logging.logging_redirect_tqdm``), so a warning never lands on
the bar's line.
"""

from __future__ import annotations

import contextlib
import logging

import numpy as np


@contextlib.contextmanager
def progress_bar(*, total: int | None = None, initial: int = 0, desc: str = "samples", enabled: bool = True):
    """A tqdm bar (``update(1)`` per sample) with logging redirected through it while it is open."""
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    bar = tqdm(total=total, initial=initial, desc=desc, unit="sample", disable=not enabled)
    # Only the root logger has handlers here (logging.basicConfig in the CLI); redirecting it covers every module.
    with bar, logging_redirect_tqdm(loggers=[logging.getLogger()], tqdm_class=tqdm):
        yield bar


def show_sigma(bar, result) -> None:
    """Put the estimate's 1-sigma (`CalibrationResult.sigma`, in mm and deg) beside the bar; no-op without one."""
    if bar is None or result.sigma is None or not hasattr(bar, "set_postfix_str"):
        return
    s_rot, s_t = result.sigma
    bar.set_postfix_str(f"1σ {s_t * 1e3:.2f} mm {np.rad2deg(s_rot):.3f}°")


def say(text: str) -> None:
    """A status line for the user, above any open progress bar."""
    from tqdm import tqdm

    tqdm.write(text)


def show_monitor(bar, report) -> None:
    """Change detector state, live 1-sigma and drift beside the monitor's bar (``MonitorReport`` of `app.commands.monitor`)."""
    if bar is None or not hasattr(bar, "set_postfix_str"):
        return
    n = report.samples_until_armed
    parts = ["armed" if n == 0 else f"armed after {n}"]
    if report.estimate_sigma is not None:
        s_rot, s_t = report.estimate_sigma
        parts.append(f"1σ {s_t * 1e3:.2f} mm {np.rad2deg(s_rot):.3f}°")
    if report.drift is not None:
        parts.append(f"drift {report.drift[0]:.1f} mm {report.drift[1]:.2f}°")
    if report.alarms:
        parts.append(f"ALARMS {len(report.alarms)}")
    bar.set_postfix_str(", ".join(parts))
