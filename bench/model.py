"""Benchmark of the measurement model and ``solve("auto")`` (issue 10): markdown tables, out/bench/model.md.

Sections:

1. Realistic profile (`handeye.calib.simulate.realistic_profile`: UR10 DH error, 1.5% depth
   scale, 3 mm depth offset, 1% focal, 2 px misregistration), N = 30: error of
   ``auto`` vs the Cramér-Rao bound of the extended model, vs the bound of the
   model that generated the data (`generating_bound`) and vs ``auto`` on the
   same cell without systematic errors; NEES of its covariance. Then the same
   with each systematic effect switched off, and each alone (`section_effects`).
2. Eight poses of a board with good orientations: ``auto`` vs every pose-based
   solver, ours and OpenCV's.
3. Symmetric board: 30% of the marker poses flipped by a half turn.
4. Every real set in the shared datasets (`bench.datasets`): held-out (leave-one-out,
   10-fold above 60 samples) prediction error of the marker point, ``auto`` vs
   every closed form and the paper's refinement; predicted vs observed.
5. Plain cell: the paper's refined YKronT' vs the Cramér-Rao bound.
6. Speed at N = 1000 (one thread).

Run: ``python -m bench --model`` or ``python -m bench.model [--quick]``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from bench.datasets import datasets_dir, real_sets  # noqa: E402
from bench.solvers import OPENCV_HAND_EYE, OPENCV_ROBOT_WORLD, run_solver  # noqa: E402
from handeye.calib import model, solve, solvers  # noqa: E402
from handeye.calib import robot_error, simulate  # noqa: E402
from handeye.calib import transforms as tf  # noqa: E402
from handeye.calib.api import METHODS, closed_form  # noqa: E402
from handeye.calib.crossval import cross_validate, fold_indices  # noqa: E402
from handeye.calib.errors import CalibrationError  # noqa: E402
from handeye.calib.refine import cramer_rao_bound, error_vector, nees  # noqa: E402
from handeye.calib.setup import Setup  # noqa: E402
from bench.tables import markdown_table  # noqa: E402

POSE_METHODS = [m for m, i in METHODS.items() if i.needs == "poses"]


def _rms(v) -> float:
    return float(np.sqrt(np.mean(np.square(v))))


def extended_cov(d: simulate.SimulatedData, robot_rms: float, orientation_sigma: float | None = None,
                 free=(True, True, True)) -> np.ndarray:
    """Cramér-Rao bound (9, 9) of the camera and its correction under the extended model, at the truth.

    Order: camera rotation (left rotation vector, rad), camera translation
    (m), depth scale, depth offset (m), focal scale; rows and columns of a
    camera parameter not in ``free`` are zero (known). Unknowns: camera (6),
    marker translation (3) (+ rotation with ``orientation_sigma``), and the
    camera parameters in ``free``. Noise: the
    true point covariance plus the robot error propagated through the lever
    arm (`handeye.calib.model.robot_cofactor`) at ``robot_rms`` per axis, treated as
    white (the simulated kinematic error is systematic, so this is the bound
    of an idealised robot with the same error level).
    """
    C, K, M = model.split(d.X, d.Y, d.A_true, Setup.EYE_TO_HAND)
    p_true = model.predict_points(C, K[:3, 3], M)
    cov = d.point_cov + robot_rms**2 * model.robot_cofactor(C, K, M, Setup.EYE_TO_HAND)
    B = p_true if orientation_sigma is None else np.concatenate(
        [np.concatenate([d.B_true[:, :3, :3], p_true[:, :, None]], axis=2), d.B_true[:, 3:]], axis=1)
    prob = model.Linearization(M, B, model.whitener(cov), sigma_rot=orientation_sigma, free=free)
    info = model.information(prob, C, K, np.zeros(3))
    model.camera_block(info)          # the degeneracy check
    rows = list(range(6)) + list(range(prob.n_pose, prob.n_pose + int(np.sum(free))))
    return _camera_and_correction(np.linalg.inv(info)[np.ix_(rows, rows)], free)


def _camera_and_correction(cov, free) -> np.ndarray:
    """(9, 9) from the covariance of the camera (6) and the free camera parameters, zeros for the known ones."""
    keep = list(range(6)) + [6 + i for i in range(3) if free[i]]
    out = np.zeros((9, 9))
    out[np.ix_(keep, keep)] = cov
    return out


def translation_rms(cov) -> float:
    """RMS (m) of the camera translation error of a (9, 9) `extended_cov`: ``sqrt(trace)`` of its block."""
    return float(np.sqrt(np.trace(cov[3:6, 3:6])))


def workspace_jacobian(Y, points_cam) -> np.ndarray:
    """Jacobian (m, 3, 9) of the base-frame point the calibrated camera reports, at an exact calibration.

    A camera point ``c`` is reported in the base frame as ``Y correct(h(c))``
    (`handeye.calib.model.CameraCorrection`); its derivative w.r.t. the parameters of
    `extended_cov` (camera rotation and translation, depth scale, offset,
    focal scale) at the truth, for true camera-frame points ``points_cam`` (m, 3).
    """
    R = Y[:3, :3]
    J = np.zeros((len(points_cam), 3, 9))
    J[:, :, 0:3] = -tf.skew(points_cam @ R.T)        # left rotation perturbation, Exp(d) R
    J[:, :, 3:6] = np.eye(3)
    J[:, :, 6:9] = -R @ model.measure(points_cam, np.zeros(3))[2]   # correcting undoes the measured change
    return J


def workspace_rms(cov, Y, points_cam) -> float:
    """RMS (m) over ``points_cam`` of the base-frame point error that a (9, 9) covariance ``cov`` gives."""
    J = workspace_jacobian(Y, points_cam)
    return float(np.sqrt(np.mean(np.einsum("mij,jk,mik->m", J, cov, J))))


def workspace_error(Y_est, correction: model.CameraCorrection, real: simulate.RealisticData, P) -> float:
    """RMS (m) over base-frame points ``P`` (m, 3) of where a calibration puts what the camera sees.

    Each point is measured by ``real``'s camera without noise (its systematic
    error applied), corrected with ``correction`` and mapped to the base frame
    by ``Y_est``: the error a user of the calibration gets on that workspace.
    """
    d = real.data
    seen = real.camera.measure(tf.transform_points(tf.invert(d.Y), P))
    return _rms(np.linalg.norm(tf.transform_points(Y_est, correction.correct(seen)) - P, axis=1))


def generating_cov(real: simulate.RealisticData, prof: simulate.RealisticProfile) -> np.ndarray:
    """Bound (9, 9) of the camera and its correction under the model that generated ``real`` (Bayesian CRLB).

    Same order as `extended_cov`. Unknowns: camera (6), marker translation (3), depth scale and offset
    (flat prior: estimated from the data, as `auto` does), and with priors of
    the profile's magnitudes (1-sigma): the focal scale, the 24 DH parameters
    of the robot (joint offsets, link lengths d and a, twists) and the
    colour/depth misregistration (px); an effect of magnitude zero is known
    (not an unknown). Noise: the true point covariance plus
    the repeatability (white) through the lever arm. Jacobian by central
    differences of the simulator's measurement chain at the truth, so the
    bound sees the robot error as what it is (a few parameters shared by all
    samples), not as white noise. Marker points only (eye-to-hand).
    """
    from handeye.calib.noise import FOCAL_PX

    d, kin = real.data, real.kinematics
    base = np.array([prof.depth_scale, prof.depth_offset, prof.focal_scale])

    def measured(phi):
        C = tf.make_transform(tf.so3_exp(phi[0:3]) @ d.Y[:3, :3], d.Y[:3, 3] + phi[3:6])
        X = d.X.copy()
        X[:3, 3] += phi[6:9]
        A = robot_error.ur_forward(real.q, kin["d"] + phi[18:24], kin["a"] + phi[24:30], kin["alpha"] + phi[30:36],
                                kin["offsets"] + phi[12:18])
        B = tf.invert(C) @ A @ X
        p = B[:, :3, 3]
        shift = (prof.misregistration_px + phi[36]) / FOCAL_PX * p[:, 2]
        dz = -B[:, 0, 2] * shift / B[:, 2, 2]
        return model.measure(p * ((p[:, 2] + dz) / p[:, 2])[:, None], base + phi[9:12])[0].reshape(-1)

    k, h = 37, 1e-6
    J = np.empty((3 * len(d.A), k))
    for j in range(k):
        e = np.zeros(k)
        e[j] = h
        J[:, j] = (measured(e) - measured(-e)) / (2 * h)
    C, K, M = model.split(d.X, d.Y, d.A_true, Setup.EYE_TO_HAND)
    cov = d.point_cov + prof.repeatability_m**2 * model.robot_cofactor(C, K, M, Setup.EYE_TO_HAND)
    G = (model.whitener(cov) @ J.reshape(len(d.A), 3, k)).reshape(-1, k)
    # Prior 1-sigma per unknown: inf = no prior (estimated from the data), 0 = known (left out).
    sigma = np.full(k, np.inf)
    sigma[11] = prof.focal_scale
    sigma[12:18] = np.deg2rad(prof.joint_offset_deg)
    sigma[18:30] = prof.link_length_m
    sigma[30:36] = np.deg2rad(prof.twist_deg)
    sigma[36] = prof.misregistration_px
    keep = sigma > 0
    with np.errstate(divide="ignore"):
        prior = np.where(np.isinf(sigma), 0.0, 1.0 / sigma**2)[keep]
    cov_est = np.linalg.inv(G[:, keep].T @ G[:, keep] + np.diag(prior))
    wanted = [j for j in (*range(6), 9, 10, 11) if keep[j]]
    at = np.cumsum(keep) - 1              # row of each kept unknown in cov_est
    return _camera_and_correction(cov_est[np.ix_(at[wanted], at[wanted])], keep[9:12])


#: Held-out points per cell on which the workspace error is measured (`simulate.workspace_points`).
WORKSPACE_POINTS = 200

#: Estimators of `section_realistic`: name -> solve of (A, points, poses).
REALISTIC_ESTIMATORS = {
    "auto (points)": lambda A, p, B: solve("auto", A, p),
    "auto (points + orientations)": lambda A, p, B: solve("auto", A, B),
    "YKronT'+ML (paper model)": lambda A, p, B: solve("YKronT'", A, p, refine=True),
    "YKronT' (closed form)": lambda A, p, B: closed_form("YKronT'", A, p),
    "YQuatT' (closed form)": lambda A, p, B: closed_form("YQuatT'", A, B),
}


@dataclasses.dataclass
class _RealisticTally:
    """What `section_realistic` collects over its cells."""

    errs: dict = dataclasses.field(default_factory=dict)          # (estimator, cell) -> [(translation, workspace)]
    bound: dict = dataclasses.field(default_factory=lambda: {key: [] for key in ("ext", "ext_rot", "ext_depth",
                                                                                   "gen")})
    nees_auto: list = dataclasses.field(default_factory=list)
    nees_shared: dict = dataclasses.field(default_factory=lambda: {"points": [], "points + orientations": []})
    est: dict = dataclasses.field(default_factory=dict)           # camera parameter -> estimated values


def _realistic_cell(seed: int, prof, n: int, tally: _RealisticTally) -> None:
    """One realistic cell and its bias-free twin: bounds and every estimator's errors into ``tally``."""
    cells = {"real": simulate.realistic_profile(n, np.random.default_rng(seed), prof),
             "bias-free": simulate.realistic_profile(n, np.random.default_rng(seed), prof.bias_free())}
    real = cells["real"]
    d = real.data
    P = {k: simulate.workspace_points(c, WORKSPACE_POINTS, np.random.default_rng([seed, 1]))
         for k, c in cells.items()}
    seen = tf.transform_points(tf.invert(d.Y), P["real"])
    covs = {"ext": extended_cov(d, real.robot_rms_m),
            "ext_rot": extended_cov(d, real.robot_rms_m, prof.orientation_noise_rad),
            "ext_depth": extended_cov(d, real.robot_rms_m, free=(True, True, False)),
            "gen": generating_cov(real, prof)}
    for key, cov in covs.items():
        tally.bound[key].append((translation_rms(cov), workspace_rms(cov, d.Y, seen)))
    for name, fn in REALISTIC_ESTIMATORS.items():
        for label, cell in cells.items():
            dd = cell.data
            res = fn(dd.A, dd.points, dd.B)
            tally.errs.setdefault((name, label), []).append(
                (np.linalg.norm(error_vector(res.Y, dd.Y)[3:]),
                 workspace_error(res.Y, res.camera_correction, cell, P[label])))
            if name == "auto (points)" and label == "real":
                tally.nees_auto.append(nees(res.Y, d.Y, res.cov))
                # On the camera's uncorrected points (what a URDF or tf gets): T_base_cam alone, and the
                # transform with the correction folded in that the exports carry.
                for what, T in (("T_base_cam", res.Y),
                                ("camera_transform_raw_points", res.camera_transform_raw_points)):
                    tally.errs.setdefault((f"auto (points): {what} on uncorrected points", label), []).append(
                        (np.nan, workspace_error(T, model.CameraCorrection(), cell, P[label])))
                # With the robot's kinematic error as what it is: shared by all samples (joints known).
                F = prof.dh_error_factor(real.q)
                for kind, B in (("points", d.points), ("points + orientations", d.B)):
                    shared = solve("auto", d.A, B, robot_shared_error=F)
                    tally.nees_shared[kind].append(nees(shared.Y, d.Y, shared.cov))
                for k, v in res.auto.camera_correction.items():
                    tally.est.setdefault(k, []).append(v.value if v.estimated else np.nan)


