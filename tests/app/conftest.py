"""Shared fixtures for the app tests that run the simulated cell.

Each test gets its own loopback address (the `loopback` fixture) for the UR simulator, so
tests never collide on the RTDE/dashboard ports.
"""

import pytest

from app.config import Config, load_config


@pytest.fixture
def sim_config(tmp_path):
    """Build a config for the simulated cell on a given host, writing sessions under tmp_path."""

    def make(host: str, base: Config | None = None, **calibrate) -> Config:
        cfg = base or load_config(None)
        data = cfg.model_dump()
        data["robot"]["host"] = host
        data["calibrate"].update(calibrate)
        data["session"]["root"] = str(tmp_path / "sessions")
        return Config.model_validate(data)

    return make
