"""Re-solve a recorded session (or an imported file) with one, several or all solvers, and advise.

Works for both setups; the session header says which (eye-to-hand:
``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand: ``X = T_flange_cam``,
``Y = T_base_marker``).

The report groups the solvers by what they use (marker points or marker
poses), sorts each group by the held-out prediction error of the marker
point (`handeye.calib.crossval.cross_validate`: each fold solved without its
samples, their points predicted from the robot poses), marks the recommended
result (the lowest held-out error) and explains refined rows that agree
(refinement takes every start to the same maximum-likelihood optimum)
(`advice`). Every result is judged against the tolerance (`handeye.calib.verdict`):
the verdict of the recommended one comes first.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from handeye.app import devices, provenance
from handeye.app.config import CalibrateConfig
from handeye.app.errors import SessionError
from handeye.app.runs.calibrate import write_run_report
from handeye.app.session import read_session
from handeye.calib import transforms as tf
from handeye.calib.api import METHODS, observations_problem, solve_observations
from handeye.calib.errors import HandeyeError, InsufficientDataError
from handeye.calib.observation import Observation
from handeye.calib.result import CalibrationResult
from handeye.calib.setup import Setup
from handeye.drivers.robot.registry import kinematic_model


@dataclass
class ReplaySettings:
    """What ``replay -c CONFIG`` takes from a config (the defaults without one).

    ``tolerance``: ``[calibrate] tolerance_mm, tolerance_deg`` the verdicts judge against;
    ``shared_error``: the robot's kinematic error model (`KinematicModel.shared_error_factor`) or
    None; ``exports``, ``frames``: what ``--out`` writes; ``config``: the config itself (None without one);
    ``marker_offset`` (3,), m, or None and ``marker_offset_sigma``, m: the known marker-side translation
    ``auto`` holds (`handeye.calib.problem.CalibrationProblem.marker_offset`; ``--marker-offset`` or ``[marker]
    offset_m``).
    """

    tolerance: tuple[float, float] = (CalibrateConfig().tolerance_mm, CalibrateConfig().tolerance_deg)
    shared_error: object = None
    exports: list = field(default_factory=lambda: list(devices.RESULT_FILES))
    frames: dict | None = None
    config: object = None
    marker_offset: tuple | None = None
    marker_offset_sigma: float = 0.0


def replay_settings(config: Path | None, *, marker_offset=None, marker_offset_sigma_mm=None) -> ReplaySettings:
    """`ReplaySettings` of the config at ``config`` (defaults for None), with the command line's marker offset
    (m) and its 1-sigma (mm) over the config's ``[marker] offset_m`` / ``offset_sigma_m``."""
    sigma = None if marker_offset_sigma_mm is None else marker_offset_sigma_mm * 1e-3
    if config is None:
        return ReplaySettings(marker_offset=marker_offset, marker_offset_sigma=sigma or 0.0)
    from handeye.app.config import load_config

    cfg = load_config(config)
    model = kinematic_model(cfg.robot)   # (from the config: no driver is built)
    shared_error = None if model is None else model.shared_error_factor
    return ReplaySettings((cfg.calibrate.tolerance_mm, cfg.calibrate.tolerance_deg), shared_error,
                          cfg.session.exports, cfg.frames.model_dump(), cfg,
                          marker_offset if marker_offset is not None else cfg.marker.offset_m,
                          sigma if sigma is not None else cfg.marker.offset_sigma_m)


@dataclass
class ReplayOutcome:
    """What `replay_source` found: the rows and the advice on them, and what `write_outputs` needs.

    ``header``: the source, setup, samples and what an importer measured; ``table``: the solvers'
    comparison (`format_table`); ``advice``: the lines under it (`advice`); ``best``: the row whose
    result ``--out`` writes (the recommended one, else the first that solved), judged; ``truth``:
    the recorded camera truth (4, 4) or None; ``devices``: what identified the robot and camera of a
    handeye session (its header's ``devices``), else None.
    """

    header: str
    table: str
    advice: list
    rows: list
    best: object
    observations: list
    setup: Setup
    source: Path
    truth: np.ndarray | None = None
    devices: dict | None = None


def write_outputs(outcome: "ReplayOutcome", out_dir: Path, exports, frames: dict | None = None,
                  report=None) -> dict:
    """Write ``outcome.best``'s result into ``out_dir`` in each export format (`handeye.app.devices.write_result`)
    and its ``report.html``, as calibrate writes its session's; ``report``: the ``[report]`` fields (site,
    cell, operator; a config's or a dict); returns ``{kind: path}``."""
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise SessionError(f"--out {out_dir}: cannot create ({e.strerror})") from None
    cell = provenance.cell(report or {}, outcome.devices)
    source = outcome.source.resolve()
    files = devices.write_result(outcome.best.result, out_dir, exports, frames, samples_from=source, cell=cell)
    files["report"] = write_run_report(outcome.best.result, out_dir, outcome.observations, frames,
                                       samples_from=source, cell=cell)
    return files


