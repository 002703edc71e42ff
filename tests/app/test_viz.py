"""The rerun viewer path: no viewer, a viewer that cannot open a window, one that dies mid-run.

In every case the run goes on, one warning line says why, and the
``recording.rrd`` is complete.
"""

import logging
import subprocess
import sys

import numpy as np
import pytest

from handeye.app import viz as viz_mod
from handeye.app.cli import main
from handeye.app.viz import Viz
from tests.app.verdict_status import printed_status

REAL_VIEWER = viz_mod.viewer_command()

FAKE_VIEWER = """
import socket, sys, time
args = sys.argv[1:]
open(sys.argv[0] + ".args", "w").write(" ".join(args))
s = socket.socket()
s.bind((args[args.index("--bind") + 1], int(args[args.index("--port") + 1])))
s.listen()
time.sleep(float({life}))
print("fake viewer: window closed", file=sys.stderr)
sys.exit(1)
"""


def _log_some(v: Viz, n: int = 3) -> None:
    for i in range(n):
        v.robot(float(i), np.eye(4))
        v.event(float(i), f"event {i}")


def _viewer_warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING and "viewer" in r.getMessage()]


def test_no_viewer_executable_is_one_warning(tmp_path, monkeypatch, caplog):
    monkeypatch.setattr(viz_mod, "viewer_command", lambda: None)
    rrd = tmp_path / "recording.rrd"
    with caplog.at_level(logging.WARNING), Viz("eye_to_hand", rrd, viewer=True) as v:
        _log_some(v)
    assert v.viewer is None
    (msg,) = _viewer_warnings(caplog)
    assert "no rerun viewer executable" in msg and str(rrd) in msg
    assert rrd.stat().st_size > 0


def test_viewer_without_display_is_one_warning(tmp_path, monkeypatch, caplog):
    """The rerun viewer shipped with rerun-sdk, started with no display: it listens, then exits."""
    if viz_mod.viewer_command() is None:
        pytest.skip("rerun-sdk ships no viewer executable on this platform")
    for var in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(var, raising=False)
    rrd = tmp_path / "recording.rrd"
    with caplog.at_level(logging.WARNING), Viz("eye_to_hand", rrd, viewer=True) as v:
        _log_some(v)
    (msg,) = _viewer_warnings(caplog)
    assert "exited" in msg and "DISPLAY" in msg, msg
    assert rrd.stat().st_size > 0


def test_viewer_dying_mid_run_leaves_the_recording_whole(tmp_path, monkeypatch, caplog):
    script = tmp_path / "fake_viewer.py"
    script.write_text(FAKE_VIEWER.format(life=1.5))
    monkeypatch.setattr(viz_mod, "viewer_command", lambda: [sys.executable, str(script)])
    rrd = tmp_path / "recording.rrd"
    with caplog.at_level(logging.WARNING):
        v = Viz("eye_in_hand", rrd, viewer=True)
        assert v.viewer is not None and v.viewer.alive()
        _log_some(v)
        v.viewer.proc.wait(10)
        _log_some(v)  # notices the dead viewer: one warning, then goes on with the file only
        v.drift(10.0, 1.5, 0.1)  # logged only after the viewer died
        v.close()
    (msg,) = _viewer_warnings(caplog)
    assert "window closed" in msg, msg
    # Loopback only unless the config says otherwise (issue 11).
    args = (tmp_path / "fake_viewer.py.args").read_text().split()
    assert args[args.index("--bind") + 1] == "127.0.0.1"
    # What was logged after the viewer died is in the file.
    if REAL_VIEWER is not None:
        out = subprocess.run([*REAL_VIEWER, "rrd", "print", str(rrd)], capture_output=True, text=True, timeout=60).stdout
        assert "/drift/translation_mm" in out and "/world/flange" in out
    assert rrd.stat().st_size > 0


@pytest.mark.slow
def test_demo_with_viewer_and_no_display_writes_result(tmp_path, monkeypatch, caplog, capsys, loopback):
    for var in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(var, raising=False)
    cfg = tmp_path / "sim.toml"
    text = open("config/sim.toml").read().replace('host = "127.0.0.2"', f'host = "{loopback(40)}"')
    cfg.write_text(text)
    with caplog.at_level(logging.WARNING):
        rc = main(["demo", "-c", str(cfg), "--viewer", "--samples", "5", "--session-root", str(tmp_path / "s")])
    assert len(_viewer_warnings(caplog)) == 1
    (session,) = (tmp_path / "s").iterdir()
    assert (session / "result.yaml").exists() and (session / "recording.rrd").stat().st_size > 0
    out = capsys.readouterr().out
    assert rc == printed_status(out), out
    assert "open the recording:  " in out and str(session / "recording.rrd") in out
    assert "publish in ROS 2:    ros2 run tf2_ros static_transform_publisher" in out