def section_realistic(rng, trials: int, n: int = 30) -> str:
    """Realistic profile: error of each estimator against the bounds and the bias-free cell, in two measures.

    The camera translation (``T_base_cam``), and the workspace error: where
    the calibrated camera (``T_base_cam`` with the camera correction it
    estimated) puts held-out marker points of the same workspace.
    """
    prof = simulate.RealisticProfile()
    tally = _RealisticTally()
    for _ in range(trials):
        _realistic_cell(int(rng.integers(1 << 31)), prof, n, tally)
    errs, bound, nees_auto, nees_shared, est = tally.errs, tally.bound, tally.nees_auto, tally.nees_shared, tally.est
    b = {key: np.sqrt(np.mean(np.square(v), axis=0)) for key, v in bound.items()}     # (translation, workspace)
    tables = {0: [], 1: []}
    for name in dict.fromkeys(k[0] for k in errs):
        e = np.sqrt(np.mean(np.square(errs[(name, "real")]), axis=0))
        e0 = np.sqrt(np.mean(np.square(errs[(name, "bias-free")]), axis=0)) if (name, "bias-free") in errs else None
        ext = b["ext_rot"] if "orientations" in name or "YQuat" in name else b["ext"]
        for m in (0, 1):
            if np.isnan(e[m]):
                continue
            free_cols = [f"{e0[m] * 1e3:.2f}", f"{e[m] / e0[m]:.2f}"] if e0 is not None else ["-", "-"]
            tables[m].append([name, f"{e[m] * 1e3:.2f}", *free_cols, f"{e[m] / ext[m]:.2f}",
                              f"{e[m] / b['ext_depth'][m]:.2f}", f"{e[m] / b['gen'][m]:.2f}"])
    truth = {"depth_scale": prof.depth_scale, "depth_offset": prof.depth_offset, "focal_scale": prof.focal_scale}
    chosen = ", ".join(f"{k} in {np.mean(np.isfinite(v)) * 100:.0f}% (mean {np.nanmean(v) if np.isfinite(v).any() else 0:+.4f},"
                       f" true {truth[k]:+.4f})" for k, v in est.items())
    ratios = ["ratio to bias-free", "ratio to extended CRLB (depth + focal)", "ratio to CRLB (depth only)",
              "ratio to bound of the generating model"]
    bounds_line = (lambda m: f"extended model {b['ext'][m] * 1e3:.2f} mm from points, {b['ext_rot'][m] * 1e3:.2f} mm "
                   f"with orientations, {b['ext_depth'][m] * 1e3:.2f} mm with the focal length known; generating "
                   f"model {b['gen'][m] * 1e3:.2f} mm")
    return "\n".join([
        f"### Realistic profile (N = {n}, {trials} cells; UR10 DH error: joint zero offsets {prof.joint_offset_deg}°, "
        f"links {prof.link_length_m * 1e3:.1f} mm, twists {prof.twist_deg}° (1σ); repeatability "
        f"{prof.repeatability_m * 3e3:.1f} mm (3σ); depth scale {prof.depth_scale * 100:.1f}%, offset "
        f"{prof.depth_offset * 1e3:.0f} mm, focal {prof.focal_scale * 100:.0f}%, misregistration "
        f"{prof.misregistration_px:.0f} px; camera 0.8 m away)",
        "",
        "#### The camera's position: error of T_base_cam's translation",
        "",
        markdown_table(["estimator", "RMS error [mm]", "same, bias-free cell [mm]", *ratios], tables[0]),
        "",
        f"#### The workspace: where the calibrated camera puts a marker point ({WORKSPACE_POINTS} held-out poses of "
        "the same joint span per cell, seen with the camera's depth and focal error but no noise or "
        "misregistration, T_base_cam with the camera correction it estimated)",
        "",
        markdown_table(["estimator", "RMS error [mm]", "same, bias-free cell [mm]", *ratios], tables[1]),
        "",
        f"Bounds (RMS over cells), camera translation: {bounds_line(0)}; workspace: {bounds_line(1)}. Extended "
        "model: the robot error taken as white at its simulated RMS. Generating model (`generating_cov`): DH error, "
        "focal scale and misregistration as unknowns with the profile's magnitudes as prior 1-sigma, depth scale "
        "and offset free. "
        f"NEES of `auto (points)`: mean {np.mean(nees_auto):.2f} ± {np.std(nees_auto) / np.sqrt(len(nees_auto)):.2f} "
        f"(standard error; 6 if honest), median {np.median(nees_auto):.2f}. With the joint angles, the DH error "
        "given to `auto` as an error shared by all samples (`robot_shared_error=handeye.calib.robot_error.ur_dh_error_factor(q, ...)`, "
        "the profile's magnitudes): NEES "
        + ", ".join(f"{k} {np.mean(v):.2f} ± {np.std(v) / np.sqrt(len(v)):.2f}" for k, v in nees_shared.items())
        + f". Camera parameters estimated: {chosen}.",
    ])


