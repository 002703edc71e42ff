"""The first pages of the docs run as written: every ``handeye`` command line of README.md and docs/usage.md
parses against the CLI's own argparse (nothing is executed), and the ones to paste from the clone call
``.venv/bin/handeye`` (which ``make demo`` builds); the demo's printout in the README is what a demo prints."""

import re
import shlex
from pathlib import Path

import pytest

from app.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
DOCS = ("README.md", "docs/usage.md")
PROGRAMS = ("handeye", ".venv/bin/handeye")


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
    assert words[0] == ".venv/bin/handeye", f"{where}: bare `handeye` is not on the PATH after make demo"
    parser, commands = build_parser()
    try:
        args, extra = parser.parse_known_args(words[1:])
    except SystemExit:
        pytest.fail(f"{where}: does not parse: {command}")
    passthrough = getattr(commands[args.command], "PASSTHROUGH", False)
    assert passthrough or not extra, f"{where}: unknown arguments {extra}: {command}"


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
    """docs/usage.md's exit-status table and every command's --help show `app.exit_status.TABLE`, row by row."""
    from app import exit_status

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
