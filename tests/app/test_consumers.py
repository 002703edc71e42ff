"""The robot program as a consumer of the calibration in use, through the real ur_rtde client and the simulated
controller's production program (it takes the version at its stops, as docs/monitor-service.md's URScript does):
a version given and acknowledged, one waiting for approval, a controller that drops every connection, a program
that keeps an old version."""

import time

import numpy as np
import pytest

from handeye.app.calibration_versions import Approvals, History, write_approval
from handeye.app.consumers import CalibrationLoop, RobotProgram
from handeye.calib import transforms as tf
from tests.simulated_ur import START_Q

pytestmark = pytest.mark.slow


def _camera(mm: float, deg: float) -> np.ndarray:
    base = tf.from_rotvec_translation([2.0, -0.4, 0.3], [0.7, -0.6, 0.85])
    return tf.from_rotvec_translation([0.0, np.deg2rad(deg), 0.0], [mm * 1e-3, 0.0, 0.0]) @ base


def _program(sim) -> None:
    q0 = list(START_Q)
    q1 = list(START_Q)
    q1[0] += 0.3
    sim.start_program({"waypoints": [{"q": q0, "pause_s": 0.1}, {"q": q1, "pause_s": 0.1}], "speed": 2.0,
                       "acceleration": 8.0, "takes_calibration": True})


def _poll_until(loop: CalibrationLoop, what, timeout: float = 15.0) -> None:
    deadline = time.monotonic() + timeout
    while not what():
        assert time.monotonic() < deadline, (loop.in_use_by(), [(x.name, x.error) for x in loop.links])
        loop.poll(time.time())
        time.sleep(0.1)


@pytest.fixture
def cell(sim_factory, tmp_path):
    sim = sim_factory(3)
    _program(sim)
    events = []
    loop = CalibrationLoop.of(History("approve"), [RobotProgram(sim.host)], run=tmp_path,
                              approvals=Approvals([tmp_path]), ack_timeout_s=1.0,
                              on_event=lambda t, kind, fields: events.append((kind, fields)))
    yield sim, loop, events
    loop.close()


def test_the_program_takes_each_version_put_in_use_and_an_approval_closes_the_move(cell, tmp_path):
    sim, loop, events = cell
    h = loop.history
    loop.applied(h.first(_camera(0, 0), 0.4, time.time(), "armed"), time.time())
    _poll_until(loop, lambda: loop.in_use_by() == {"robot program": 1})
    program = sim.state()["program"]
    assert program["calibration_version"] == 1
    # The transform arrives as sent: translation to the um, rotation to the float.
    np.testing.assert_allclose(program["calibration"][:3], tf.to_ur_pose(_camera(0, 0))[:3], atol=1e-6)
    np.testing.assert_allclose(program["calibration"][3:], tf.to_ur_pose(_camera(0, 0))[3:], atol=1e-12)
    assert loop.status(time.time()) is None
    # A move re-learnt: version 2 waits for a person; the program keeps version 1 meanwhile.
    loop.last_move = {"time": "02:09", "sample": 29, "mm": 10.4}
    h.propose(_camera(10, 0.5), 0.5, time.time(), "re-learnt after the move at sample 29", {})
    assert h.settle(_camera(10, 0.5), 0.4, time.time()) is None
    level, sentence = loop.status(time.time())
    assert level == "moved" and "camera moved 10.4 mm at 02:09 (sample 29)" in sentence
    assert f"waiting for approval: handeye approve {tmp_path}" in sentence
    assert "the robot program still uses version 1" in sentence
    time.sleep(0.6)
    loop.poll(time.time())
    assert sim.state()["program"]["calibration_version"] == 1
    write_approval(tmp_path, 2, "ann@cell7", time.time())
    _poll_until(loop, lambda: loop.in_use_by() == {"robot program": 2})
    assert h.in_use.number == 2 and h.in_use.applied_by == "approved by ann@cell7"
    np.testing.assert_allclose(sim.state()["program"]["calibration"][:3], tf.to_ur_pose(_camera(10, 0.5))[:3],
                               atol=1e-6)
    assert loop.status(time.time()) is None
    kinds = [k for k, _ in events]
    assert kinds.index("calibration_approved") < kinds.index("calibration_version_in_use", kinds.index(
        "calibration_approved")) < len(kinds) - 1 and kinds[-1] == "calibration_taken"


def test_a_controller_that_drops_the_connection_is_a_warning_then_given_the_version_again(cell):
    sim, loop, events = cell
    h = loop.history
    loop.applied(h.first(_camera(0, 0), 0.4, time.time(), "armed"), time.time())
    _poll_until(loop, lambda: loop.in_use_by() == {"robot program": 1})
    sim.command("sim drop 2")
    time.sleep(0.3)
    loop.polled_t = -np.inf
    loop.poll(time.time())
    assert loop.links[0].error is not None
    level, sentence = loop.status(time.time())
    assert level == "warn" and "robot program" in sentence and "out of reach" in sentence
    # Re-learnt and put in use while the controller is away (apply auto): given once it is back.
    h.policy = "auto"
    h.propose(_camera(5, 0.2), 0.5, time.time(), "re-learnt after the move at sample 40", {})
    loop.applied(h.settle(_camera(5, 0.2), 0.4, time.time()), time.time())
    assert loop.status(time.time())[0] == "moved"
    _poll_until(loop, lambda: loop.in_use_by() == {"robot program": 2}, timeout=20.0)
    assert loop.links[0].error is None and loop.status(time.time()) is None
    assert [k for k, _ in events].count("consumer_unreachable") == 1      # one event per outage, not per poll


def test_a_program_that_keeps_an_old_version_keeps_the_cell_moved_until_it_takes_the_new_one(cell):
    sim, loop, _ = cell
    h = loop.history
    h.policy = "auto"
    loop.applied(h.first(_camera(0, 0), 0.4, time.time(), "armed"), time.time())
    _poll_until(loop, lambda: loop.in_use_by() == {"robot program": 1})
    sim.stop_program()          # the program stops reading the registers: it keeps version 1
    time.sleep(0.5)
    h.propose(_camera(10, 0.5), 0.5, time.time(), "re-learnt after the move at sample 29", {})
    loop.applied(h.settle(_camera(10, 0.5), 0.4, time.time()), time.time())
    deadline = time.time() + 2.0
    while time.time() < deadline:
        loop.poll(time.time())
        time.sleep(0.1)
    level, sentence = loop.status(time.time())
    assert level == "moved" and "re-learnt as version 2" in sentence and "the robot program still uses version 1" \
        in sentence
    _program(sim)
    _poll_until(loop, lambda: loop.in_use_by() == {"robot program": 2})
    assert loop.status(time.time()) is None
