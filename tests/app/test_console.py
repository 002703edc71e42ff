"""Off a terminal (journal, CI, a pipe) a run prints lines, not progress-bar redraws."""

import os
import subprocess
import sys

import pytest

from handeye.app.progress import LineProgress, progress_bar, show_monitor


def test_line_progress_prints_a_status_line_every_n_samples_and_a_last_one():
    lines = []
    p = LineProgress(3, desc="samples", write=lines.append)
    for i in range(7):
        p.update(1)
        p.set_postfix_str(f"armed after {7 - i - 1}")
    p.close()
    # Each line carries the state set after its sample (the runs update, then set the state).
    assert lines == ["samples: 3 | armed after 4", "samples: 6 | armed after 1", "samples: 7 | armed after 0"]
    p.close()
    assert len(lines) == 3  # nothing new to tell


def test_progress_bar_off_a_terminal_is_line_mode_and_carries_the_monitor_state(capsys):
    class Report:
        samples_until_armed, estimate_sigma, drift, alarms = 0, (0.001, 0.0008), (1.5, 0.02), [1]

    with progress_bar(status_every=2) as bar:  # pytest's captured stdout is no terminal
        assert isinstance(bar, LineProgress)
        for _ in range(4):
            bar.update(1)
            show_monitor(bar, Report())
    out, err = capsys.readouterr()
    state = "testing, 1σ 0.80 mm 0.057°, drift 1.5 mm 0.02°, ALARMS 1"
    assert out.splitlines() == [f"samples: {n} | {state}" for n in (2, 4)]
    assert "\r" not in out + err
    with progress_bar(mode="lines", enabled=False) as bar:
        bar.update(1)
    assert capsys.readouterr() == ("", "")


@pytest.mark.slow
def test_monitor_to_a_pipe_writes_lines_of_bounded_size(tmp_path, loopback):
    text = open("config/sim.toml").read().replace('host = "127.0.0.2"', f'host = "{loopback(45)}"')
    assert "\nstatus_every = 20 " in text
    config = tmp_path / "cell.toml"
    config.write_text(text.replace("\nstatus_every = 20 ", "\nstatus_every = 5 "))
    env = {**os.environ, "PYTHONPATH": os.getcwd()}
    done = subprocess.run([sys.executable, "-m", "handeye.app.cli", "monitor", "-c", str(config), "--max-samples", "12",
                           "--no-frames", "--no-viz", "--session-root", str(tmp_path / "s")],
                          capture_output=True, text=True, timeout=240, env=env)
    assert done.returncode == 0, done.stdout + done.stderr
    both = done.stdout + done.stderr
    assert "\r" not in both
    status = [line for line in done.stdout.splitlines() if line.startswith("samples: ") and " | " in line]
    assert [s.split(" | ")[0] for s in status] == ["samples: 5", "samples: 10", "samples: 12"], done.stdout
    # One status line per 5 samples and one line per event: a tqdm bar wrote ~270 bytes of redraws per sample.
    assert len(both.encode()) < 3000, len(both.encode())
