"""The exit status a command's printed verdict calls for (`handeye.app.exit_status`), to hold its exit status to."""

from handeye.app import exit_status


def printed_status(out: str) -> int:
    """`handeye.app.exit_status.of_verdict` of the first ``PASS:`` / ``WARN:`` / ``FAIL:`` line of ``out``."""
    level = next(line.split(":")[0] for line in out.splitlines() if line.startswith(("PASS:", "WARN:", "FAIL:")))
    return exit_status.of_verdict(level.lower())
