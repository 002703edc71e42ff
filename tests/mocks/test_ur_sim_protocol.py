"""The simulated controller on the wire (raw sockets, no ur_rtde) and its
controller model in-process."""

import socket
import struct

import numpy as np
import pytest

from handeye.drivers.robot import ur_kinematics as kin
from handeye.mocks.ur_sim.controller import SimController
from handeye.mocks.ur_sim.motion import trapezoid_duration



@pytest.fixture(scope="module")
def sim(sim_factory):
    return sim_factory(4, controller="5.11")


class RTDE:
    def __init__(self, host):
        self.s = socket.create_connection((host, 30004), timeout=2.0)

    def request(self, kind: str, payload: bytes = b""):
        self.s.sendall(struct.pack(">HB", len(payload) + 3, ord(kind)) + payload)
        return self.recv()

    def recv(self):
        size, kind = struct.unpack(">HB", self._exact(3))
        return chr(kind), self._exact(size - 3)

    def _exact(self, n):
        buf = b""
        while len(buf) < n:
            buf += self.s.recv(n - len(buf))
        return buf


def test_rtde_handshake_recipes_and_data(sim):
    c = RTDE(sim.host)
    assert c.request("V", struct.pack(">H", 2)) == ("V", b"\x01")
    kind, body = c.request("v")
    assert kind == "v" and struct.unpack(">IIII", body)[:2] == (5, 11)
    kind, body = c.request("O", struct.pack(">d", 500.0) + b"timestamp,no_such_variable")
    assert body[1:].decode() == "DOUBLE,NOT_FOUND"
    kind, body = c.request("O", struct.pack(">d", 250.0) + b"timestamp,actual_q,safety_status_bits")
    assert body[1:].decode() == "DOUBLE,VECTOR6D,UINT32"
    kind, body = c.request("I", b"input_int_register_0,input_double_register_0")
    assert body[0] == 1 and body[1:].decode() == "INT32,DOUBLE"
    kind, body = c.request("I", b"input_int_register_0")
    assert body[0] == 2  # ids count up per connection
    other = RTDE(sim.host)
    other.request("V", struct.pack(">H", 2))
    kind, body = other.request("I", b"input_int_register_0,input_int_register_5")
    assert body[0] == 0 and body[1:].decode() == "IN_USE,INT32"
    assert c.request("S") == ("S", b"\x01")
    stamps = []
    for _ in range(5):
        kind, body = c.recv()
        assert kind == "U"
        ts, *q = struct.unpack(">Bd6dI", body)[1:]
        stamps.append(ts)
        np.testing.assert_allclose(q[:6], sim.state()["q"], atol=1e-9)
    # 250 Hz requested of a 500 Hz controller: every other 2 ms tick, never closer; more ticks
    # apart only when the simulator was starved and skipped packages (as a real controller does).
    ticks = np.diff(stamps) / 0.002
    np.testing.assert_allclose(ticks, np.round(ticks), atol=1e-6)
    assert np.round(ticks).min() == 2
    kind, body = c.request("P")
    while kind == "U":  # packages already in flight
        kind, body = c.recv()
    assert (kind, body) == ("P", b"\x01")
    c.s.close()
    other.s.close()


def test_dashboard_answers_and_script_upload_starts_the_protocol(sim):
    assert sim.command("PolyscopeVersion").startswith("URSoftware 5.11.")
    assert sim.command("get serial number").isdigit()
    assert sim.command("is in remote control") == "true"
    assert sim.command("frobnicate").startswith("could not understand")
    uploads = sim.state()["script_uploads"]
    with socket.create_connection((sim.host, 30003)) as s:
        s.sendall(b"def rtde_control():\n    global reg_offset_int = 0\n    textmsg(1)\nend\n")
    for _ in range(100):
        st = sim.state()
        if st["script_uploads"] > uploads:
            break
    assert st["script_running"] and st["commands"][-1]["name"] == "upload:rtde_control"
    assert sim.command("stop") == "Stopped" and not sim.state()["script_running"]


def _run(ctl, ticks):
    for _ in range(ticks):
        ctl.tick()


def test_controller_movej_follows_the_trapezoid_and_fk_matches_tcp():
    ctl = SimController("ur5e", "5.11", initial_q=np.zeros(6), tcp_offset=(0, 0, 0.2, 0, 0, 0))
    ctl.upload_script("def rtde_control():\nend\n")
    q1 = np.array([0.5, -0.3, 0.2, 0.0, 0.1, -0.4])
    ctl.write_inputs({"input_int_register_0": 1, "input_int_register_1": 0, "input_double_register_6": 1.0,
                      "input_double_register_7": 2.0, **{f"input_double_register_{i}": q1[i] for i in range(6)}})
    T = trapezoid_duration(0.5, 1.0, 2.0)  # leading joint 0.5 rad
    _run(ctl, round(T / ctl.dt) - 5)
    assert ctl.out_int[0] == 1 and ctl.motion is not None  # still moving, not done yet
    _run(ctl, 10)
    assert ctl.out_int[0] == 2 and ctl.motion is None  # done with command
    np.testing.assert_allclose(ctl.q, q1, atol=1e-12)
    snap = ctl.snapshot()
    np.testing.assert_allclose(kin.forward(ctl.q, "ur5e")[:3, 3] + kin.forward(ctl.q, "ur5e")[:3, 2] * 0.2,
                               snap["actual_TCP_pose"][:3], atol=1e-12)
    ctl.write_inputs({"input_int_register_0": 0})
    ctl.tick()
    assert ctl.out_int[0] == 1  # ready for the next command


def test_controller_refuses_movej_outside_joint_limits_with_a_protective_stop():
    ctl = SimController("ur10", "3.15")
    ctl.upload_script("def rtde_control():\nend\n")
    ctl.write_inputs({"input_int_register_0": 1, "input_double_register_0": 7.0, "input_double_register_6": 1.0,
                      "input_double_register_7": 1.0})
    ctl.tick()
    assert ctl.safety_mode == 3 and not ctl.script_running and ctl.motion is None
