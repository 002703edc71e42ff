"""Fixtures shared by every test folder."""

import contextlib
import os
import signal
import sys

import pytest
from hypothesis import settings

# Property tests are seeded like every other test (the same examples on every run,
# so CI cannot turn red by chance) and keep no example database in the checkout.
settings.register_profile("handeye", derandomize=True, database=None)
settings.load_profile("handeye")

# A suite started in the background (`make test &`, nohup) has SIGINT ignored, and an ignored signal
# survives exec: the Ctrl-C tests' children would never see their SIGINT. A handled one is reset to
# the default on exec, so the children get Python's Ctrl-C behaviour, as from a terminal.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

import app.backends  # noqa: F401  every robot and camera backend registered by name, as in the app
from drivers.errors import DeviceError
from mocks.ur_sim import launch
from tests.simulated_ur import SIM_TCP, START_Q, free_host, process_net


@pytest.fixture
def loopback():
    """``loopback(n)`` -> this process's address ``n`` for a simulated controller (n < 100;
    the robot tests' own simulators use the lower slots, so these start at .100)."""
    return lambda n: f"{process_net()}.{100 + n}"


@pytest.fixture(scope="module")
def sim_factory():
    """Launch simulated UR10 controllers for this module (``make(slot, controller)``); stopped at module end."""
    sims = []

    def make(slot, controller="5.11"):
        for attempt in range(5):
            try:
                sim = launch(free_host(slot + 10 * attempt), model="ur10", controller=controller,
                             initial_q=START_Q, tcp_offset=SIM_TCP)
                break
            except DeviceError as exc:
                if "in use" not in str(exc) or attempt == 4:
                    raise
        sims.append(sim)
        return sim

    yield make
    for sim in sims:
        sim.stop()


class OutsideReads:
    """Audit hook on ``open``, installed once: while armed by ``watch(data)``, records files opened
    outside ``data`` but beside it (its parent's tree: the canaries tests plant) or in /etc."""

    def __init__(self):
        self.data = self.area = None
        self.opened: list[str] = []
        sys.addaudithook(self._hook)

    def _hook(self, event, args):
        if event != "open" or self.data is None or not isinstance(args[0], (str, bytes, os.PathLike)):
            return
        p = os.path.realpath(os.fsdecode(args[0]))
        if not (p == self.data or p.startswith(self.data + os.sep)) and \
                (p.startswith(self.area + os.sep) or p.startswith("/etc/")):
            self.opened.append(p)

    @contextlib.contextmanager
    def watch(self, data):
        """Arm for the ``with`` body; on leaving it, fail the test if anything outside ``data`` was opened."""
        self.data = os.path.realpath(data)
        self.area, self.opened = os.path.dirname(self.data), []
        try:
            yield self
        finally:
            self.data = None
        assert not self.opened, f"read outside the data directory {data}: {self.opened}"


@pytest.fixture(scope="session")
def outside_reads() -> OutsideReads:
    """An `OutsideReads` watcher: ``with outside_reads.watch(data_dir): load(...)``."""
    return OutsideReads()