def replay_source(source: Path, methods: list[str], *, refine: bool = False, robust: bool = False,
                  setup: Setup | None = None, rng: np.random.Generator | None = None,
                  tolerance: tuple[float, float] = ReplaySettings.tolerance, shared_error=None,
                  marker_offset=None, marker_offset_sigma: float = 0.0,
                  import_options: dict | None = None) -> ReplayOutcome:
    """Re-solve a session directory or an imported file with each method, each result judged against
    ``tolerance`` (mm, deg); returns the outcome: the tables grouped by what the solvers use and sorted by
    held-out error, the advice (`advice`), the recommended row (``shared_error``, ``marker_offset``,
    ``marker_offset_sigma``: `replay`; ``import_options``: `handeye.app.devices.import_options`)."""
    if not Path(source).exists():
        raise SessionError(f"{source}: no such file or directory")
    if (Path(source) / "session.json").exists():
        session = read_session(source)
        if setup is not None and setup != session.setup:
            raise SessionError(f"{source} is an {session.setup} session; --setup {setup} contradicts it")
        observations, file_setup, truth = session.observations, session.setup, session.truth
        header, identity = "", session.header.get("devices")
    else:
        observations, file_setup, meta = devices.import_observations(Path(source), setup, **(import_options or {}))
        truth, header, identity = {}, _import_summary(meta), None
    setup = setup or file_setup
    if not observations:
        raise InsufficientDataError(f"{source}: no samples to replay")
    if methods == ["all"]:
        methods = list(METHODS)
    T_true = devices.camera_truth(setup, truth)
    rows = replay(observations, setup, methods, refine=refine, robust=robust,
                  truth=T_true, rng=rng, shared_error=shared_error, tolerance=tolerance,
                  marker_offset=marker_offset, marker_offset_sigma=marker_offset_sigma)
    if all(r.result is None for r in rows):
        raise HandeyeError(f"no solver succeeded on {source}: " + "; ".join(f"{r.method}: {r.error}" for r in rows))
    best = recommended(rows) or next(r for r in rows if r.result is not None)
    return ReplayOutcome(f"{source} ({setup}, {len(observations)} samples)\n{header}", format_table(rows, setup),
                         advice(rows, refine=refine), rows, best, observations, Setup(setup), Path(source), T_true,
                         identity)


def _import_summary(meta: dict) -> str:
    """What an importer measured that the table does not show (the streams' clock offset)."""
    if "clock_offset_s" not in meta:
        return ""
    line = f"clock offset (t_robot = t_camera + offset): {meta['clock_offset_s'] * 1e3:+.1f} ms"
    if "xcorr_score" in meta:
        line += f" (angular-speed correlation {meta['xcorr_score']:.2f}"
        if "refine_rms_mm" in meta:
            line += f", refined on the residual: RMS {meta['refine_rms_mm']:.2f} mm"
        line += ")"
    return line + "\n"


#: Refined results closer than this (mm, deg) count as the same optimum (well inside any 1-sigma we accept).
SAME_MM, SAME_DEG = 0.5, 0.05


@dataclass
class ReplayRow:
    """One solver's outcome on the replayed samples.

    ``error`` holds the one-line reason when the solver refused the data (e.g.
    a pose-based method on a point-only session); ``truth_error`` is
    ``(deg, mm)`` of the camera transform against the recorded truth, if any;
    ``uses`` is ``"points"`` or ``"poses"``; ``heldout`` the
    `handeye.calib.crossval.CrossValidation` of the method on these samples (None if
    cross-validation was off or failed, with ``heldout_error`` saying why). The result carries its
    verdict (`handeye.calib.verdict.judge`).
    """

    method: str
    result: CalibrationResult | None
    seconds: float
    error: str | None = None
    truth_error: tuple[float, float] | None = None
    uses: str = ""
    heldout: object | None = None
    heldout_error: str | None = None


def _is_auto(method: str) -> bool:
    from handeye.calib.api import AUTO

    return isinstance(method, str) and method.strip().lower() == AUTO


def _uses(method: str) -> str:
    from handeye.calib.api import resolve_method

    if _is_auto(method):
        return "auto"
    try:
        return resolve_method(method).needs
    except HandeyeError:
        return "?"


