"""``python -m bench``: the benchmarks' entry, outside the product."""

import pytest

from bench.__main__ import main


def test_help_after_a_benchmark_flag_is_that_benchmarks_own(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--month", "--help"])
    assert stop.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: python -m bench --month") and "--days" in out


def test_help_alone_lists_the_benchmarks(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: python -m bench") and "--month" in out and "--shift" in out


def test_an_option_no_benchmark_has_is_refused(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--month", "--hours", "8"])           # the shift's option, not the month's
    assert stop.value.code == 2
