"""A session killed mid-run (SIGKILL, no cleanup) keeps every sample taken and replays."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from app.cli import main
from app.runs.calibrate import calibrate
from app.session import read_session

pytestmark = pytest.mark.slow


def _sample_lines(root: Path) -> int:
    files = list(root.glob("*/samples.jsonl"))
    if not files:
        return 0
    return files[0].read_bytes().count(b'"kind": "sample"')


def test_sigkill_mid_run_then_replay_and_resume(tmp_path, capsys, sim_config, loopback):
    cfg = tmp_path / "sim.toml"
    cfg.write_text(Path("config/sim.toml").read_text().replace('host = "127.0.0.2"', f'host = "{loopback(4)}"'))
    root = tmp_path / "sessions"
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "demo", "-c", str(cfg), "--samples", "40",
                             "--until-sigma", "off", "--session-root", str(root), "--no-viz"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while _sample_lines(root) < 7:
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "no samples recorded in 60 s"
            time.sleep(0.05)
    finally:
        # The process only, like `kill -9 <pid>`: its simulator and RTDE client must exit by
        # themselves (parent death), or the resume below cannot bind the simulator's ports.
        proc.kill()
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    session_dir = next(root.iterdir())
    session = read_session(session_dir)
    n = len(session.observations)
    assert n >= 7
    for obs in session.observations:  # every sample line names frames that exist
        assert (session_dir / obs.meta["color"]).exists() and (session_dir / obs.meta["depth"]).exists()
    assert main(["replay", str(session_dir), "-m", "YKronT'", "-m", "YQuatT'"]) == 0
    out = capsys.readouterr().out
    assert f"eye_to_hand, {n} samples" in out and "| YKronT' |" in out and "err [mm]" in out

    # ... and the killed session can be resumed: two more samples, appended with fresh indices.
    cfg2 = sim_config(loopback(4), samples=n + 2, min_samples=6, target_sigma_mm=0.0, target_sigma_deg=0.0)
    cfg2 = cfg2.model_copy(update={"viz": cfg2.viz.model_copy(update={"enabled": False})})
    resumed = calibrate(cfg2, resume=session_dir, progress=False)
    assert resumed.report.session == session_dir and resumed.report.n_samples == n + 2
    indices = [o.index for o in read_session(session_dir).observations]
    assert len(indices) == n + 2 and indices == sorted(set(indices))
    assert (session_dir / "result.yaml").exists()


def test_ctrl_c_stops_and_keeps_samples(tmp_path, loopback):
    cfg = tmp_path / "sim.toml"
    cfg.write_text(Path("config/sim.toml").read_text().replace('host = "127.0.0.2"', f'host = "{loopback(6)}"'))
    root = tmp_path / "sessions"
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "calibrate", "--yes-move", "-c", str(cfg),
                             "--session-root", str(root), "--no-viz", "--no-frames"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while _sample_lines(root) < 2:
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)  # what Ctrl-C at the terminal sends
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, err
    assert "stopped by: interrupted" in out
    session = read_session(next(root.iterdir()))
    assert len(session.observations) >= 2
    assert session.events[-1]["event"] == "interrupted"
