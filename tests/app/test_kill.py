"""A session killed mid-run (SIGKILL, no cleanup) keeps every sample taken and replays."""

import html
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from handeye.app.cli import main
from handeye.app.runs.calibrate import calibrate
from handeye.app.runs.demo import demo
from handeye.app.session import read_session
from tests.app.verdict_status import printed_status

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
    proc = subprocess.Popen([sys.executable, "-m", "handeye.app.cli", "demo", "-c", str(cfg), "--samples", "40",
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
    rc = main(["replay", str(session_dir), "-m", "YKronT'", "-m", "YQuatT'"])
    out = capsys.readouterr().out
    assert rc == printed_status(out), out
    assert f"eye_to_hand, {n} samples" in out and "| YKronT' |" in out and "err [mm]" in out

    # ... and the killed session can be resumed: two more samples, appended with fresh indices.
    cfg2 = sim_config(loopback(4), samples=n + 2, min_samples=6, target_sigma_mm=0.0, target_sigma_deg=0.0)
    cfg2 = cfg2.model_copy(update={"viz": cfg2.viz.model_copy(update={"enabled": False})})
    resumed = calibrate(cfg2, resume=session_dir, progress=False)
    assert resumed.report.session == session_dir and resumed.report.n_samples == n + 2
    indices = [o.index for o in read_session(session_dir).observations]
    assert len(indices) == n + 2 and indices == sorted(set(indices))
    assert (session_dir / "result.yaml").exists()


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "handeye.app.cli", *args]


def _sim_cell(tmp_path, host: str, **calibrate) -> Path:
    """config/sim.toml on ``host`` with ``[calibrate]`` values replaced."""
    text = Path("config/sim.toml").read_text().replace('host = "127.0.0.2"', f'host = "{host}"')
    for key, value in calibrate.items():
        text = re.sub(rf"(?m)^{key} = \S+", f"{key} = {value}", text, count=1)
    cfg = tmp_path / "sim.toml"
    cfg.write_text(text)
    return cfg


def _holds(root: Path, n_samples: int):
    """`_ctrl_c`'s moment: ``root``'s session holds ``n_samples`` samples."""
    return lambda: _sample_lines(root) >= n_samples


def _ctrl_c(argv: list[str], ready, while_running=None) -> tuple[int, str, str]:
    """Run ``argv`` in its own session, and once ``ready()`` send SIGINT to the whole process group, as a
    terminal's Ctrl-C does (the children the run started included). ``while_running()`` is called once
    meanwhile. Returns (exit status, stdout, stderr)."""
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        if while_running is not None:
            while_running(proc)
        deadline = time.monotonic() + 90
        while not ready():
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the moment for Ctrl-C did not come in 90 s"
            time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    # The run stopped its own children (they have sessions of their own): none is left behind.
    assert not _processes_naming(f"--parent-pid {proc.pid}")
    assert "Traceback" not in err, err
    return proc.returncode, out, err


def _processes_naming(text: str) -> list[str]:
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            line = cmdline.read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if text in line:
            found.append(line)
    return found


def test_ctrl_c_to_the_process_group_keeps_the_demo_result_and_resumes(tmp_path, capsys, loopback):
    """Ctrl-C after min_samples samples: the simulator does not take the SIGINT, the run stops the robot,
    solves the kept samples, writes result.yaml and report.html, records the interruption and prints the
    command that continues it, exit 130; that command resumes the session to the samples asked for."""
    host = loopback(7)
    cfg = _sim_cell(tmp_path, host, min_samples=5)
    root = tmp_path / "sessions"
    argv = ["demo", "-c", str(cfg), "--samples", "7", "--until-sigma", "off", "--session-root", str(root),
            "--no-viz", "--no-frames"]

    rc, out, err = _ctrl_c(_cli(*argv), _holds(root, 5))
    assert rc == 130, err
    session_dir = next(root.iterdir())
    session = read_session(session_dir)
    n = len(session.observations)
    assert 5 <= n < 7 and f"samples: {n}" in out and "stopped by: interrupted" in out
    assert session.events[-1] == {**session.events[-1], "event": "interrupted", "n_samples": n}
    assert session.interrupted
    assert (session_dir / "result.yaml").stat().st_size > 0 and (session_dir / "report.html").stat().st_size > 0
    resume = [line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("continue this run:")]
    assert resume == [shlex.join(["handeye", *argv, "--resume", str(session_dir)])], out

    # verify of the interrupted calibration's result names the command that continues it first (offline against
    # its own samples, which it then refuses: a copy of the session is still the session it was calibrated on)
    copy = shutil.copytree(session_dir, tmp_path / "copy")
    assert main(["verify", "--result", str(copy), "--session", str(session_dir),
                 "--session-root", str(tmp_path / "verify")]) == 1
    out, err = capsys.readouterr()
    assert f"interrupted (Ctrl-C) after {n} samples; continue it with: handeye demo [-c <config>] --resume " \
           f"{copy}" in out and "was calibrated on" in err

    # ... and the printed command continues the session (same address: the simulator has gone with its run)
    rc = main(shlex.split(resume[0])[1:])
    out = capsys.readouterr().out
    assert rc == printed_status(out), out
    assert "samples: 7" in out and "stopped by: samples" in out
    session = read_session(session_dir)
    assert [o.index for o in session.observations] == list(range(7)) and not session.interrupted


def test_ctrl_c_to_the_process_group_stops_calibrate_with_too_few_samples(tmp_path, capsys, loopback):
    """Ctrl-C before there is anything to solve: exit 130, no result, the samples kept, the interruption
    recorded, the continue command printed; verify of that session says there is no result and how to go on."""
    cfg = _sim_cell(tmp_path, loopback(6))
    root = tmp_path / "sessions"
    argv = ["calibrate", "--yes-move", "-c", str(cfg), "--session-root", str(root), "--no-viz", "--no-frames"]
    rc, out, err = _ctrl_c(_cli(*argv), _holds(root, 2))
    assert rc == 130, err
    session_dir = next(root.iterdir())
    session = read_session(session_dir)
    n = len(session.observations)
    assert n >= 2 and "stopped by: interrupted" in out and f"no calibration: interrupted with {n} samples" in out
    assert session.events[-1]["event"] == "interrupted"
    assert f"continue this run:   {shlex.join(['handeye', *argv, '--resume', str(session_dir)])}" in out
    assert main(["verify", "--result", str(session_dir)]) == 1
    err = capsys.readouterr().err
    assert "no result to verify" in err and f"handeye demo [-c <config>] --resume {session_dir}" in err


def test_ctrl_c_to_the_process_group_ends_monitor_and_demo_monitor_normally(tmp_path, loopback):
    """monitor and demo --monitor (side by side, each on its own address): Ctrl-C is the normal end (summary,
    exit 0 without an alarm), not a lost controller: the simulator running the production program does not
    take the SIGINT."""
    runs = {}
    for slot, command in ((8, ["monitor"]), (9, ["demo", "--monitor"])):
        (tmp_path / command[-1]).mkdir()
        root = tmp_path / command[-1] / "sessions"
        runs[command[-1]] = (_cli(*command, "-c", str(_sim_cell(tmp_path / command[-1], loopback(slot))),
                                  "--session-root", str(root), "--no-viz", "--no-frames"), root)
    ended = {}
    ended["monitor"] = _ctrl_c(runs["monitor"][0], _holds(runs["monitor"][1], 1), while_running=lambda _: ended.update(
        {"--monitor": _ctrl_c(runs["--monitor"][0], _holds(runs["--monitor"][1], 1))}))
    for name, (rc, out, err) in ended.items():
        assert rc == 0, (name, err)
        assert " samples, " in out and "ALARM" not in out and "error" not in err, (name, out, err)
        session = read_session(next(runs[name][1].iterdir()))
        assert [e["event"] for e in session.events][-2:] == ["interrupted", "sample_set"], name


def test_ctrl_c_at_the_worst_moments_keeps_what_the_session_holds(sim_config, loopback, monkeypatch):
    """Deterministic Ctrl-Cs where a timed signal rarely lands: while the 3rd sample's line is synced (it is in
    the session, so it is in the final solve and the counts), then during that final solve (no result, the run
    ends as interrupted with every sample kept, the interruption recorded twice)."""
    from handeye.app import devices
    from handeye.app.session import SessionWriter

    add_sample, make_solve, solved = SessionWriter.add_sample, devices.make_solve, []

    def add_sample_then_ctrl_c(self, obs, **kw):
        kept = add_sample(self, obs, **kw)
        if self.n_samples == 3:
            raise KeyboardInterrupt
        return kept

    def solve_with_ctrl_c(*args, **kw):
        solve = make_solve(*args, **kw)

        def run(observations, *, final, **kw):
            if final:
                solved.append(len(observations))
                raise KeyboardInterrupt
            return solve(observations, final=final)
        return run

    monkeypatch.setattr(SessionWriter, "add_sample", add_sample_then_ctrl_c)
    monkeypatch.setattr(devices, "make_solve", solve_with_ctrl_c)
    cfg = sim_config(loopback(12), samples=8, min_samples=3, target_sigma_mm=0.0, target_sigma_deg=0.0)
    cfg = cfg.model_copy(update={"viz": cfg.viz.model_copy(update={"enabled": False}),
                                 "session": cfg.session.model_copy(update={"save_frames": False})})
    out = calibrate(cfg, progress=False)
    assert solved == [3] and out.report.n_samples == 3 and out.report.result is None
    assert out.report.stopped_by == "interrupted" and not (out.report.session / "result.yaml").exists()
    session = read_session(out.report.session)
    assert len(session.observations) == 3 and session.interrupted
    assert [(e["event"], e["n_samples"], e.get("stage")) for e in session.events] == [
        ("interrupted", 3, None), ("interrupted", 3, "final solve")]


def test_ctrl_c_to_the_process_group_stops_verify_before_it_has_poses_to_judge(sim_config, loopback, tmp_path):
    """Ctrl-C while verify moves to its first pose: the robot stopped, one line saying nothing was judged and
    where the session is, exit 130 (it was a ValueError traceback from the simulator's truth of no poses)."""
    out = demo(sim_config(loopback(14), samples=12), progress=False)
    cfg = _sim_cell(tmp_path, loopback(15))
    root = tmp_path / "verify"
    # Ctrl-C once the poses are planned and the robot starts moving (the session's file is there).
    rc, printed, err = _ctrl_c(_cli("verify", "-c", str(cfg), "--result", str(out.report.session / "result.yaml"),
                                    "--yes-move", "--no-viz", "--no-frames", "--session-root", str(root)),
                               lambda: bool(list(root.glob("*/samples.jsonl"))))
    session_dir = next(root.iterdir())
    n = len(read_session(session_dir).observations)
    assert rc == 130, err
    measured = f"{n} pose{'' if n == 1 else 's'} measured"
    assert n < 3 and printed.strip() == (f"interrupted: robot stopped; {measured}, fewer than the 3 a verification "
                                         f"needs: nothing judged (session {session_dir})")
    assert read_session(session_dir).events[-1]["event"] == "interrupted"
    assert not (session_dir / "verify.yaml").exists()


def test_ctrl_c_while_the_calibration_hook_runs_at_the_start_ends_monitor_normally(tmp_path, loopback):
    """Armed from a reference, monitor hands the calibration in use to its calibration hook before the first
    sample; a Ctrl-C while that hook still runs is the run's normal end (summary, exit 0, the session's end
    events), not 'interrupted' with exit 130 and the session left without its end; the hook is stopped."""
    from tests.app.test_production import reference_session

    ref = reference_session(tmp_path / "ref", 12, np.random.default_rng(3))
    started = tmp_path / "hook started"
    hook = f"sh -c 'touch \"{started}\"; exec sleep 60'"
    root = tmp_path / "sessions"
    rc, out, err = _ctrl_c(_cli("monitor", "-c", str(_sim_cell(tmp_path, loopback(13))), "--reference", ref,
                                "--calibration-hook", hook, "--session-root", str(root), "--no-viz", "--no-frames"),
                           started.exists)
    assert rc == 0, (out, err)
    assert "0 samples, 0 skipped" in out and "go on monitoring from this calibration in use: " in out, out
    session = read_session(next(root.iterdir()))
    assert [e["event"] for e in session.events][-2:] == ["interrupted", "sample_set"]
    assert (session.path / "calibration_in_use.yaml").exists()
    assert not _processes_naming("exec sleep 60") and not _processes_naming("sleep 60")


def test_an_interrupted_calibration_is_not_handed_over_as_complete(tmp_path, capsys, loopback, monkeypatch):
    """Ctrl-C after 6 of up to 12 samples, short of the 1-sigma target: the verdict warns that the run stopped
    early, with the samples taken, the target and the 1-sigma the progress line showed (and why it is larger
    than the error over the workspace), in the console, result.yaml and report.html (it was a PASS that said
    nothing of the interruption)."""
    from handeye.app.session import SessionWriter

    add_sample = SessionWriter.add_sample

    def add_sample_then_ctrl_c(self, obs, **kw):
        kept = add_sample(self, obs, **kw)
        if self.n_samples == 6:
            raise KeyboardInterrupt
        return kept

    monkeypatch.setattr(SessionWriter, "add_sample", add_sample_then_ctrl_c)
    root = tmp_path / "sessions"
    assert main(["demo", "-c", str(_sim_cell(tmp_path, loopback(16))), "--samples", "12", "--session-root",
                 str(root), "--no-viz", "--no-frames"]) == 130
    out = capsys.readouterr().out
    session_dir = next(root.iterdir())
    reason = ("the run was stopped early (Ctrl-C) after 6 samples, before its target (the camera transform's 1-sigma "
              "below 1 mm / 0.1 deg, at most 12 samples; it was ")
    assert "\nWARN: " in out and f"\n  - {reason}" in out, out
    assert "the progress line's 1-sigma: the camera's own position" in out and "continue it with --resume" in out
    verdict = yaml.safe_load((session_dir / "result.yaml").read_text())["verdict"]
    assert verdict["level"] == "warn" and verdict["reasons"][0].startswith(reason)
    assert html.escape(reason) in (session_dir / "report.html").read_text()


def _ctrl_c_at_sample(monkeypatch, n: int) -> None:
    """The run's first Ctrl-C, once its ``n``-th sample is in the session."""
    from handeye.app.session import SessionWriter

    add_sample = SessionWriter.add_sample

    def add_sample_then_ctrl_c(self, obs, **kw):
        kept = add_sample(self, obs, **kw)
        if self.n_samples == n:
            raise KeyboardInterrupt
        return kept

    monkeypatch.setattr(SessionWriter, "add_sample", add_sample_then_ctrl_c)



def _ctrl_c_in(monkeypatch, owner, name: str, presses: int = 1) -> None:
    """``presses`` real SIGINTs to this process as ``owner.name`` starts (as a terminal's Ctrl-C would land)."""
    original = getattr(owner, name)

    def pressed(*args, **kw):
        for _ in range(presses):
            signal.raise_signal(signal.SIGINT)
        return original(*args, **kw)

    monkeypatch.setattr(owner, name, pressed)


def test_a_second_ctrl_c_while_the_demo_writes_its_result_keeps_the_summary(tmp_path, capsys, loopback, monkeypatch):
    """Ctrl-C, then Ctrl-C again while the report is written: the report is still written and the summary
    printed, exit 130 (it was 'handeye demo: interrupted' and nothing else); a third press quits at once."""
    from handeye.app.runs import calibrate as runs_calibrate

    _ctrl_c_at_sample(monkeypatch, 5)
    _ctrl_c_in(monkeypatch, runs_calibrate, "write_run_report")
    root = tmp_path / "sessions"
    argv = ["demo", "-c", str(_sim_cell(tmp_path, loopback(17))), "--samples", "12", "--no-viz", "--no-frames"]
    rc = main([*argv, "--session-root", str(root / "second")])
    out, err = capsys.readouterr()
    session_dir = next((root / "second").iterdir())
    assert rc == 130 and "stopped by: interrupted" in out and "\nWARN: " in out and "continue this run:" in out, out
    assert "handeye demo: interrupted" not in err and (session_dir / "report.html").stat().st_size > 0
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler     # the command's end restored it

    # two more presses there: the third quits without the summary, as every press did before
    monkeypatch.undo()
    _ctrl_c_at_sample(monkeypatch, 5)
    _ctrl_c_in(monkeypatch, runs_calibrate, "write_run_report", presses=2)
    assert main([*argv, "--session-root", str(root / "third")]) == 130
    out, err = capsys.readouterr()
    assert "handeye demo: interrupted" in err and "session:" not in out


def test_a_second_ctrl_c_cuts_the_final_solve_short_and_the_samples_are_summarised(tmp_path, capsys, loopback,
                                                                                   monkeypatch):
    """Ctrl-C, then Ctrl-C during the final solve: the solve is cut short, and the samples are still
    summarised (no calibration, the command that continues the run), exit 130."""
    from handeye.app import devices

    make_solve = devices.make_solve

    def solve_pressed(*args, **kw):
        solve = make_solve(*args, **kw)

        def run(observations, *, final, **more):
            if final:
                signal.raise_signal(signal.SIGINT)
            return solve(observations, final=final, **more)
        return run

    _ctrl_c_at_sample(monkeypatch, 5)
    monkeypatch.setattr(devices, "make_solve", solve_pressed)
    root = tmp_path / "sessions"
    assert main(["demo", "-c", str(_sim_cell(tmp_path, loopback(18))), "--samples", "12", "--no-viz", "--no-frames",
                 "--session-root", str(root)]) == 130
    out, err = capsys.readouterr()
    assert "no calibration: interrupted with 5 samples" in out and "continue this run:" in out, out
    assert "handeye demo: interrupted" not in err
    events = read_session(next(root.iterdir())).events
    assert [(e["event"], e.get("stage")) for e in events] == [("interrupted", None), ("interrupted", "final solve")]


def test_a_second_ctrl_c_while_demo_monitor_ends_keeps_its_summary(tmp_path, capsys, loopback, monkeypatch):
    """demo --monitor: Ctrl-C (its normal end), then Ctrl-C while it writes its calibration in use: the summary
    is printed and the session ends with its events, exit 0 (it was exit 130 and one line)."""
    from handeye.app import calibration_in_use

    _ctrl_c_at_sample(monkeypatch, 3)
    _ctrl_c_in(monkeypatch, calibration_in_use.InUseFile, "end")
    root = tmp_path / "sessions"
    rc = main(["demo", "--monitor", "-c", str(_sim_cell(tmp_path, loopback(19))), "--no-viz", "--no-frames",
               "--session-root", str(root)])
    out, err = capsys.readouterr()
    assert rc == 0 and " samples, 0 skipped" in out and "NOT WATCHING" in out and "interrupted" not in err, (out, err)
    assert [e["event"] for e in read_session(next(root.iterdir())).events][-2:] == ["interrupted", "sample_set"]
