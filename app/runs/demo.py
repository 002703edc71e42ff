"""The demo runs: calibrate, or monitor, the simulated cell (UR simulator and rendered camera, truth known)."""

from __future__ import annotations

from pathlib import Path

from handeye.app import devices
from handeye.app.config import Config
from handeye.app.errors import ConfigError, SessionError
from handeye.app.production import Bump
from handeye.app.runs.calibrate import CalibrationOutput, calibrate
from handeye.app.runs.monitor import MonitorReport, monitor
from handeye.app.session import read_session

#: Monitor settings of ``handeye demo --monitor``: quick standstills and a first calibration tried every
#: 4 new poses, so the whole story (arming, bump, alarm, re-learn) fits in about a minute.
DEMO_MONITOR = {"still_s": 0.2, "poll_s": 0.02, "reestimate_samples": 4}

#: The demo's time limit when the config sets none: at least 300 s, and this many seconds per sample asked for
#: (a stop of the production program comes about every 1.2 s on a 2-core box), so that ``--max-samples``
#: ends the run and the limit only guards against a cell that gives no samples.
DEMO_SECONDS_PER_SAMPLE = 3.0


def demo(cfg: Config, *, resume: Path | None = None, progress: bool = True) -> CalibrationOutput:
    """Calibrate the simulated cell: the UR simulator (started by the robot driver, driven
    through the real ur_rtde client) and the rendered camera, whose true pose is known.

    ``resume``: a session of a simulated cell to continue, as `handeye.app.runs.calibrate.calibrate` does.

    Raises
    ------
    ConfigError
        If the config names real hardware: the demo moves without asking.
    SessionError
        If ``resume`` was recorded on a real cell (no simulated truth): its samples are not the demo's.
    """
    if not devices.simulated(cfg):
        raise ConfigError("demo runs only a simulated cell (a simulated robot.type and camera.backend); "
                          "use 'handeye calibrate' for hardware")
    if resume is not None and not read_session(resume).truth:
        raise SessionError(f"session {resume} was recorded on a real cell: continue it there with "
                           f"'handeye calibrate -c <its config> --resume {resume}'")
    return calibrate(cfg, resume=resume, progress=progress)


def demo_monitor(cfg: Config, *, bump: Bump | None, reference: Path | None = None, max_samples: int | None = None,
                 progress: bool = True, publish=None) -> MonitorReport:
    """Passive monitoring of the simulated cell: its controller runs a looping production program,
    the rendered camera is bumped partway (``bump``), the monitor alarms and re-estimates.

    Without ``max_samples`` the run ends a few samples after the re-estimate is due.

    Raises
    ------
    ConfigError
        If the config names real hardware.
    """
    if not devices.simulated(cfg):
        raise ConfigError("demo --monitor runs only a simulated cell (a simulated robot.type and camera.backend); "
                          "use 'handeye monitor' for hardware")
    from handeye.app.config import config_from_dict

    data = cfg.model_dump()
    mon = data["monitor"]
    mon.update(DEMO_MONITOR)
    after = bump.after if bump is not None else 0
    mon["max_samples"] = max_samples or (after + 32 if bump else 30)
    mon["duration_s"] = cfg.monitor.duration_s or max(300.0, DEMO_SECONDS_PER_SAMPLE * mon["max_samples"])
    cfg = config_from_dict(data, "demo --monitor")
    return monitor(cfg, reference=reference, progress=progress, bump=bump, publish=publish)
