"""Shared fixtures for the app tests that run the simulated cell.

Each test gets its own loopback address (the `loopback` fixture) for the UR simulator, so
tests never collide on the RTDE/dashboard ports.
"""

import dataclasses

import pytest

from app.config import Config, load_config


@pytest.fixture
def sim_config(tmp_path):
    """Build a config for the simulated cell on a given host, writing sessions under tmp_path."""

    def make(host: str, base: Config | None = None, **calibrate) -> Config:
        cfg = base or load_config(None)
        robot = {**cfg.robot, "host": host}
        return dataclasses.replace(
            cfg,
            robot=robot,
            calibrate=dataclasses.replace(cfg.calibrate, **calibrate),
            session=dataclasses.replace(cfg.session, root=str(tmp_path / "sessions")),
        )

    return make
