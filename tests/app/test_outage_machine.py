"""`handeye.app.outage.Reconnecting` driven through arbitrary sequences (hypothesis state machine): devices that go down
for any number of calls, refuse any number of reopens, answer "no pose at that time", a stop during an outage,
and a limit on an outage's length. The clock and the waits are the test's, so a sequence runs in microseconds.

Invariants after every call: it returned, or raised the device's `PoseTimeError` or an `OutageError`, never
anything else and never a hang; no outage is left open; each outage's events are ``outage_start``, then only
``reconnect_failed``, then ``outage_end`` (or nothing more when it gave up); the waits follow the configured
backoff; ``outages`` counts the ended ones."""

import threading

import pytest
from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

from handeye.app.errors import OutageError
from handeye.app.outage import ReconnectConfig, Reconnecting
from handeye.drivers.errors import ConnectionLostError, PoseTimeError


class Device:
    """A device whose next ``failures`` operations fail (the stream dropped), whose next ``refusals`` reopens
    fail, and whose next answered operation may be "no pose at that time"."""

    def __init__(self):
        self.failures = self.refusals = 0
        self.pose_time = False

    def op(self) -> str:
        if self.failures:
            self.failures -= 1
            raise ConnectionLostError("stream dropped")
        if self.pose_time:
            self.pose_time = False
            raise PoseTimeError("pose_at: before the robot state buffer", ahead=False)
        return "answer"

    def reconnect(self) -> None:
        if self.refusals:
            self.refusals -= 1
            raise ConnectionLostError("connection refused")


class ReconnectingMachine(RuleBasedStateMachine):
    @initialize(initial=st.floats(0.01, 2.0), factor=st.floats(1.0, 3.0), max_s=st.floats(0.01, 30.0),
                max_outage=st.sampled_from([0.0, 0.5, 5.0, 60.0]))
    def start(self, initial, factor, max_s, max_outage):
        self.config = ReconnectConfig(initial_s=initial, factor=factor, max_s=max_s, max_outage_s=max_outage)
        self.now, self.waits, self.events = 0.0, [], []
        self.stop = threading.Event()
        self.device = Device()

        def wait(seconds: float) -> bool:
            self.waits.append(seconds)
            self.now += seconds
            return self.stop.is_set()

        self.rc = Reconnecting("robot", self.device, self.config, on_event=self.events.append, stop=self.stop,
                               clock=lambda: self.now, wait=wait)
        self.ended = 0

    @rule(failures=st.integers(0, 12), refusals=st.integers(0, 12))
    def go_down(self, failures, refusals):
        self.device.failures, self.device.refusals = failures, refusals

    @rule()
    def ask_outside_the_buffer(self):
        self.device.pose_time = True

    @rule()
    def stop_the_run(self):
        self.stop.set()

    @rule()
    def call(self):
        first_event, first_wait = len(self.events), len(self.waits)
        was_down, t0 = self.device.failures > 0, self.now
        try:
            outcome = self.rc.call(lambda d: d.op())
        except PoseTimeError:
            outcome = "pose time"
        except OutageError as e:
            outcome = e
        events = self.events[first_event:]
        kinds = [e.event for e in events]
        waits = self.waits[first_wait:]
        if not was_down:
            # A device that answers (or says "no pose at that time") has no outage.
            assert kinds == [] and outcome in ("answer", "pose time"), (kinds, outcome)
            return
        assert kinds[0] == "outage_start" and set(kinds[1:-1]) <= {"reconnect_failed"}, kinds
        if isinstance(outcome, OutageError):
            assert "outage_end" not in kinds
            assert self.stop.is_set() or (self.config.max_outage_s and "reconnect.max_outage_s" in str(outcome))
        else:
            assert kinds[-1] == "outage_end" and kinds.count("outage_end") == 1, kinds
            self.ended += 1
            if self.config.max_outage_s:
                assert self.now - t0 <= self.config.max_outage_s + 1e-9
        # The waits are the configured backoff from its start (the first reopen is immediate: no wait).
        backoff = self.config.delays()
        expected = [next(backoff) for _ in range(len(waits) + 1)][1:]
        assert waits == pytest.approx(expected[:len(waits)]), (waits, expected)
        # A stopped run gives up an outage at once: no wait begins after the stop.
        assert not self.stop.is_set() or isinstance(outcome, OutageError)

    @invariant()
    def no_outage_left_open(self):
        if hasattr(self, "rc"):
            assert not self.rc.in_outage and self.rc.outages == self.ended


ReconnectingMachine.TestCase.settings = settings(max_examples=150, stateful_step_count=30, deadline=None,
                                                 derandomize=True, database=None)
test_reconnecting_rides_out_any_sequence = ReconnectingMachine.TestCase
