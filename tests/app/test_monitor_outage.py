"""monitor() rides out a dropped robot connection, an unplugged camera and a broker restart mid-run: the simulated
UR controller (handeye.mocks.ur_sim through the real ur_rtde client) runs its production program, the rendered camera
follows it, and the outages go to the session and to a real mosquitto broker. Eye-to-hand (``Y = T_base_cam``)."""

import threading
import time

import pytest

from handeye.app import devices
from handeye.app.config import Config
from handeye.app.runs import monitor as mon
from handeye.app.session import read_session

from handeye.drivers.errors import ConnectionLostError

from tests.app.test_mqtt_outage import Broker, subscriber

pytestmark = pytest.mark.slow

N_SAMPLES = 12
ROBOT_DROP_AFTER, BROKER_STOP_AFTER, CAMERA_UNPLUG_AFTER = 2, 5, 8    # samples before each outage
AWAY_S = 1.0


class UnplugAtNextCapture:
    """The camera is unplugged for ``seconds`` from its next read (the next standstill's capture): its reads and
    reopens fail as an unplugged USB camera's do until then."""

    def __init__(self, camera, seconds: float):
        self.until = None
        read, connect = camera.read, camera.connect

        def guarded(fn, starts: bool):
            def call():
                if self.until is None and starts:
                    self.until = time.monotonic() + seconds
                if self.until is not None and time.monotonic() < self.until:
                    raise ConnectionLostError("camera unplugged")
                return fn()
            return call

        camera.read, camera.connect = guarded(read, True), guarded(connect, False)