#: Effects of the realistic profile that `section_effects` switches off one at a time (fields set to zero).
EFFECTS = {
    "robot DH error": ("joint_offset_deg", "link_length_m", "twist_deg"),
    "repeatability": ("repeatability_m", "repeatability_rad"),
    "depth scale": ("depth_scale",),
    "depth offset": ("depth_offset",),
    "focal scale": ("focal_scale",),
    "misregistration": ("misregistration_px",),
}


def section_effects(rng, trials: int, n: int = 30) -> str:
    """Which unmodelled effect makes `auto` miss the bias-free error: each switched off, and each alone."""
    base = simulate.RealisticProfile()
    off = {name: {f: 0.0 for f in fields} for name, fields in EFFECTS.items()}
    variants = [("all effects", {}), ("none (repeatability only)", {k: v for name, o in off.items()
                                                                    if name != "repeatability" for k, v in o.items()})]
    variants += [(f"all but {name}", o) for name, o in off.items()]
    variants += [(f"{name} only", {k: v for other, o in off.items() if other not in (name, "repeatability")
                                   for k, v in o.items()}) for name in EFFECTS if name != "repeatability"]
    seeds = [int(rng.integers(1 << 31)) for _ in range(trials)]
    rows, ref = [], None
    for label, changes in variants:
        prof = dataclasses.replace(base, **changes)
        err, err_depth, nees_v, err_ws = [], [], [], []
        for seed in seeds:
            cell = simulate.realistic_profile(n, np.random.default_rng(seed), prof)
            d = cell.data
            res = solve("auto", d.A, d.points)
            err.append(np.linalg.norm(error_vector(res.Y, d.Y)[3:]))
            P = simulate.workspace_points(cell, WORKSPACE_POINTS, np.random.default_rng([seed, 1]))
            err_ws.append(workspace_error(res.Y, res.camera_correction, cell, P))
            nees_v.append(nees(res.Y, d.Y, res.cov))
            err_depth.append(np.linalg.norm(error_vector(solve("auto", d.A, d.points, camera_correction="depth").Y,
                                                         d.Y)[3:]))
        e = np.array([_rms(err), _rms(err_ws)])
        ref = e if label.startswith("none") else ref
        rows.append([label, e, f"{_rms(err_depth) * 1e3:.2f}",
                     f"{np.mean(nees_v):.2f} ± {np.std(nees_v) / np.sqrt(len(nees_v)):.2f}"])
    for r in rows:
        e = r.pop(1)
        r[1:1] = [f"{e[0] * 1e3:.2f}", f"{e[0] / ref[0]:.2f}", f"{e[1] * 1e3:.2f}", f"{e[1] / ref[1]:.2f}"]
    return "\n".join([
        f"### Realistic profile, one effect at a time (N = {n}, the same {trials} cells in every row; marker points)",
        "",
        markdown_table(["systematic errors present", "auto: RMS error T_base_cam [mm]", "ratio to none",
             "auto: workspace error [mm]", "ratio to none", "auto, camera_correction=\"depth\": T_base_cam [mm]",
             "NEES of auto (± s.e.)"], rows),
    ])


