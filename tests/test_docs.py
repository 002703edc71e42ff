"""The first pages of the docs run as written: every ``handeye`` command line of README.md, docs/usage.md and
docs/benchmarks.md parses against the CLI's own argparse (nothing is executed; a ``bench`` line also against
the benchmark's own), and the ones to paste from the clone call ``.venv/bin/handeye`` (which ``make demo``
builds); the demo's printout in the README is what a demo prints; every link to a heading finds it."""

import argparse
import re
import shlex
from pathlib import Path

import pytest

from handeye.app.cli import build_parser

import bench.__main__ as bench_main

ROOT = Path(__file__).resolve().parents[1]
DOCS = ("README.md", "docs/usage.md", "docs/benchmarks.md")
PROGRAMS = ("handeye", ".venv/bin/handeye")
BENCH = [".venv/bin/python", "-m", "bench"]


def fenced_lines(text: str) -> list[tuple[int, str]]:
    """``(line number, line)`` of every line inside a fenced code block."""
    out, inside = [], False
    for n, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("```"):
            inside = not inside
        elif inside:
            out.append((n, line))
    return out


def inline_spans(text: str) -> list[tuple[int, str]]:
    """``(line number, code)`` of every inline code span outside the fenced blocks (a span may wrap a line)."""
    lines = text.splitlines()
    fenced = {n for n, _ in fenced_lines(text)} | {n for n, line in enumerate(lines, 1)
                                                   if line.lstrip().startswith("```")}
    prose = "\n".join("" if n in fenced else line for n, line in enumerate(lines, 1))
    return [(prose.count("\n", 0, m.start()) + 1, " ".join(m.group(1).split()))
            for m in re.finditer(r"`([^`]+)`", prose)]


def command_lines() -> list[tuple[str, str, bool]]:
    """``(where, command, fenced)`` of every handeye invocation in the docs (comments stripped)."""
    found = []
    for doc in DOCS:
        text = (ROOT / doc).read_text(encoding="utf-8")
        for fenced, items in ((True, fenced_lines(text)), (False, inline_spans(text))):
            for n, code in items:
                words = code.split()
                # (an inline `handeye verify` names a command; with arguments it is a command line)
                if words and words[0] in PROGRAMS and len(words) > (1 if fenced else 2):
                    found.append((f"{doc}:{n}", code, fenced))
                elif words[:3] in (BENCH, ["python", "-m", "bench"]) and (fenced or len(words) > 3):
                    found.append((f"{doc}:{n}", code, fenced))
    return found


COMMANDS = command_lines()


def test_the_docs_show_commands_at_all():
    assert len(COMMANDS) > 30 and sum(fenced for *_, fenced in COMMANDS) > 20


@pytest.mark.parametrize("where, command, fenced", COMMANDS, ids=[w for w, *_ in COMMANDS])
def test_every_command_line_parses(where, command, fenced):
    """Every command line (fenced, or inline with arguments) runs from the clone as written
    (``.venv/bin/handeye``) and parses: known command, known options, values of the right type, nothing
    left over."""
    words = shlex.split(command, comments=True)
    if words[1:3] == ["-m", "bench"]:      # test_every_bench_command_line_parses_in_its_benchmark
        assert words[:3] == BENCH, f"{where}: `python` is not the project's after make demo"
        return
    assert words[0] == ".venv/bin/handeye", f"{where}: bare `handeye` is not on the PATH after make demo"
    parser, commands = build_parser()
    try:
        args, extra = parser.parse_known_args(words[1:])
    except SystemExit:
        pytest.fail(f"{where}: does not parse: {command}")
    passthrough = getattr(commands[args.command], "PASSTHROUGH", False)
    assert passthrough or not extra, f"{where}: unknown arguments {extra}: {command}"


class _Parsed(Exception):
    """Raised in place of running a benchmark once its own parser has taken the arguments."""