def test_monitor_goes_on_through_a_robot_drop_a_broker_restart_and_a_camera_unplug(sim_config, loopback, tmp_path,
                                                                                    monkeypatch):
    broker = Broker(tmp_path)
    broker.start()
    port = broker.port
    inbox = []
    sub = subscriber(port, inbox)     # a plant's persistent-session subscriber: it misses nothing over the restart
    data = sim_config(loopback(23)).model_dump()
    data["monitor"].update(still_s=0.2, poll_s=0.02, max_samples=N_SAMPLES, duration_s=60.0)
    data["reconnect"].update(initial_s=0.1, factor=2.0, max_s=0.4)
    data["mqtt"].update(enabled=True, port=port, topic_prefix="cell", connect_timeout_s=5.0, reconnect_min_s=1,
                        reconnect_max_s=1)
    data["viz"]["enabled"] = False
    cfg = Config.model_validate(data)

    # The devices monitor() opens, so that the test can pull their plugs (monitor wraps them in Reconnecting).
    opened = {}
    robot_of, camera_of = devices.open_robot, devices.open_camera

    def open_robot(cfg, *, read_only):
        opened["robot"] = robot_of(cfg, read_only=read_only)
        return opened["robot"]

    def open_camera(cfg, robot):
        opened["camera"] = camera_of(cfg, robot)
        return opened["camera"]

    pulled = {}
    restart = threading.Timer(AWAY_S, broker.start)

    def after_sample(bar, report):
        """Called by monitor() after every sample (its console display): the outages start here."""
        if report.n_samples == ROBOT_DROP_AFTER:
            pulled["robot"] = report.n_samples, time.time()
            opened["robot"].sim.drop(refuse_s=AWAY_S)
        elif report.n_samples == BROKER_STOP_AFTER:
            pulled["mqtt"] = report.n_samples, time.time()
            broker.stop()
            restart.start()
        elif report.n_samples == CAMERA_UNPLUG_AFTER:
            pulled["camera"] = report.n_samples, time.time()
            UnplugAtNextCapture(opened["camera"], AWAY_S)

    monkeypatch.setattr(mon.devices, "open_robot", open_robot)
    monkeypatch.setattr(mon.devices, "open_camera", open_camera)
    monkeypatch.setattr(mon, "show_monitor", after_sample)
    t0 = time.monotonic()
    try:
        report = mon.monitor(cfg, progress=False)
        elapsed = time.monotonic() - t0
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and not any(t == "cell/status" and m["state"] == "offline"
                                                      for t, m, _ in inbox):
            time.sleep(0.05)
    finally:
        if restart.is_alive():
            restart.join()
        sub.disconnect()
        sub.loop_stop()
        broker.stop()

    # The run went on and ended normally, with every sample it was asked for.
    assert report.n_samples == N_SAMPLES and report.elapsed_s < cfg.monitor.duration_s, report
    session = read_session(report.session)
    names = [e["event"] for e in session.events]
    assert names[-1] == "sample_set" and not {"device_error", "gave_up", "interrupted"} & set(names), names
    # None lost: every sample the run took is in the session, whole, and every capture is a sample or a skip.
    assert len(session.observations) == N_SAMPLES and len(session.skipped) == report.n_skipped
    assert all(o.point_cam is not None and o.joints is not None for o in session.observations)
    assert sorted([o.index for o in session.observations] + [s["index"] for s in session.skipped]) == list(
        range(N_SAMPLES + report.n_skipped))
    # The captures that may be skipped: the first after a device's outage, when the robot left the standstill
    # during it (the check that keeps a frame and a pose of different places apart); at most one per outage.
    starts = sorted(e["t"] for e in session.events if e["event"] == "outage_start" and e.get("device") in (
        "robot", "camera"))
    assert len(session.skipped) <= len(starts) and all(s["reason"] == "robot moved during the capture"
                                                     for s in session.skipped), session.skipped
    for s in session.skipped:
        away = max((t for t in starts if t < s["t"]), default=None)
        assert away is not None and not any(away < o.t < s["t"] for o in session.observations), (s, starts)

    # Each outage recorded with its reconnect: its start after the sample that pulled the plug, its end at least
    # AWAY_S later and within a capped backoff wait (max_s) of it (plus the RTDE client's reconnect).
    for device in ("robot", "camera"):
        events = [e for e in session.events if e.get("device") == device]
        kinds = [e["event"] for e in events]
        assert kinds[0] == "outage_start" and kinds[-1] == "outage_end", (device, kinds)
        assert set(kinds[1:-1]) <= {"reconnect_failed"} and kinds.count("outage_start") == 1, (device, kinds)
        after, pulled_t = pulled[device]
        assert events[0]["t"] >= pulled_t
        assert AWAY_S - 0.1 < events[-1]["outage_s"] < AWAY_S + 3.0, (device, events[-1])
        # Sampled up to the outage, and on once the device was back.
        assert sum(o.t < events[0]["t"] for o in session.observations) == after
        assert sum(o.t > events[-1]["t"] for o in session.observations) == N_SAMPLES - after, device
        assert all(s["t"] > events[0]["t"] for s in session.skipped if device == "camera")
    assert "lost" in next(e for e in session.events if e.get("device") == "robot")["error"]
    assert "camera unplugged" in next(e for e in session.events if e.get("device") == "camera")["error"]
    # The broker's restart is an outage too (paho reconnects; the session has its start and end).
    broker_events = [e for e in session.events if e.get("device") == "mqtt"]
    assert [e["event"] for e in broker_events] == ["outage_start", "outage_end"], broker_events
    assert broker_events[0]["t"] >= pulled["mqtt"][1] and AWAY_S < broker_events[1]["outage_s"] < AWAY_S + 3.0

    # And over MQTT: each outage's start and end (the failed attempts only in the session), the broker's published
    # once it was back, then offline.
    published = list(dict.fromkeys((m["device"], m["event"]) for t, m, _ in inbox if t == "cell/outage"))
    for device in ("robot", "mqtt", "camera"):
        assert [e for d, e in published if d == device] == ["outage_start", "outage_end"], published
    assert published.index(("robot", "outage_end")) < published.index(("camera", "outage_start"))
    ends = {m["device"]: m for t, m, _ in inbox if t == "cell/outage" and m["event"] == "outage_end"}
    for device in ("robot", "camera", "mqtt"):
        recorded = [e for e in session.events if e.get("device") == device][-1]
        assert ends[device]["outage_s"] == pytest.approx(recorded["outage_s"])
        assert ends[device]["session"] == str(report.session)
    assert elapsed < 45.0, elapsed
