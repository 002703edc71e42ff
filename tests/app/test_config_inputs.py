"""Config files that used to validate and then fail: each is a one-line ConfigError naming field and file.

Property test: any value in any field of config/sim.toml, and any byte
damage to the file, gives a loaded config or a ConfigError -- never another
exception -- and nothing opens a device (no robot address is used here).
"""

import os
import re
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from handeye.app import devices
from handeye.app.cli import main
from handeye.app.config import Config, load_config
from handeye.app.errors import ConfigError
from handeye.calib.errors import HandeyeError

SIM = Path(__file__).resolve().parents[2] / "config" / "sim.toml"
SIM_LINES = SIM.read_text().splitlines()
VALUE_LINES = [i for i, line in enumerate(SIM_LINES) if re.match(r"^[a-z_]+ *= ", line)]


def _one_line_error(capsys, rc):
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    assert len(err) == 1 and "error:" in err[0], err
    return err[0]


def _edit(tmp_path, old, new, name="c.toml"):
    text = SIM.read_text()
    assert old in text
    p = tmp_path / name
    p.write_text(text.replace(old, new))
    return p


@pytest.mark.parametrize("old,new,field", [
    ('alarm_hook = ""', 'alarm_hook = "echo \\"unbalanced"', "monitor.alarm_hook"),
    ('alarm_hook = ""', 'alarm_hook = "no-such-program-xyz --now"', "monitor.alarm_hook"),
    ('calibration_hook = ""', 'calibration_hook = "no-such-program-xyz"', "monitor.calibration_hook"),
    ("engine = {}", "engine = {detector = 5}", "monitor.engine"),
    ("engine = {}", "engine = {tolerance_mm = \"fast\"}", "monitor.engine"),
    ("engine = {}", "engine = {relearn_samples = 1.5}", "monitor.engine"),
    ("engine = {}", "engine = {walk_mm_per_sqrt_h = true}", "monitor.engine"),
    ('method = "auto"', 'method = "bogus"', "calibrate.method"),
    ('root = "sessions"', 'root = "/etc/hostname/sessions"', "session.root"),
    ("speed = 0.5", "speed = true", "speed"),
    ("acceleration = 2.0", "acceleration = false", "acceleration"),
    ("speed = 0.5", "speed = 0.5\npath_step = 1e-7", "path_step"),
    ("speed = 0.5", "speed = 0.5\npath_step = 2.0", "path_step"),
])
def test_bad_field_is_one_line_naming_field_and_file(tmp_path, capsys, old, new, field):
    p = _edit(tmp_path, old, new)
    line = _one_line_error(capsys, main(["calibrate", "--yes-move", "--no-viz", "-c", str(p)]))
    assert field in line and str(p) in line


def test_unknown_method_on_the_command_line_fails_before_any_motion(capsys, loopback, tmp_path):
    p = _edit(tmp_path, 'host = "127.0.0.2"', f'host = "{loopback(3)}"')
    line = _one_line_error(capsys, main(["calibrate", "--yes-move", "-c", str(p), "--method", "bogus",
                                         "--session-root", str(tmp_path / "s")]))
    assert "calibrate.method" in line and "bogus" in line and "YKronT'" in line
    assert not (tmp_path / "s").exists()  # failed before the session (and the robot) was opened


def test_method_aliases_are_normalised(tmp_path):
    cfg = load_config(_edit(tmp_path, 'method = "auto"', 'method = "yquatt"'))
    assert cfg.calibrate.method == "YQuatT'"


def test_a_partial_detector_table_keeps_the_default_false_alarm_rate(tmp_path):
    """``detector = { window = 30 }`` changes the window only: the *moved* test's rate stays the engine's
    (it once fell to another default, ten times stricter)."""
    from handeye.calib.change import FALSE_ALARM_RATE

    assert load_config(_edit(tmp_path, "engine = {}", "engine = { detector = { window = 30 } }")) \
        .monitor.engine.detector.false_alarm_rate == FALSE_ALARM_RATE == load_config(None).monitor.engine \
        .detector.false_alarm_rate
    cfg = load_config(_edit(tmp_path, "engine = {}", "engine = { detector = { false_alarm_rate = 1e-5 } }"))
    assert cfg.monitor.engine.detector.false_alarm_rate == 1e-5 and cfg.monitor.engine.detector.window == 20