def section_board(rng, trials: int, n: int = 8) -> str:
    names = ["auto"] + POSE_METHODS + list(OPENCV_HAND_EYE) + list(OPENCV_ROBOT_WORLD)
    errs = {m: [] for m in names}
    for _ in range(trials):
        d = simulate.realistic_cell(n, rng, pose_noise=(np.deg2rad(0.2), 0.002), sigma_lateral=0.0005,
                                    sigma_depth=0.002)
        for m in names:
            try:
                if m == "auto":
                    Y = solve("auto", d.A, d.B).Y
                else:
                    Y = run_solver(m, d.A, d.B)[1]
            except (CalibrationError, cv2.error):
                errs[m].append(np.nan)
                continue
            errs[m].append(np.linalg.norm(error_vector(Y, d.Y)[3:]))
    rows = sorted(([m, f"{_rms(np.nan_to_num(e, nan=1.0)) * 1e3:.2f}", f"{np.nanmedian(e) * 1e3:.2f}",
                    int(np.isnan(e).sum())] for m, e in errs.items() for e in [np.array(e)]),
                  key=lambda r: float(r[1]))
    return "\n".join([
        f"### Eight board poses with good orientations ({trials} cells; orientation noise 0.2°, "
        "point noise 0.5 mm lateral / 2 mm along the ray)",
        "",
        markdown_table(["solver", "RMS error T_base_cam [mm]", "median [mm]", "failures"], rows),
    ])