def heldout_error(method: str, observations, setup: Setup, *, refine: bool, robust: bool,
                  rng: np.random.Generator | None, marker_offset=None, marker_offset_sigma: float = 0.0):
    """`handeye.calib.crossval.cross_validate` of ``method`` on the samples it uses (leave-one-out up to 10
    samples, else 5 folds: a few solves per method); returns ``(CrossValidation or None, reason or None)``.
    ``marker_offset`` (m) and ``marker_offset_sigma`` (m): ``auto``'s known marker-side translation."""
    from handeye.calib.api import resolve_method
    from handeye.calib.crossval import cross_validate

    try:
        problem = observations_problem(method, observations, setup,
                                       **_offset(method, marker_offset, marker_offset_sigma))
        name = method if _is_auto(method) else resolve_method(method).name
        folds = None if problem.n <= 10 else 5
        return cross_validate(name, problem, folds=folds, rng=rng, refine=refine, robust=robust), None
    except HandeyeError as e:
        return None, str(e)


def replay(
    observations: list[Observation],
    setup: Setup,
    methods: list[str],
    *,
    refine: bool = False,
    robust: bool = False,
    truth: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
    crossval: bool = True,
    shared_error=None,
    tolerance: tuple[float, float] = ReplaySettings.tolerance,
    marker_offset=None,
    marker_offset_sigma: float = 0.0,
) -> list[ReplayRow]:
    """Solve the same samples with each method, time it, judge it, and cross-validate it.

    Parameters
    ----------
    observations : list[Observation]
    setup : {"eye_to_hand", "eye_in_hand"}
    methods : list of str
        Paper names (``"YKronT'"``, ``"YQuatT'"``, ``"XKronRT"``, ...).
    truth : ndarray (4, 4), optional
        True camera transform (``T_base_cam`` eye-to-hand, ``T_flange_cam``
        eye-in-hand) to report errors against.
    crossval : bool
        Also measure each method's held-out prediction error (`heldout_error`).
    shared_error : callable, optional
        A robot's `Robot.shared_error_factor`: ``auto`` adds the error it
        models as shared by the samples, when they carry their joints
        (`handeye.app.devices.robot_shared_error`).
    tolerance : (float, float)
        mm, deg: what each result's verdict judges against (`handeye.app.devices.judge`).
    marker_offset : array_like, shape (3,), optional
        The known marker-side translation, m, and ``marker_offset_sigma`` its
        1-sigma (m): ``auto`` holds it (`handeye.calib.problem.CalibrationProblem`);
        the paper's methods do not take it.

    Returns
    -------
    list[ReplayRow]
        One per method, in the given order; a method that raises a
        ``HandeyeError`` gets a row with ``error`` set instead of stopping the rest.
    """
    rows = []
    for method in methods:
        t0 = time.perf_counter()
        try:
            res = solve_observations(method, observations, setup, refine=refine, robust=robust, rng=rng,
                                     robot_shared_error=devices.robot_shared_error(method, observations, shared_error),
                                     **_offset(method, marker_offset, marker_offset_sigma))
        except HandeyeError as e:
            rows.append(ReplayRow(method, None, time.perf_counter() - t0, error=str(e), uses=_uses(method)))
            continue
        dt = time.perf_counter() - t0
        res = devices.judge(res, method, observations, setup, tolerance, shared_error,
                            **_offset(method, marker_offset, marker_offset_sigma))
        err = None
        if truth is not None:
            rot, trans = tf.pose_error(res.camera_transform, truth)
            err = (float(np.rad2deg(rot)), float(trans * 1e3))
        row = ReplayRow(method, res, dt, truth_error=err, uses=_uses(method))
        if crossval:
            row.heldout, row.heldout_error = heldout_error(method, observations, setup, refine=refine,
                                                           robust=robust, rng=rng,
                                                           **_offset(method, marker_offset, marker_offset_sigma))
        rows.append(row)
    return rows


def _offset(method: str, marker_offset, sigma: float) -> dict:
    """The marker-offset keywords of ``method``'s solve: ``auto`` takes them, the paper's methods do not."""
    if marker_offset is None or not _is_auto(method):
        return {}
    return {"marker_offset": marker_offset, "marker_offset_sigma": sigma}


def _rank_key(r: ReplayRow):
    if r.result is None:
        return (2, 0.0)
    if r.heldout is None:
        return (1, r.result.residuals.rms_translation)
    return (0, r.heldout.observed_rms)


def recommended(rows: list[ReplayRow]) -> ReplayRow | None:
    """The row with the lowest held-out prediction error (None without cross-validation results)."""
    ranked = [r for r in rows if r.result is not None and r.heldout is not None]
    return min(ranked, key=_rank_key) if ranked else None