@pytest.mark.parametrize("make,match", [
    (lambda p: p.write_bytes(b'setup = "eye_to_hand"\n# caf\xe9 \xff\n'), "not UTF-8"),
    (lambda p: p.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n"), "nested deeper"),
    (lambda p: p.write_text("a = " + "[" * 40 + "]" * 40 + "\n"), "nested deeper"),
    (lambda p: p.mkdir(), "is a directory"),
    (lambda p: os.mkfifo(p), "not a regular file"),
    (lambda p: p.write_bytes(b"x" * (2 * 1024 * 1024)), "larger than"),
])
def test_unreadable_files_are_one_line(tmp_path, capsys, make, match):
    p = tmp_path / "c.toml"
    make(p)
    line = _one_line_error(capsys, main(["calibrate", "--yes-move", "-c", str(p)]))
    assert match in line and str(p) in line


def test_hook_parsed_at_load_and_kept_as_argv():
    from handeye.app.config import hook_argv

    assert hook_argv("touch '/tmp/a b'") == ["touch", "/tmp/a b"]
    assert hook_argv("  ") == []
    with pytest.raises(ConfigError, match="monitor.alarm_hook.*closing quotation"):
        hook_argv("touch 'x")


# TOML values of every type, including ones no field takes.
TOML_VALUES = st.sampled_from([
    "true", "false", "0", "-1", "1e-7", "1e308", "inf", "-inf", "nan", "1_000_000_000_000", '""', '"x"',
    '"\\u00e9"', "[]", "[1, 2]", '["a", 1]', "{}", "{a = 1}", "{detector = 5}", "1979-05-27", "[[1], [2]]",
    "0.0", "-0.0", "3", '"YKronT\'"', '"eye_in_hand"', "[0.0, 0.0, 0.0]",
])


def _load_and_validate(text: str, tmp: Path):
    p = tmp / "fuzz.toml"
    p.write_text(text, encoding="utf-8", errors="surrogateescape")
    try:
        cfg = load_config(p)
        # Never create directories where a mutated root points: validate the rest against a temp root.
        cfg = cfg.model_copy(update={"session": cfg.session.model_copy(update={"root": str(tmp / "sessions")})})
        devices.check_session_root(cfg)
    except HandeyeError as e:
        assert "\n" not in str(e) or "invalid TOML" in str(e)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(line=st.sampled_from(VALUE_LINES), value=TOML_VALUES)
def test_any_value_in_any_field_is_loaded_or_a_config_error(tmp_path, line, value):
    lines = list(SIM_LINES)
    key = lines[line].split("=")[0]
    lines[line] = f"{key}= {value}"
    _load_and_validate("\n".join(lines) + "\n", tmp_path)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pos=st.integers(0, len(SIM.read_bytes())), junk=st.binary(max_size=8), cut=st.integers(0, 12))
def test_byte_damage_is_loaded_or_a_config_error(tmp_path, pos, junk, cut):
    data = SIM.read_bytes()
    damaged = data[:pos] + junk + data[pos + cut:]
    p = tmp_path / "fuzz.toml"
    p.write_bytes(damaged)
    try:
        cfg = load_config(p)
        cfg = cfg.model_copy(update={"session": cfg.session.model_copy(update={"root": str(tmp_path / "sessions")})})
        devices.check_session_root(cfg)
    except HandeyeError:
        pass


def test_the_monitors_hook_options_override_the_config(tmp_path):
    """--hook and --calibration-hook replace [monitor] alarm_hook and calibration_hook; a program that is not
    there is the same one-line error naming the field as in the file."""
    from handeye.app.cli import build_parser
    from handeye.app.commands.common import load_config_args

    parser, _ = build_parser()
    args = parser.parse_args(["monitor", "--hook", "touch a", "--calibration-hook", "touch 'b c'"])
    cfg = load_config_args(args)
    assert (cfg.monitor.alarm_hook, cfg.monitor.calibration_hook) == ("touch a", "touch 'b c'")
    with pytest.raises(ConfigError, match="monitor.calibration_hook"):
        load_config_args(parser.parse_args(["monitor", "--calibration-hook", "no-such-program-xyz"]))


def test_every_bad_field_reads_the_same_and_an_unknown_key_names_the_close_one(tmp_path):
    """One wording for every wrong type and bound, whatever the field (it was pydantic's 'Input should be a valid
    integer' beside handeye's "must be a number, got 'fast'"); an unknown key names the key it is close to,
    in the backend's own table too."""
    p = tmp_path / "c.toml"
    p.write_text('[robot]\ntype = "ur_sim"\nhost = "127.0.0.2"\nhots = "x"\nspeed = "fast"\n'
                 '[camera]\nbackend = "openni2"\nfps = "30"\nwidht = 640\nregistration = 1\n'
                 '[calibrate]\nsampels = 3\ntilt_deg = 120\n[frames]\nbsae = "base"\n[mqtt]\nenabeld = true\n')
    with pytest.raises(ConfigError) as e:
        load_config(p)
    parts = str(e.value).removeprefix(f"{p}: ").split("; ")
    assert sorted(parts) == sorted([
        "robot.hots: unknown key (did you mean host?)", "robot.speed: must be a number, got 'fast'",
        "camera.fps: must be an integer, got '30'", "camera.widht: unknown key (did you mean width?)",
        "camera.registration: must be true or false, got 1", "calibrate.sampels: unknown key (did you mean samples?)",
        "calibrate.tilt_deg: must be at most 90, got 120", "frames.bsae: unknown key (did you mean base?)",
        "mqtt.enabeld: unknown key (did you mean enabled?)"]), parts


def test_a_shipped_config_is_found_from_any_directory_and_a_local_file_comes_first(tmp_path, monkeypatch):
    """``-c config/sim.toml`` from outside the clone (an installed wheel) is the package's; a file of that name
    in the current directory is the user's and wins."""
    monkeypatch.chdir(tmp_path)
    assert load_config("config/sim.toml") == Config()
    assert load_config("sim_ros2.toml").robot.type == "ros2_sim"
    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "sim.toml").write_text('setup = "eye_in_hand"\n')
    assert str(load_config("config/sim.toml").setup) == "eye_in_hand"
    with pytest.raises(ConfigError, match="not found"):
        load_config("config/nope.toml")
