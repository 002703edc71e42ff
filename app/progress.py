"""The console progress bar of a run: tqdm with log lines routed above it and the live 1-sigma beside it.

Log records written while the bar is shown go through ``tqdm.write`` (via
``tqdm.contrib.logging.logging_redirect_tqdm``), so a warning never lands on
the bar's line.
"""

from __future__ import annotations

import contextlib
import logging

from app.pipeline import sigma


@contextlib.contextmanager
def progress_bar(*, total: int | None = None, initial: int = 0, desc: str = "samples", enabled: bool = True):
    """A tqdm bar (``update(1)`` per sample) with logging redirected through it while it is open."""
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    bar = tqdm(total=total, initial=initial, desc=desc, unit="sample", disable=not enabled)
    # Only the root logger has handlers here (logging.basicConfig in the CLI); redirecting it covers every module.
    with bar, logging_redirect_tqdm(loggers=[logging.getLogger()], tqdm_class=tqdm):
        yield bar


def show_sigma(bar, cov) -> None:
    """Put the current estimate's worst-axis 1-sigma (mm, deg) beside the bar; no-op without a covariance."""
    if bar is None or cov is None or not hasattr(bar, "set_postfix_str"):
        return
    s_deg, s_mm = sigma(cov)
    bar.set_postfix_str(f"1σ {s_mm:.2f} mm {s_deg:.3f}°")


def say(text: str) -> None:
    """A status line for the user, above any open progress bar."""
    from tqdm import tqdm

    tqdm.write(text)


def show_monitor(bar, report) -> None:
    """Detector state, live 1-sigma and drift beside the monitor's bar."""
    if bar is None or not hasattr(bar, "set_postfix_str"):
        return
    from app.monitor import detector_state

    parts = [detector_state(report.samples_until_armed).replace(" more samples", "").replace(" more sample", "")]
    if report.estimate_cov is not None:
        s_deg, s_mm = sigma(report.estimate_cov)
        parts.append(f"1σ {s_mm:.2f} mm {s_deg:.3f}°")
    if report.drift is not None:
        parts.append(f"drift {report.drift[0]:.1f} mm {report.drift[1]:.2f}°")
    if report.alarms:
        parts.append(f"ALARMS {len(report.alarms)}")
    bar.set_postfix_str(", ".join(parts))