def format_table(rows: list[ReplayRow], setup: Setup) -> str:
    """Markdown tables, one per group (marker points / marker poses), each sorted by held-out error.

    Columns: solver, samples, inliers, residual RMS (mm), camera xyz (mm),
    1-sigma (mm, deg), held-out prediction error (mm) and what the model
    predicts for it, time, error vs. truth, the verdict's level and the recommendation.
    """
    cam = Setup(setup).camera_name
    has_truth = any(r.truth_error is not None for r in rows)
    best = recommended(rows)
    head = ["solver", "n", "inliers", "resid RMS [mm]", f"{cam} xyz [mm]", "1σ [mm]", "1σ [deg]",
            "held-out [mm]", "predicted [mm]", "time [ms]"]
    if has_truth:
        head += ["err [mm]", "err [deg]"]
    head += ["verdict", "advice"]
    out = []
    for uses, title in (("points", "solvers using marker points"), ("poses", "solvers using marker poses"),
                        ("auto", "the solver 'auto' (handeye.calib.auto: camera and robot model)"),
                        ("?", "unknown solvers")):
        group = sorted((r for r in rows if r.uses == uses), key=_rank_key)
        if not group:
            continue
        out += ["", f"{title}, by held-out prediction error:", "",
                "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for r in group:
            if r.result is None:
                cells = [r.method, "-", "-", f"failed: {r.error}"] + [""] * (len(head) - 4)
            else:
                res = r.result
                xyz = " ".join(f"{v:.1f}" for v in res.camera_transform[:3, 3] * 1e3)
                s_deg, s_mm = _sigma_deg_mm(res)
                n_in = res.n_samples if res.inliers is None else int(np.count_nonzero(res.inliers))
                ho = ("-", "-") if r.heldout is None else (f"{r.heldout.observed_rms * 1e3:.2f}",
                                                            f"{r.heldout.predicted_rms * 1e3:.2f}")
                cells = [r.method, str(res.n_samples), str(n_in), f"{res.residuals.rms_translation * 1e3:.2f}",
                         xyz, f"{s_mm:.2f}", f"{s_deg:.3f}", *ho, f"{r.seconds * 1e3:.1f}"]
                if has_truth:
                    cells += ["-", "-"] if r.truth_error is None else [f"{r.truth_error[1]:.2f}",
                                                                      f"{r.truth_error[0]:.3f}"]
                cells.append(res.verdict.level if res.verdict is not None else "-")
                cells.append("**recommended**" if r is best else "")
            out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out).lstrip("\n")


def advice(rows: list[ReplayRow], *, refine: bool) -> list[str]:
    """Lines under the tables: the recommendation and why refined rows agree (each result's problems are
    its verdict's reasons)."""
    lines = []
    ok = [r for r in rows if r.result is not None]
    # Groups whose refined rows all reach the same optimum: one result, however many solvers.
    agreeing = {}
    if refine:
        for uses in ("points", "poses"):
            group = [r for r in ok if r.uses == uses]
            if len(group) < 2:
                continue
            ref = group[0].result.camera_transform
            errs = np.array([tf.pose_error(r.result.camera_transform, ref) for r in group])
            spread_mm, spread_deg = float(errs[:, 1].max()) * 1e3, float(np.rad2deg(errs[:, 0].max()))
            if spread_mm <= SAME_MM and spread_deg <= SAME_DEG:
                agreeing[uses] = (group, spread_mm, spread_deg)
    best = recommended(rows)
    if best is not None:
        what = f"{best.method}{' (refined)' if refine else ''}"
        if best.uses in agreeing:
            what = (f"the refined result from marker {best.uses} (all {len(agreeing[best.uses][0])} solvers of that "
                    f"group reach it; {best.method} had the lowest held-out error)")
        lines.append(f"recommended: {what}: held-out prediction error {best.heldout.observed_rms * 1e3:.2f} mm "
                     f"(its model predicts {best.heldout.predicted_rms * 1e3:.2f} mm)")
    elif ok:
        why = next((r.heldout_error for r in ok if r.heldout_error), "cross-validation off")
        lines.append(f"no recommendation: no held-out prediction error ({why}); rows sorted by residual RMS")
    for uses, (group, spread_mm, spread_deg) in agreeing.items():
        lines.append(f"note: the {len(group)} refined rows using marker {uses} agree within "
                     f"{spread_mm:.3f} mm / {spread_deg:.4f} deg: maximum-likelihood refinement takes "
                     "every solver's closed-form start to the same optimum, so they differ only in time "
                     "(replay without --refine to compare the closed forms)")
    return lines


def _sigma_deg_mm(res: CalibrationResult) -> tuple[float, float]:
    """`CalibrationResult.sigma` in deg and mm (NaN without a covariance)."""
    if res.sigma is None:
        return float("nan"), float("nan")
    s_rot, s_t = res.sigma
    return float(np.rad2deg(s_rot)), s_t * 1e3
