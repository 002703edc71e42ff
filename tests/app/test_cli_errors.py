"""CLI error paths: one line on stderr, exit 1 (2 for usage); nothing moves without consent."""

import io

import pytest

from app.cli import confirm_motion, main
from calib.errors import HandeyeError


def _one_line_error(capsys, rc):
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    assert len(err) == 1 and "error:" in err[0], err
    return err[0]


def test_unknown_config_key(tmp_path, capsys):
    p = tmp_path / "c.toml"
    p.write_text("[calibrate]\nsampels = 3\n")
    line = _one_line_error(capsys, main(["calibrate", "--yes-move", "-c", str(p)]))
    assert "calibrate.sampels" in line


def test_bad_value_names_field(tmp_path, capsys):
    p = tmp_path / "c.toml"
    p.write_text("[calibrate]\ntilt_deg = -5\n")
    assert "calibrate.tilt_deg" in _one_line_error(capsys, main(["calibrate", "--yes-move", "-c", str(p)]))


def test_invalid_toml_and_missing_file(tmp_path, capsys):
    p = tmp_path / "c.toml"
    p.write_text("[calibrate\n")
    assert "invalid TOML" in _one_line_error(capsys, main(["demo", "-c", str(p)]))
    assert "not found" in _one_line_error(capsys, main(["demo", "-c", str(tmp_path / "nope.toml")]))


def test_replay_missing_source(tmp_path, capsys):
    _one_line_error(capsys, main(["replay", str(tmp_path / "nothing")]))


def test_calibrate_refuses_without_tty_or_flag(capsys, monkeypatch):
    monkeypatch.setattr("sys.stdin", io.StringIO(""))
    line = _one_line_error(capsys, main(["calibrate"]))
    assert "--yes-move" in line


def test_confirmation_prompt(monkeypatch):
    class Tty(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr("builtins.input", lambda prompt: "n")
    with pytest.raises(HandeyeError, match="not confirmed"):
        confirm_motion(False, stdin=Tty())
    monkeypatch.setattr("builtins.input", lambda prompt: "y")
    confirm_motion(False, stdin=Tty())


def test_usage_error_exits_2():
    with pytest.raises(SystemExit) as e:
        main(["frobnicate"])
    assert e.value.code == 2
