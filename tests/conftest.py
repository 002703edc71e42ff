"""Fixtures shared by every test folder."""

import os

import pytest
from hypothesis import settings

# Property tests are seeded like every other test (the same examples on every run,
# so CI cannot turn red by chance) and keep no example database in the checkout.
settings.register_profile("handeye", derandomize=True, database=None)
settings.load_profile("handeye")

import app.backends  # noqa: F401  every robot and camera backend registered by name, as in the app


def process_net() -> str:
    """A loopback /24 of this test process (``127.a.b``), derived from its pid, so that
    concurrent runs of the suite (CI, several checkouts) never share simulator ports."""
    pid = os.getpid()
    return f"127.{(pid >> 8) % 250 + 1}.{pid % 256}"


@pytest.fixture
def loopback():
    """``loopback(n)`` -> this process's address ``n`` for a simulated controller (n < 100;
    the robot tests' own simulators use the lower slots, so these start at .100)."""
    return lambda n: f"{process_net()}.{100 + n}"
