"""The simulated controller never outlives the process that launched it, whatever kills
that process and however many threads it has, and always frees its ports."""

import os
import signal
import subprocess
import sys
import time

import pytest

from bench.faults import PARENT, ports_free, process_alive
from handeye.mocks.ur_sim import launch
from tests.simulated_ur import free_host


def _wait_gone(pid: int, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while process_alive(pid):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


@pytest.mark.parametrize("slot", [60, 61])
def test_sim_exits_when_its_many_threaded_parent_is_killed(slot):
    host = free_host(slot)
    parent = subprocess.Popen([sys.executable, "-c", PARENT, host], stdout=subprocess.PIPE, text=True)
    try:
        sim_pid = int(parent.stdout.readline())
        time.sleep(0.5)
        assert process_alive(sim_pid), "the simulator must survive the exit of the thread that launched it"
        parent.kill()
        parent.wait()
        assert _wait_gone(sim_pid, 3.0), "orphaned simulator"
        assert ports_free(host)
    finally:
        parent.kill()


def test_sigterm_storm_stops_the_sim():
    sim = launch(free_host(62))
    for _ in range(100):  # one SIGTERM per exiting thread of a dying parent, and then some
        os.kill(sim.proc.pid, signal.SIGTERM)
    assert _wait_gone(sim.proc.pid, 3.0)
    assert sim.proc.wait(1.0) == 0
    assert ports_free(sim.host)