def section_flips(rng, trials: int, n: int = 19) -> str:
    prof = simulate.RealisticProfile(flip_fraction=0.3)
    found, total, e_auto, r_quat, r_auto = 0, 0, [], [], []
    for _ in range(trials):
        real = simulate.realistic_profile(n, rng, prof)
        d = real.data
        res = solve("auto", d.A, d.B)
        flips = res.auto.flips or {"flipped": []}
        found += len(set(flips["flipped"]) & set(real.flipped.tolist()))
        total += len(real.flipped)
        e_auto.append(np.linalg.norm(error_vector(res.Y, d.Y)[3:]))
        r_auto.append(res.residuals.max_translation)
        r_quat.append(closed_form("YQuatT'", d.A, d.B).residuals.max_translation)
    return "\n".join([
        f"### Symmetric board: {prof.flip_fraction:.0%} of {n} marker poses half-turned ({trials} cells, realistic profile)",
        "",
        markdown_table(["", "value"], [
            ["flips found by auto", f"{found} / {total}"],
            ["auto: RMS error T_base_cam [mm]", f"{_rms(e_auto) * 1e3:.2f}"],
            ["auto: median max residual [mm]", f"{np.median(r_auto) * 1e3:.1f}"],
            ["YQuatT' without the fix: median max residual [mm]", f"{np.median(r_quat) * 1e3:.1f}"],
        ]),
    ])