def bench_refuses(command: str, monkeypatch) -> bool:
    """Whether the benchmark a ``python -m bench`` line runs (bench.solvers, bench.shift, ...) refuses
    the arguments ``python -m bench`` hands on to it. The benchmark stops once its parser has them."""
    parse_args = argparse.ArgumentParser.parse_args

    def parse_only(self, args=None, namespace=None):
        parse_args(self, args, namespace)       # SystemExit on an option the benchmark does not have
        raise _Parsed

    with monkeypatch.context() as patch:
        patch.setattr(argparse.ArgumentParser, "parse_args", parse_only)
        try:
            bench_main.main(shlex.split(command, comments=True)[3:])
        except SystemExit:
            return True
        except _Parsed:
            return False
    raise AssertionError(f"ran without parsing its arguments: {command}")


BENCH_COMMANDS = [(where, command) for where, command, _ in COMMANDS
                  if shlex.split(command, comments=True)[1:3] == ["-m", "bench"]]


@pytest.mark.parametrize("where, command", BENCH_COMMANDS, ids=[w for w, _ in BENCH_COMMANDS])
def test_every_bench_command_line_parses_in_its_benchmark(where, command, monkeypatch):
    """``python -m bench`` takes any argument on to the benchmark it runs: each one the docs show is the
    benchmark's own."""
    assert not bench_refuses(command, monkeypatch), f"{where}: the benchmark refuses its arguments: {command}"


def test_the_bench_check_catches_an_option_the_benchmark_lacks(monkeypatch):
    assert bench_refuses(".venv/bin/python -m bench --month --hours 8", monkeypatch)    # the shift's option
    assert bench_refuses(".venv/bin/python -m bench --quik", monkeypatch)
    assert not bench_refuses(".venv/bin/python -m bench --shift --hours 8", monkeypatch)


def test_the_check_catches_a_bad_command():
    parser, _ = build_parser()
    with pytest.raises(SystemExit):
        parser.parse_known_args(["verify", "--tolerance", "2"])        # MM,DEG expected
    args, extra = parser.parse_known_args(["replay", "x", "--bogus"])
    assert extra == ["--bogus"]


def readme_demo_printout() -> list[str]:
    """The README's example of ``make demo``'s printout (the fenced block after "First run" that starts with
    ``session:``)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    first_run = text[text.index("## First run"):]
    block = re.search(r"```\n(session: .*?)```", first_run, re.S).group(1)
    return block.rstrip("\n").splitlines()


def printout_shape(lines: list[str]) -> list[str]:
    """Each non-empty line's label: the words before its first number, path or value (verdict lines by kind)."""
    shape = []
    for line in lines:
        if not line.strip() or line.startswith("  - "):
            continue
        if re.match(r"(PASS|WARN|FAIL): ", line):
            shape.append("<verdict>")
            continue
        shape.append(re.split(r"[:=(]", line, maxsplit=1)[0].rstrip())
    return shape


def check_demo_printout(printed: str) -> None:
    """``printed`` (a demo's stdout) has the README example's lines, in the README's order and no others but
    the progress lines and the verdict's reasons."""
    lines = [ln for ln in printed.splitlines() if not ln.startswith("samples: ")]
    start = next(i for i, ln in enumerate(lines) if ln.startswith("session: "))
    assert printout_shape(lines[start:]) == printout_shape(readme_demo_printout()), printed


def test_the_readme_printout_has_the_shape_the_check_expects():
    shape = printout_shape(readme_demo_printout())
    assert shape[:3] == ["session", "setup", "<verdict>"] and "next" in shape and "  publish in ROS 2" in shape


def test_the_exit_status_table_of_the_docs_and_the_help_is_the_one_the_commands_return(capsys):
    """docs/usage.md's exit-status table and every command's --help show `handeye.app.exit_status.TABLE`, row by row."""
    from handeye.app import exit_status

    text = (ROOT / "docs/usage.md").read_text(encoding="utf-8")
    section = text[text.index("### Exit status"):]
    rows = re.findall(r"(?m)^\| (\d+) \| (\w+) \| (.+) \|$", section[:section.index("\n\n", section.index("|---"))])
    assert [(int(s), o, m) for s, o, m in rows] == list(exit_status.TABLE)
    parser, commands = build_parser()
    for argv in (["--help"], *([name, "--help"] for name in commands)):
        with pytest.raises(SystemExit):
            parser.parse_args(argv)
        page, name = capsys.readouterr().out, argv[0]
        assert page.endswith(exit_status.help_text() + "\n"), name
        assert all(f"  {status:>3}  {outcome} " in page for status, outcome, _ in exit_status.TABLE), name


