"""Shared fixtures for the app tests that run the simulated cell.

Each test gets its own loopback address (the `loopback` fixture) for the UR simulator, so
tests never collide on the RTDE/dashboard ports.
"""

import shutil
import subprocess
import time
from pathlib import Path

import pytest

from handeye.app.config import Config, load_config

# The simulated robot of the tests moves about 3x faster than the shipped config's (a run's time is mostly
# motion: the demo takes 17 s instead of 36 s). Nothing a test asserts depends on the speed; the shipped
# values run in `make demo`, the docs' commands and the tests that start the CLI on config/sim.toml.
FAST_CELL = {"robot": {"speed": 2.5, "acceleration": 15.0, "settle_time": 0.05},
             "calibrate": {"settle_s": 0.05},
             "production": {"speed": 3.0, "acceleration": 20.0}}


def fast_cell(data: dict) -> dict:
    """``data`` (a config's model_dump) with the tests' fast simulated robot (`FAST_CELL`)."""
    for section, values in FAST_CELL.items():
        data[section].update(values)
    return data


@pytest.fixture
def sim_config(tmp_path):
    """Build a config for the simulated cell on a given host, writing sessions under tmp_path."""

    def make(host: str, base: Config | None = None, **calibrate) -> Config:
        cfg = base or load_config(None)
        data = fast_cell(cfg.model_dump())
        data["robot"]["host"] = host
        data["calibrate"].update(calibrate)
        data["session"]["root"] = str(tmp_path / "sessions")
        return Config.model_validate(data)

    return make


MOSQUITTO = "/usr/sbin/mosquitto"


@pytest.fixture
def mosquitto(tmp_path):
    """A real mosquitto broker on 127.0.0.1 at a free port (``make sysdeps`` installs it).

    ``mosquitto(extra_lines)`` starts one with extra config lines (e.g. a password file)
    and returns its port; every broker is stopped after the test.
    """
    import os
    import socket
    import subprocess
    import time

    if not os.access(MOSQUITTO, os.X_OK):
        pytest.fail(f"{MOSQUITTO} missing: run `make sysdeps` (installs the Debian package mosquitto)")
    procs = []

    def start(extra: str = "allow_anonymous true") -> int:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        conf = tmp_path / f"mosquitto-{port}.conf"
        # "user root": as root, mosquitto would drop to user mosquitto, who cannot read pytest's tmp files.
        conf.write_text(f"listener {port} 127.0.0.1\n{extra}\npersistence false\nuser root\n")
        proc = subprocess.Popen([MOSQUITTO, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        procs.append(proc)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if proc.poll() is not None:
                pytest.fail(f"mosquitto exited: {proc.stderr.read().decode()[-300:]}")
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                return port
            except OSError:
                time.sleep(0.05)
        pytest.fail("mosquitto did not listen within 10 s")

    yield start
    for proc in procs:
        proc.terminate()
        proc.wait(5)


@pytest.fixture
def mqtt_inbox():
    """``mqtt_inbox(port, topic="#", **tls)`` subscribes with paho and returns a list that fills with
    ``(topic, json payload, retain)`` as messages arrive; clients are stopped after the test."""
    import json
    import threading

    import paho.mqtt.client as mqtt

    clients = []

    def subscribe(port: int, topic: str = "#", *, username=None, password=None, ca_file=None) -> list:
        inbox, ready = [], threading.Event()
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"test-sub-{port}-{len(clients)}")
        if username:
            c.username_pw_set(username, password)
        if ca_file:
            c.tls_set(ca_certs=ca_file)
        c.on_connect = lambda cl, u, f, rc, p: cl.subscribe(topic, qos=1)
        c.on_subscribe = lambda *a: ready.set()
        c.on_message = lambda cl, u, m: inbox.append((m.topic, json.loads(m.payload), bool(m.retain)))
        c.connect("127.0.0.1" if not ca_file else "localhost", port)
        c.loop_start()
        clients.append(c)
        assert ready.wait(10), "subscription not acknowledged"
        return inbox

    yield subscribe
    for c in clients:
        c.disconnect()
        c.loop_stop()


@pytest.fixture
def engine_update():
    """A `handeye.calib.monitor.MonitorUpdate` as the engine hands it to the publisher: ``(index, T, cov, alarm)``."""
    import numpy as np

    from handeye.calib.monitor import MonitorUpdate

    def make(index, T, cov, alarm: bool):
        kind = "moved" if alarm else ""
        return MonitorUpdate(index, float(index), "armed", kind, kind, T, cov, np.zeros(3), 1.0, 0.4,
                             123.4 if alarm else 0.0, 1.5, 0.1, 0.5, 0.01, 2.0, 3.0, 0.8, "")

    return make
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"


@pytest.fixture
def render_page(tmp_path):
    """``render_page(html_path) -> (dom, console)``: the page as headless Chromium renders it (its DOM after
    loading) and every console message it logged (errors, warnings, uncaught exceptions). Chromium comes from
    the system packages (``make sysdeps``); without it the test fails, it does not skip."""
    assert Path(CHROMIUM).exists(), "chromium is missing: run `make sysdeps` (Debian package chromium)"

    def render(page: Path):
        # No network for the page: any fetch it tried would fail and be logged on the console.
        argv = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--enable-logging=stderr", "--v=0",
                f"--user-data-dir={tmp_path / 'chromium-profile'}", "--proxy-server=127.0.0.1:9",
                "--virtual-time-budget=3000", "--dump-dom", Path(page).resolve().as_uri()]
        done = subprocess.run(argv, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr[-2000:]
        console = [line for line in done.stderr.splitlines() if ":CONSOLE" in line]
        return done.stdout, console

    return render


PDFTOTEXT = shutil.which("pdftotext") or "/usr/bin/pdftotext"


@pytest.fixture
def render_pdf(tmp_path):
    """``render_pdf(html_path) -> (pdf_path, first_page_text)``: the page printed to PDF by headless Chromium (the
    print CSS, Letter paper: the narrower of Letter and A4) and the text of its first page in reading order
    (``pdftotext``, Debian package poppler-utils, from ``make sysdeps``; without it the test fails)."""
    assert Path(CHROMIUM).exists(), "chromium is missing: run `make sysdeps` (Debian package chromium)"
    assert Path(PDFTOTEXT).exists(), "pdftotext is missing: run `make sysdeps` (Debian package poppler-utils)"

    def render(page: Path):
        pdf = tmp_path / (Path(page).parent.name + ".pdf")
        profile = tmp_path / f"chromium-pdf-{pdf.stem}"
        argv = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={profile}",
                "--proxy-server=127.0.0.1:9", "--no-pdf-header-footer", f"--print-to-pdf={pdf}",
                Path(page).resolve().as_uri()]
        done = subprocess.run(argv, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0 and pdf.exists() and pdf.read_bytes().startswith(b"%PDF"), done.stderr[-2000:]
        text = subprocess.run([PDFTOTEXT, "-f", "1", "-l", "1", str(pdf), "-"], capture_output=True, text=True,
                              timeout=60, check=True).stdout
        return pdf, text

    return render


@pytest.fixture
def poll_until():
    """``poll_until(loop, what, timeout=15.0)``: poll a `handeye.app.consumers.CalibrationLoop` at once (not after
    its poll period) until ``what()`` holds; past the timeout the test fails with who uses which version."""
    def poll(loop, what, timeout=15.0):
        deadline = time.monotonic() + timeout
        while not what():
            assert time.monotonic() < deadline, loop.in_use_by()
            loop.polled_t = float("-inf")
            loop.poll(time.time())
            time.sleep(0.05)
    return poll
