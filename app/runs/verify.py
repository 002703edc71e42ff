"""Verification: judge a calibration result on samples it did not see, in the base frame, mm and deg.

Active: move to ``[verify] poses`` fresh planned poses spread over the
``[calibrate]`` region, never the calibration's, measure the marker there and
compare it with the one the result predicts. Passive: the same on samples
taken read-only while production moves the robot (the monitor's sampling).
Offline: the same against another recorded session or an imported file (the
cross-session check). Either way: pass/fail against ``[verify] tolerance_mm /
tolerance_deg``, ``verify.yaml`` and ``report.html`` in the verify session
(offline: a new directory under ``session.root``).

Eye-to-hand: ``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand:
``X = T_flange_cam``, ``Y = T_base_marker`` (paper eq. 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from handeye.app import devices, provenance
from handeye.app import verify as av
from handeye.app.config import Config
from handeye.app.errors import SessionError
from handeye.app.report import write_report
from handeye.app.session import new_output_dir, read_session
from handeye.calib import verify as cv
from handeye.calib.errors import HandeyeError, InsufficientDataError
from handeye.calib.verdict import judge_verification


@dataclass
class VerifyOutput:
    """A verification and where it went.

    ``doc``: the verify.yaml document (`handeye.app.verify.verify_document`); ``path``: verify.yaml;
    ``report``: report.html; ``passed``: within the tolerance; ``interrupted``: Ctrl-C stopped the
    robot after ``n_poses`` poses (``session`` holds them); ``verification``: the judged
    `handeye.calib.verify.Verification`. ``doc``, ``path`` and ``report`` are None when Ctrl-C came before
    `handeye.calib.verify.MIN_POSES` poses were measured: nothing was judged.
    """

    doc: dict | None
    path: Path | None
    report: Path | None
    passed: bool
    n_poses: int
    session: Path
    interrupted: bool = False
    verification: cv.Verification | None = None


def verify(cfg: Config, result: Path, *, session: Path | None = None, setup: str | None = None,
           passive: bool = False, expect_xyz: np.ndarray | None = None,
           confirm: Callable[[], None] = lambda: None) -> VerifyOutput:
    """Verify ``result`` (result.yaml or its session) offline against ``session``, else on the cell.

    ``setup``: of an imported ``session`` file; ``passive``: sample read-only while production moves
    the robot; ``expect_xyz``: rough camera position (m) for the frame-safety check; ``confirm``: called
    once an active run has connected and planned its poses, before it moves the robot (raises to refuse).
    """
    loaded = av.load_result(result)
    rng = np.random.default_rng(cfg.verify.seed)
    truth_mm = None
    interrupted = False
    if session is not None:
        observations, source, mode = _offline_samples(session, setup, loaded), session, "offline"
        _check_enough(observations, source)
        out_dir = new_output_dir(cfg.session.root, loaded.model.setup, "verify")
    else:
        if passive:
            run_, mode = av.verify_passive(cfg, loaded), "passive"
        else:
            run_, mode = av.verify_active(cfg, loaded, rng=rng, confirm=confirm), "active"
        observations, source, out_dir = run_.observations, run_.session, run_.session
        interrupted = run_.interrupted
        if interrupted and len(observations) < cv.MIN_POSES:
            # Stopped before there was anything to judge: the poses measured stay in the session.
            return VerifyOutput(None, None, None, False, len(observations), out_dir, True)
        _check_enough(observations, source)
        if run_.truth:
            truth_mm = av.true_error_mm(loaded, observations, run_.truth, run_.camera_bias)
    tol = dict(tolerance_mm=cfg.verify.tolerance_mm, tolerance_deg=cfg.verify.tolerance_deg)
    verification = cv.verify(av.pose_errors(loaded.model, observations), rng=rng, **tol)
    rigid = None if loaded.rigid is None else cv.verify(av.pose_errors(loaded.rigid, observations), rng=rng, **tol)
    safety = None if expect_xyz is None else cv.frame_safety(loaded.model.camera_transform, loaded.model.setup,
                                                             expect_xyz)
    calibration = loaded.calibration_samples()
    repeated = cv.repeated_poses([o.T_base_flange for o in observations], [o.T_base_flange for o in calibration]) \
        if calibration else []
    verdict = judge_verification(verification, rigid=rigid, repeated=len(repeated),
                                 warnings=() if safety is None else safety.warnings)
    cell = provenance.cell(cfg.report, read_session(out_dir).header.get("devices") if mode != "offline"
                           else (loaded.doc.get("cell") or {}))
    doc = av.verify_document(loaded, mode, source, verification, rigid, safety, truth_mm, verdict=verdict,
                             repeated=repeated, cell=cell)
    path = av.write_verify(doc, out_dir)
    report = write_report(out_dir, result_doc=loaded.doc, observations=calibration, verify_doc=doc,
                          verify_observations=observations, title="handeye verification report", cell=cell)
    return VerifyOutput(doc, path, report, verification.passed, len(observations), out_dir, interrupted,
                        verification)


def _check_enough(observations, source) -> None:
    if len(observations) < cv.MIN_POSES:
        raise InsufficientDataError(f"verification needs at least {cv.MIN_POSES} poses with a measurement, "
                                    f"{source} has {len(observations)}")


def _offline_samples(source: Path, setup, loaded):
    if not Path(source).exists():
        raise SessionError(f"{source}: no such file or directory")
    if (Path(source) / "session.json").exists():
        session = read_session(source)
        observations, file_setup = session.observations, session.setup
    else:
        observations, file_setup, _ = devices.import_observations(Path(source), setup or loaded.model.setup.value)
    if file_setup != loaded.model.setup:
        raise SessionError(f"{source} is an {file_setup} session, {loaded.path} an {loaded.model.setup} result")
    if loaded.samples_from is not None and Path(source).resolve() == loaded.samples_from.resolve():
        raise HandeyeError(f"{source} is the session {loaded.path} was calibrated on: verify it on samples it did "
                           "not see (another session, or the active mode)")
    return observations