#: Short names of the camera parameters in the real-set table.
_SHORT = {"depth_scale": "scale", "depth_offset": "offset", "focal_scale": "focal"}


def section_real(quick: bool) -> str:
    with tempfile.TemporaryDirectory(prefix="handeye-bench-") as work:
        return _real_rows(quick, Path(work))


def uncorrected_heldout(A, B, setup: str, folds: int | None) -> tuple[float, float]:
    """Held-out RMS (m) of the marker point for a consumer of `auto`'s rigid-only exports, and without them.

    Each fold's `CalibrationResult.camera_transform_raw_points` predicts the
    held-out samples' uncorrected points from the robot, with no camera
    correction: what a URDF or tf plus the camera's raw points give. Second,
    the same with the fold's ``camera_transform`` (the correction dropped).
    """
    p = B if B.ndim == 2 else B[:, :3, 3]
    errors = {"raw_points": [], "camera": []}
    for test in fold_indices(len(A), folds):
        train = np.setdiff1d(np.arange(len(A)), test)
        res = solve("auto", A[train], B[train], setup=setup)
        _, K, M = model.split(res.X, res.Y, A[test], setup)
        # The model's camera transform C is the camera transform in both setups.
        for kind, C in (("raw_points", res.camera_transform_raw_points), ("camera", res.camera_transform)):
            errors[kind].append(p[test] - model.predict_points(C, K[:3, 3], M))
    return tuple(_rms(np.linalg.norm(np.concatenate(errors[k]), axis=1)) for k in ("raw_points", "camera"))


