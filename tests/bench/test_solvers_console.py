"""`python -m bench` console: stage lines as it goes, each table printed as soon as it is ready, and the
finished sections kept (printed and written) on Ctrl-C."""

import signal
import subprocess
import sys
import time


def test_bench_prints_progressively_and_keeps_partial_results_on_ctrl_c(tmp_path):
    out = tmp_path / "bench"
    # --quick, not --tiny: its later sections take most of a minute, so a loaded machine cannot finish
    # them between the first table and the signal (--tiny could: the run then ended 0).
    proc = subprocess.Popen([sys.executable, "-m", "bench.solvers", "--quick", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # Wait until the first table has been printed (unbuffered through a pipe), then press Ctrl-C.
    first = []
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        first.append(line)
        if line.startswith("| YKronT'"):
            break
    assert any(ln.startswith("## Experiment 1") for ln in first), first
    proc.send_signal(signal.SIGINT)
    rest, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "bench.solvers [1/7] experiment 1" in err and "interrupted; partial results in" in err
    report = (out / "solvers.md").read_text()
    assert "## Experiment 1" in report and "**Interrupted** during" in report
    assert "## Timing" not in report
    assert (out / "solvers_samples.png").exists()