def _quoted(doc: str, pattern: str) -> list[str]:
    """The inline code spans of ``doc`` that match ``pattern`` (a regex, from the span's start)."""
    return [code for _, code in inline_spans((ROOT / doc).read_text(encoding="utf-8")) if re.match(pattern, code)]


def test_the_bench_progress_the_docs_quote_counts_the_experiments_the_run_has(tmp_path):
    """docs/usage.md's ``bench.solvers [i/n] ...`` has the n the benchmark's first progress line shows (it said
    [3/8] where the run shows [1/7])."""
    import os
    import subprocess
    import sys

    (quote,) = _quoted("docs/usage.md", r"bench\.solvers \[")
    proc = subprocess.Popen([sys.executable, "-m", "bench.solvers", "--quick", "--out", str(tmp_path)],
                            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, cwd=tmp_path,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        first = proc.stderr.readline()
    finally:
        proc.kill()
        proc.wait()
    total = re.match(r"bench\.solvers \[1/(\d+)\] ", first)
    assert total, first
    assert re.match(rf"bench\.solvers \[\d+/{total.group(1)}\] ", quote), (quote, first)


def test_the_second_ctrl_c_line_the_docs_quote_is_the_one_printed(caplog):
    """docs/usage.md quotes what a second Ctrl-C prints while a stopped run ends (`handeye.app.stopping`)."""
    import signal

    from handeye.app import stopping

    quote = next(q for q in _quoted("docs/usage.md", r"stopping: "))
    with caplog.at_level("WARNING", logger="handeye.app.stopping"), stopping.command():
        stopping.winding_down()
        signal.raise_signal(signal.SIGINT)
    assert [r.getMessage() for r in caplog.records] == [quote]


def test_the_verdict_of_an_unresolved_tolerance_the_docs_quote_is_the_one_printed():
    """docs/usage.md's example of a verification whose poses cannot resolve the tolerance."""
    import numpy as np

    from handeye.calib import verify as cv
    from handeye.calib.verdict import judge_verification

    (quote,) = _quoted("docs/usage.md", r"the rotation tolerance ")
    n = 12
    errors = cv.PoseErrors(np.full((n, 3), 1e-4), np.full(n, np.deg2rad(0.8)), np.full(n, 1e-8),
                           np.deg2rad(0.88) ** 2)
    v = cv.verify(errors, tolerance_mm=2.0, tolerance_deg=0.5, rng=np.random.default_rng(0))
    assert judge_verification(v).summary.startswith(quote + ": ")


def heading_anchors(path: Path) -> set[str]:
    """The anchors GitHub gives the headings of a markdown file: lower case, punctuation dropped, spaces as
    hyphens, a repeated one numbered (-1, -2, ...)."""
    text = path.read_text(encoding="utf-8")
    fenced = {n for n, _ in fenced_lines(text)}
    anchors, count = set(), {}
    for n, line in enumerate(text.splitlines(), 1):
        heading = re.match(r"#{1,6} (.+)", line)
        if heading and n not in fenced:
            slug = re.sub(r"[^\w\- ]", "", heading.group(1).strip().lower()).replace(" ", "-")
            anchors.add(f"{slug}-{count[slug]}" if slug in count else slug)
            count[slug] = count.get(slug, 0) + 1
    return anchors


def test_every_link_to_a_heading_finds_it():
    """A link into a page (``benchmarks.md#an-8-hour-shift``) lands on its heading: the benchmarks' results
    moved to a page of their own and their history to another, and three links pointed at nothing."""
    broken = []
    for doc in (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))):
        for n, line in enumerate(doc.read_text(encoding="utf-8").splitlines(), 1):
            for page, anchor in re.findall(r"\]\(([^)\s#]*)#([^)\s]+)\)", line):
                target = (doc.parent / page) if page else doc
                if not target.exists() or anchor not in heading_anchors(target):
                    broken.append(f"{doc.relative_to(ROOT)}:{n}: {page}#{anchor}")
    assert not broken, broken