def _real_rows(quick: bool, work: Path) -> str:
    rows = []
    for name, imp in real_sets(work):
        A, B, setup = imp.A, imp.B, imp.setup
        n = len(A)
        folds = None if n <= 60 else 10
        if quick and n > 60:
            continue
        cvs = {}
        for m in ["YKronT'", "YQuatT'", "YKronRT", "YQuatR*", "YAxisR", "XKronRT"]:
            try:
                cvs[m] = cross_validate(m, A, B, setup=setup, folds=folds)
            except CalibrationError:
                pass
        ml = cross_validate("YKronT'", A, B, setup=setup, folds=folds, refine=True)
        auto_res = solve("auto", A, B, setup=setup)
        auto = cross_validate("auto", A, B, setup=setup, folds=folds)
        best = min(cvs, key=lambda k: cvs[k].observed_rms)
        start = auto_res.auto.start.split("+")[0]
        start_cv = cvs.get(start)
        ok = "yes" if auto.observed_rms <= cvs[best].observed_rms else "**no**"
        within = "yes" if 1 / 1.5 <= auto.ratio <= 1.5 else "**no**"
        rows.append([
            name, n, "LOO" if folds is None else f"{folds}-fold",
            f"{auto.observed_rms * 1e3:.2f} / {auto.predicted_rms * 1e3:.2f} ({auto.ratio:.2f}, {within})",
            f"{best} {cvs[best].observed_rms * 1e3:.2f}",
            ok,
            f"{start} {start_cv.observed_rms * 1e3:.2f}" if start_cv else start,
            f"{ml.observed_rms * 1e3:.2f} / {ml.predicted_rms * 1e3:.2f}",
            " / ".join(f"{e * 1e3:.2f}" for e in uncorrected_heldout(A, B, setup, folds)),
            ", ".join(f"{_SHORT[k]} {v.value * (1e3 if k == 'depth_offset' else 100):+.2f}"
                      f"{'mm' if k == 'depth_offset' else '%'}"
                      for k, v in auto_res.auto.camera_correction.items() if v.estimated) or "none",
            " + ".join(auto_res.auto.measurements),
        ])
    if not rows:
        return f"### Real recordings: none found under {datasets_dir()} (set HANDEYE_DATASETS)"
    return "\n".join([
        "### Real recordings: held-out prediction error of the marker point [mm]",
        "",
        markdown_table(["set", "N", "folds", "auto observed / predicted (ratio, within 1.5x)", "best closed form",
             "auto <= best", "auto's start", "YKronT'+ML observed / predicted",
             "uncorrected points: auto's export / its camera_transform", "camera correction", "used"], rows),
    ])


