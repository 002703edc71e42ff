"""Build the parts a run needs from a `Config`: robot, camera, extraction, solver, online estimator, outputs.

The config arrives validated (`handeye.app.config`); the backends come from the
registries by name, so nothing here knows a particular robot or camera.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from handeye.app.config import CalibrateConfig, Config
from handeye.app.errors import ConfigError, SessionError
from handeye.app.session import check_writable_root
from handeye.app.viz import Viz
from handeye.calib.setup import Setup
from handeye.drivers.camera.registry import CAMERAS
from handeye.drivers.robot.registry import ROBOTS

#: Result files written into the session directory, by export format.
RESULT_FILES = {
    "yaml": "result.yaml",
    "json": "result.json",
    "easy_handeye": "easy_handeye.yaml",
    "easy_handeye2": "handeye.calib",
    "urdf": "handeye.urdf.xacro",
    "ros2_launch": "handeye.launch.py",
}


def check_session_root(cfg: Config) -> None:
    """ConfigError naming ``session.root`` unless sessions can be written there (checked before devices open)."""
    try:
        check_writable_root(cfg.session.root)
    except SessionError as e:
        raise ConfigError(f"session.root: {e}") from None


def open_robot(cfg: Config, *, read_only: bool):
    """The configured robot (not yet connected; use as a context manager).

    ``read_only=True`` (monitor) forces the driver's read-only mode: it then
    refuses every motion command (a backend without that mode, the ``ros2`` robot, is read-only anyway).
    """
    robot = cfg.robot
    if read_only and "read_only" in type(robot).model_fields:
        robot = robot.model_copy(update={"read_only": True})
    return ROBOTS.create(robot)


def open_camera(cfg: Config, robot):
    """The configured camera, following the robot's flange pose (which a simulated camera renders at).

    The camera follows `Robot.true_flange_pose`: a simulated robot's truth (with a kinematic error it is not
    the reported pose), which a rendered camera sees; a real robot's reported pose, the best there is.
    """
    camera = CAMERAS.create(cfg.camera)
    camera.follow(robot.true_flange_pose)
    return camera


def simulated(cfg: Config) -> bool:
    """True when both configured devices are simulators (the demo moves without asking)."""
    return ROBOTS.of_config(cfg.robot).device.simulated and CAMERAS.of_config(cfg.camera).device.simulated


def truth(camera) -> dict:
    """True transforms of a simulated camera (``T_base_cam``/``T_flange_marker`` eye-to-hand,
    ``T_flange_cam``/``T_base_marker`` eye-in-hand); empty for real cameras."""
    return camera.truth() or {}


def camera_truth(setup: Setup, truth: dict) -> np.ndarray | None:
    """The true camera transform (``T_base_cam`` or ``T_flange_cam``) from a truth dict, if it holds one."""
    key = Setup(setup).camera_name
    return None if key not in truth else np.asarray(truth[key], dtype=float)


def make_measure(cfg: Config):
    """``measure(frame) -> MarkerMeasurement`` for the configured target (``[marker]``).

    Raises ``ExtractionError`` (marker not found, bad depth) so the caller skips the frame.
    """
    from handeye.calib.vision.extract import extract

    def measure(frame):
        return extract(frame.color, frame.depth, frame.intrinsics, cfg.marker)

    return measure


def make_solve(cal: CalibrateConfig, setup: Setup, rng: np.random.Generator, shared_error=None, marker=None):
    """``solve(observations, *, final, stopped_early=None)``: the configured solver, refined while running too
    if configured, so that the stop on the predicted 1-sigma and the pose planner see the covariance of the
    result that will be reported (with "auto": the camera-correction uncertainty too, until the samples
    determine it); outlier rejection only at the end, where the result also gets its verdict against
    ``[calibrate] tolerance_mm / tolerance_deg`` (`judge`; ``stopped_early``: why the run ended before its
    target, a reason of the verdict).

    ``shared_error``: the robot's `Robot.shared_error_factor`; with ``auto`` and the joints of every sample
    (``Observation.joints``), the error it models joins the covariance as shared by all samples.
    ``marker``: the ``[marker]`` config, whose ``offset_m`` (with ``offset_sigma_m``) ``auto`` holds."""
    from handeye.calib.api import solve_observations
    from handeye.calib.methods import is_auto

    offset = {}
    if marker is not None and marker.offset_m is not None and is_auto(cal.method):
        offset = {"marker_offset": marker.offset_m, "marker_offset_sigma": marker.offset_sigma_m}

    def solve(observations, *, final: bool, stopped_early: str | None = None):
        result = solve_observations(cal.method, observations, setup, refine=cal.refine, robust=cal.robust and final,
                                    rng=rng,
                                    robot_shared_error=robot_shared_error(cal.method, observations, shared_error),
                                    **offset)
        if not final:
            return result
        return judge(result, cal.method, observations, setup, (cal.tolerance_mm, cal.tolerance_deg), shared_error,
                     stopped_early=stopped_early, **offset)

    return solve


def judge(result, method: str, observations, setup: Setup, tolerance: tuple[float, float], shared_error=None,
          marker_offset=None, marker_offset_sigma=0.0, stopped_early: str | None = None):
    """``result`` of ``method`` on ``observations`` with its predicted accuracy and verdict
    (`handeye.calib.verdict.judge`) against ``tolerance`` (mm, deg); ``shared_error``: as `make_solve`'s; the marker
    offset the result was solved with (`handeye.calib.api.observations_problem`); ``stopped_early``: why the run ended
    before its target (`handeye.calib.verdict.judge`)."""
    from handeye.calib.api import observations_problem
    from handeye.calib.verdict import judge as judge_result

    problem = observations_problem(method, observations, setup,
                                   robot_shared_error=robot_shared_error(method, observations, shared_error),
                                   marker_offset=marker_offset, marker_offset_sigma=marker_offset_sigma)
    return judge_result(result, problem, tolerance_mm=tolerance[0], tolerance_deg=tolerance[1],
                        stopped_early=stopped_early)


def robot_shared_error(method: str, observations, shared_error) -> np.ndarray | None:
    """``solve``'s ``robot_shared_error`` for ``observations``: ``shared_error`` (a robot's
    `Robot.shared_error_factor`) of their joints (``Observation.joints``, checked where they are read) for
    ``auto``; None for another method, without it, or when a sample lacks its joints (imported files)."""
    from handeye.calib.methods import is_auto

    if shared_error is None or not is_auto(method) or any(o.joints is None for o in observations):
        return None
    return shared_error(np.array([o.joints for o in observations], dtype=float))


def make_viz(cfg: Config, session: Path) -> Viz:
    """rerun recording saved as ``<session>/recording.rrd`` (``recording-2.rrd`` ... when resumed; no-op if disabled)."""
    path, n = session / "recording.rrd", 1
    while path.exists():
        n += 1
        path = session / f"recording-{n}.rrd"
    return Viz(cfg.setup, path, viewer=cfg.viz.viewer, viewer_bind=cfg.viz.viewer_bind, enabled=cfg.viz.enabled,
               log_images=cfg.viz.log_images)


def make_engine(cfg: Config):
    """A fresh, unarmed `handeye.calib.monitor.MonitorEngine` with the ``[monitor.engine]`` settings."""
    from handeye.calib.monitor import MonitorEngine

    return MonitorEngine(cfg.monitor.engine)


def write_result(result, session: Path, formats, frames: dict | None = None, samples_from=None,
                 cell: dict | None = None) -> dict:
    """Write the result in each export format into the session directory, with the ``[frames]``
    names, where its samples came from (``samples_from``) and the cell (`handeye.app.provenance.cell`);
    returns ``{format: path}``."""
    from handeye.app.formats import write_result as export

    return {fmt: export(result, Path(session) / RESULT_FILES[fmt], fmt, frames, samples_from=samples_from,
                        cell=cell) for fmt in formats}


def import_options(cfg: Config | None, *, frames: str | None = None, topics: str | None = None) -> dict:
    """Options for the importers that take them (`handeye.app.formats.registry.ImportFormat.options`): the
    ``[frames]`` and ``[marker]`` of ``cfg``, overridden by the command line's ``frames``
    (``base=NAME,flange=NAME``) and ``topics`` (``color=TOPIC,...``)."""
    from handeye.app.formats.ros2_bag import parse_pairs

    names = cfg.frames.model_dump(exclude_unset=True) if cfg is not None else {}  # the bag names the rest
    names.update(parse_pairs(frames, "--frames", ("base", "flange", "camera", "marker")))
    options = {"frames": names, "topics": parse_pairs(topics, "--topics", ("color", "depth", "info", "marker"))}
    if cfg is not None:
        options["target"] = cfg.marker
    return options


def import_observations(path: Path, setup: str | None, **options):
    """Samples from another tool's files (easy_handeye, industrial_calibration, pose-stream CSV, ROS 2 bag).

    ``options`` (`import_options`) go to the formats that take them.

    Returns
    -------
    observations : list[Observation]
    setup : str
    meta : dict
        What the importer found out (e.g. ``clock_offset_s`` of pose streams).
    """
    from handeye.app.formats import detect_format, get_format

    fmt = get_format(detect_format(path))
    # Only formats whose files may leave the setup open take it; the others state it.
    kwargs = {k: v for k, v in options.items() if k in fmt.options}
    if setup is not None and fmt.open_setup:
        kwargs["setup"] = setup
    imported = fmt.load(path, **kwargs)
    return imported.observations, imported.setup, imported.meta
