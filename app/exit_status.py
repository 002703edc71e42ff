"""One exit status per outcome, the same for every command, for scripts and services to act on.

`TABLE` is what ``handeye --help``, each command's ``--help`` and
docs/usage.md show (tests/test_docs.py holds the docs to it).
"""

from __future__ import annotations

import textwrap

PASS = 0
ERROR = 1
USAGE = 2
ALARM = 3
FAIL = 4
WARN = 5
INTERRUPTED = 130

#: ``(status, outcome, meaning)``, in the order of the table.
TABLE = (
    (PASS, "pass", "the result or verification is within the tolerance; monitor: the calibration in use is "
                   "where the camera is and every consumer has it"),
    (ERROR, "error", "one line on stderr says what: a config field, a device, a session, too few samples"),
    (USAGE, "usage", "an unknown option or a bad value on the command line"),
    (ALARM, "alarm", "monitor, demo --monitor, status: the camera moved and its re-learnt calibration is not in "
                     "use everywhere yet (re-learning, waiting for approval, a consumer behind); replay --monitor: "
                     "the camera moved"),
    (FAIL, "fail", "calibrate, demo, replay, verify: do not use the result (its reasons say why)"),
    (WARN, "warn", "calibrate, demo, replay, verify: usable once the reasons printed are checked; monitor, "
                   "status: a consumer has not confirmed the calibration in use"),
    (INTERRUPTED, "interrupted", "Ctrl-C stopped calibrate, demo or verify before its end: what was measured is "
                                 "kept, judged and summarised; monitor's Ctrl-C is its normal end (0 or 3)"),
)


def of_verdict(level: str | None) -> int:
    """The status of a verdict level (`handeye.calib.result.Verdict`); a result without a verdict is to be checked."""
    return {"pass": PASS, "fail": FAIL}.get(level, WARN)


def help_text() -> str:
    """The table for ``--help`` (an argparse epilog, printed as it is)."""
    width = max(len(outcome) for _, outcome, _ in TABLE)
    indent = " " * (width + 9)
    return "exit status:\n" + "\n".join(
        textwrap.fill(meaning, 100, initial_indent=f"  {status:>3}  {outcome:<{width}}  ", subsequent_indent=indent)
        for status, outcome, meaning in TABLE)