def section_plain(rng, trials: int, n: int = 30) -> str:
    err, bound = [], []
    for _ in range(trials):
        d = simulate.realistic_cell(n, rng)
        res = solve("YKronT'", d.A, d.points, refine=True, point_cov=d.point_cov)
        err.append(np.linalg.norm(error_vector(res.Y, d.Y)[3:]))
        bound.append(cramer_rao_bound(d.X, d.Y, d.A, d.point_cov, setup=Setup.EYE_TO_HAND)[1])
    e, b = _rms(err), _rms(bound)
    return (f"### Plain cell (paper model, N = {n}, {trials} cells): YKronT'+ML {e * 1e3:.3f} mm RMS, "
            f"CRLB {b * 1e3:.3f} mm, ratio {e / b:.3f}")


def _times_ms(fn, repeats: int) -> tuple[float, float, float, float]:
    """Wall-clock and process CPU time of ``fn`` (ms): min and median over ``repeats`` after one warm-up call.

    CPU time is the steadier figure on a shared machine (it leaves out the
    time the process waited for a core); min of either is the usual one.
    """
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return tuple(1e3 * float(f(v)) for v in (wall, cpu) for f in (np.min, np.median))


def section_speed(rng, repeats: int, n: int = 1000) -> str:
    d = simulate.realistic_cell(n, rng)
    p = d.points * 1.015
    cases = [
        ("YKronT' closed form (handeye.calib.solvers.y_kron_t_prime)", lambda: solvers.y_kron_t_prime(d.A, p)),
        ("solve(\"YKronT'\") with covariance and self-check", lambda: solve("YKronT'", d.A, p)),
        ("solve(\"auto\") points, with covariance and self-check", lambda: solve("auto", d.A, p)),
        ("solve(\"auto\") points and their covariances (as the app passes them)",
         lambda: solve("auto", d.A, p, point_cov=d.point_cov)),
        ("solve(\"auto\") poses, with covariance and self-check", lambda: solve("auto", d.A, d.B)),
    ]
    rows = [[name] + [f"{v:.2f}" for v in _times_ms(fn, repeats)] for name, fn in cases]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return "\n".join([f"### Speed at N = {n} (one thread, {repeats} repeats; load average {load:.1f} at the end)", "",
                       markdown_table(["what", "wall min [ms]", "wall median [ms]", "CPU min [ms]", "CPU median [ms]"], rows)])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.model", description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="few trials, small real sets only")
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    t = 3 if args.quick else 1
    t0 = time.perf_counter()
    parts = [
        "## Measurement model and solve(\"auto\") (`python -m bench --model`)",
        # 200 cells: the bias-free ratio is a ratio of two noisy RMS values (+-3% at 200, +-8% at 40).
        section_realistic(rng, 200 // t // (2 if args.quick else 1)),
        # Its own stream, so the cells of the sections after it are those of runs without it.
        section_effects(np.random.default_rng([args.seed, 1]), 40 // t // (2 if args.quick else 1)),
        section_board(rng, 60 // t),
        section_flips(rng, 20 // t),
        section_real(args.quick),
        section_plain(rng, 200 // t),
        section_speed(rng, 5 if args.quick else 15),
    ]
    parts.append(f"_{time.perf_counter() - t0:.0f} s, seed {args.seed}{', --quick' if args.quick else ''}_")
    text = "\n\n".join(parts) + "\n"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "model.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
