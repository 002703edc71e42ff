"""CLI error paths: one line on stderr, exit 1 (2 for usage); nothing moves without consent."""

import io

import pytest

from handeye.app.cli import main
from handeye.app.commands.common import confirm_motion
from handeye.calib.errors import HandeyeError


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


def test_calibrate_refuses_without_tty_or_flag(capsys, monkeypatch, tmp_path, loopback):
    """Connected to the (simulated) robot and camera, it refuses to move without a terminal to ask on or
    --yes-move: nothing moved, no session written."""
    from pathlib import Path

    p = tmp_path / "c.toml"
    p.write_text(Path("config/sim.toml").read_text().replace('host = "127.0.0.2"', f'host = "{loopback(68)}"'))
    monkeypatch.setattr("sys.stdin", io.StringIO(""))
    line = _one_line_error(capsys, main(["calibrate", "-c", str(p), "--session-root", str(tmp_path / "s"),
                                         "--no-viz"]))
    assert "--yes-move" in line and not list((tmp_path / "s").glob("*"))


def test_calibrate_connects_before_it_asks(capsys, monkeypatch, tmp_path, loopback):
    """No controller at robot.host and no --yes-move: the one line is the connection's, not a question about
    motion asked before the robot was even reached (it asked 'Continue? [y/N]' first)."""
    from pathlib import Path

    asked = []
    monkeypatch.setattr("handeye.app.commands.calibrate.confirm_motion", lambda yes_move: asked.append(yes_move))
    p = tmp_path / "c.toml"
    p.write_text(Path("config/ur10_xtion_eye_to_hand.toml").read_text().replace('"192.168.1.10"',
                                                                                f'"{loopback(69)}"'))
    line = _one_line_error(capsys, main(["calibrate", "-c", str(p), "--session-root", str(tmp_path), "--no-viz"]))
    assert "cannot open RTDE receive on UR controller" in line and asked == []


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


def test_unreachable_robot_is_one_line(tmp_path, capsys, loopback):
    p = tmp_path / "c.toml"
    p.write_text(f'[robot]\ntype = "ur"\nhost = "{loopback(99)}"\nworkspace_min = [0.6, -0.2, 0.2]\n'
                 'workspace_max = [1.2, 0.4, 0.8]\nconnect_timeout = 1.0\n[camera]\nbackend = "rendered"\n')
    line = _one_line_error(capsys, main(["calibrate", "--yes-move", "-c", str(p), "--session-root", str(tmp_path)]))
    assert loopback(99) in line


def test_wrong_marker_id_skips_every_frame_with_reason(tmp_path, capsys, loopback):
    """The camera shows marker 0, the config asks for 7: every frame is skipped and says why; exit 1."""
    p = tmp_path / "c.toml"
    text = open("config/sim.toml").read().replace('host = "127.0.0.2"', f'host = "{loopback(10)}"')
    p.write_text(text.replace("marker_id = 0", "marker_id = 7").replace("max_attempts = 200", "max_attempts = 3"))
    assert main(["calibrate", "--yes-move", "-c", str(p), "--session-root", str(tmp_path), "--no-viz"]) == 1
    out = capsys.readouterr().out
    assert "3x marker 7 of DICT_4X4_50 not found" in out and "no calibration: 0 samples" in out
    from handeye.app.session import read_session

    session = read_session(next(tmp_path.glob("*_eye_to_hand")))
    assert len(session.skipped) == 3 and not session.observations


@pytest.mark.parametrize("argv, expected", [
    (["demo", "--no-viz"], "handeye demo --no-viz --resume 'my sessions/s1'"),
    (["-v", "calibrate", "--resume", "old", "-c", "a b.toml"],
     "handeye -v calibrate -c 'a b.toml' --resume 'my sessions/s1'"),
    (["calibrate", "--resume=old", "--yes-move"], "handeye calibrate --yes-move --resume 'my sessions/s1'"),
    (["demo", "--res", "old", "--samples", "9"], "handeye demo --samples 9 --resume 'my sessions/s1'"),
])
def test_resume_command_is_the_runs_own_with_its_session(argv, expected):
    """The command an interrupted run prints to continue: what was typed, its own --resume (also abbreviated or
    with '=') replaced, quoted for a shell."""
    import argparse
    from pathlib import Path

    from handeye.app.commands.common import command_with

    assert command_with(argparse.Namespace(argv=argv), "--resume", Path("my sessions/s1")) == expected


def test_demo_resume_refusals(tmp_path, capsys):
    """demo --resume continues only a simulated cell's calibration session, and not with --monitor."""
    from handeye.app.session import SessionWriter

    assert "--resume continues a calibration" in _one_line_error(
        capsys, main(["demo", "--monitor", "--resume", str(tmp_path)]))
    with SessionWriter.create(tmp_path, "eye_to_hand") as w:  # a real cell's session: no simulated truth
        pass
    line = _one_line_error(capsys, main(["demo", "--resume", str(w.path), "--session-root", str(tmp_path)]))
    assert "recorded on a real cell" in line and f"handeye calibrate -c <its config> --resume {w.path}" in line


def test_ctrl_c_while_the_program_starts_or_inside_a_c_extensions_import_is_a_stop(capsys, monkeypatch):
    # Ctrl-C in the first second (numpy, scipy, OpenCV loading) was a KeyboardInterrupt traceback; during
    # open3d's first import at the simulator's first render it came out as "ImportError: initialization
    # failed" (exit 1, traceback). Both are the terminal's stop: one line, exit 130. Another ImportError is a bug.
    import handeye.app.cli as cli
    from handeye.app.commands import replay

    def interrupted():
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(cli, "build_parser", interrupted)
        assert main(["replay", "x"]) == 130
    assert capsys.readouterr().err == "handeye: interrupted\n"

    def import_stopped(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise ImportError("initialization failed") from e

    monkeypatch.setattr(replay, "run", import_stopped)
    assert main(["replay", "x"]) == 130
    assert capsys.readouterr().err == "handeye replay: interrupted\n"
    monkeypatch.setattr(replay, "run", lambda args: __import__("no_such_module_here"))
    with pytest.raises(ImportError):
        main(["replay", "x"])


def test_no_ur_controller_at_the_address_is_one_line_naming_it_and_what_to_check(tmp_path, capsys, loopback):
    """The shipped Xtion config with robot.host where no controller listens: one line that names the UR controller,
    the address tried and what to check (it said 'read: End of file' and stopped there)."""
    from pathlib import Path

    host = loopback(67)
    p = tmp_path / "c.toml"
    p.write_text(Path("config/ur10_xtion_eye_to_hand.toml").read_text().replace('"192.168.1.10"', f'"{host}"'))
    line = _one_line_error(capsys, main(["calibrate", "--yes-move", "-c", str(p), "--session-root", str(tmp_path),
                                         "--no-viz"]))
    assert f"cannot open RTDE receive on UR controller {host} (robot.host): " in line
    assert line.endswith(f"; check that the controller is on and reachable (ping {host}), on port 30004, and that "
                         "robot.host is its address"), line


def test_sim_robot_help_lists_the_simulators_options(capsys):
    """``sim-robot --help`` lists the options it takes (it listed none, and handed them on unseen); a wrong one is
    a usage error."""
    with pytest.raises(SystemExit) as e:
        main(["sim-robot", "--help"])
    out = capsys.readouterr().out
    assert e.value.code == 0 and all(f"  {o} " in out for o in ("--host HOST", "--model MODEL", "--controller"))
    with pytest.raises(SystemExit) as e:
        main(["sim-robot", "--hots", "127.0.0.5"])
    assert e.value.code == 2
