"""Fixtures shared by every test folder."""

import contextlib
import importlib
import os
import pkgutil
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

import handeye.app.backends  # noqa: F401  every robot and camera backend registered by name, as in the app


def _import_the_project() -> None:
    """Import every module of the project (bench included) before any test.

    Hypothesis draws, beside random values, literals it finds in the project's modules loaded at that moment,
    so a derandomized test drew other examples in a pytest-xdist worker that had run other files first (the
    monitoring campaign's machine: other bumps from the 9th example on). With every module loaded, the draws
    are the same whatever ran before. A module that cannot be imported here (a vendor SDK missing) is missing
    for every test alike."""
    for name in ("handeye.app", "handeye.calib", "handeye.drivers", "handeye.mocks", "handeye.config", "bench"):
        package = importlib.import_module(name)
        for info in pkgutil.walk_packages(package.__path__, name + "."):
            if not info.name.endswith("__main__"):
                with contextlib.suppress(ImportError):
                    importlib.import_module(info.name)


_import_the_project()
from handeye.drivers.errors import DeviceError
from handeye.mocks.ur_sim import launch
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


def ros2_domain() -> int:
    """This test process's ROS 2 domain, 50..99: never a developer's default domain 0, seldom the same for two
    runs of the suite on one machine (from the pid), and never the same for two workers of one run (``make
    test`` runs two pytest-xdist workers, children of one pytest: its pid and the worker's number)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if worker.startswith("gw") and worker[2:].isdigit():
        return 50 + (os.getppid() % 10) * 5 + int(worker[2:]) % 5
    return 50 + os.getpid() % 50


#: The ROS 2 graph of the tests: this machine only, and a domain of this run's own (`ros2_domain`).
ROS2_ENV = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_DOMAIN_ID": str(ros2_domain())}


@pytest.fixture(scope="session")
def ros2_graph():
    """Real DDS on loopback with a test-only ``ROS_DOMAIN_ID`` (`ROS2_ENV`), for this process and the
    node processes it starts; fails with the install line when rclpy is missing (``make`` installs it)."""
    try:
        import rclpy  # noqa: F401
    except ImportError:
        pytest.fail("rclpy missing: run `make venv` (installs handeye[ros2])")
    saved = {k: os.environ.get(k) for k in (*ROS2_ENV, "ROS_STATIC_PEERS")}
    os.environ.update(ROS2_ENV)
    os.environ.pop("ROS_STATIC_PEERS", None)
    yield ROS2_ENV
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


class Ros2Publisher:
    """`tests.ros2_publisher` in a child process: ``send(cmd)`` runs one command and returns its answer."""

    def __init__(self, prefix: str):
        import subprocess

        self.prefix = prefix
        self.proc = subprocess.Popen([sys.executable, "-m", "tests.ros2_publisher", prefix], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True, bufsize=1)
        assert self.proc.stdout.readline().strip() == "ready", "test publisher did not start"

    def send(self, cmd: dict) -> dict:
        import json

        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()
        return json.loads(self.proc.stdout.readline())

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait()


@pytest.fixture(scope="module")
def ros2_publisher(ros2_graph):
    """``ros2_publisher(prefix)`` starts a `Ros2Publisher` (killed at module end). A node of this process stays
    open meanwhile: the process's DDS participant, and what it discovered, outlive each test's devices."""
    from handeye.drivers.ros2 import Ros2Node

    started = []

    def start(prefix: str) -> Ros2Publisher:
        started.append(Ros2Publisher(prefix))
        return started[-1]

    with Ros2Node("tests"):
        yield start
    for p in started:
        p.kill()


def pytest_sessionfinish(session, exitstatus):
    session.config.handeye_exitstatus = int(exitstatus)


def pytest_unconfigure(config):
    """pyrealsense2 and rclpy loaded in one process (the RealSense and the ROS 2 tests) crash in the C++ exit
    handlers after the run (`handeye.app.cli.leave_cleanly_past_two_dds`): leave with the tests' status instead."""
    from handeye.app.cli import leave_cleanly_past_two_dds

    leave_cleanly_past_two_dds(getattr(config, "handeye_exitstatus", 0))
