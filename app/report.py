"""``report.html``: one self-contained page per run that a user can hand over (no network, plots inline SVG).

Written by ``calibrate``, ``replay --out`` and ``verify`` (`write_report`) from
the result document (`app.formats.result_to_dict`, i.e. ``result.yaml``), the
calibration samples, and the verification (``verify.yaml``) when there is one:

- setup and frames drawn (base, camera, the flange at each sample, the marker);
- pose coverage of the workspace (flange positions, calibration and verification);
- residuals per sample (marker measured minus predicted, base frame, mm);
- the error ellipsoid of the camera transform (1-sigma, translation, three views);
- held-out prediction (the result's self-check; the verification poses);
- the camera correction with its 1-sigma;
- the verification table; warnings in plain words.

Eye-to-hand: ``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand:
``X = T_flange_cam``, ``Y = T_base_marker`` (paper eq. 1).
"""

from __future__ import annotations

import datetime as _dt
import html
import io
from pathlib import Path

import numpy as np

from calib.observation import Observation
from calib.setup import Setup

REPORT_NAME = "report.html"
#: Marker (class) of every plot's container: the browser test counts them.
PLOT_CLASS = "plot"

_STYLE = """
body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}
h1{font-size:1.5em}h2{font-size:1.15em;margin-top:2em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right}
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}
.pass{color:#fff;background:#2a7d2a;padding:.3em .8em;border-radius:4px;font-weight:bold}
.fail{color:#fff;background:#b22;padding:.3em .8em;border-radius:4px;font-weight:bold}
.warn{background:#fff4d6;border-left:4px solid #e0a000;padding:.4em .8em;margin:.3em 0}
.plot svg{max-width:100%;height:auto}.note{color:#555;font-size:.9em}
"""


def _svg(fig) -> str:
    """A matplotlib figure as inline SVG (no XML header), closed afterwards."""
    import matplotlib.pyplot as plt

    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight")
    plt.close(fig)
    text = buf.getvalue()
    return text[text.index("<svg"):]


def _figure(*args, **kwargs):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # Text as paths would triple the size; the page names no fonts it lacks.
    plt.rcParams["svg.fonttype"] = "none"
    return plt.subplots(*args, **kwargs)


def _plot(title: str, svg: str, note: str = "") -> str:
    return (f'<div class="{PLOT_CLASS}" data-title="{html.escape(title)}"><h3>{html.escape(title)}</h3>{svg}'
            + (f'<p class="note">{html.escape(note)}</p>' if note else "") + "</div>")


def _table(head: list[str], rows: list[list]) -> str:
    cells = "".join(f"<th>{html.escape(str(h))}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{cells}</tr>{body}</table>"


def _axes(ax, T, name: str, length: float) -> None:
    o = T[:3, 3]
    for k, color in enumerate(("r", "g", "b")):
        e = o + T[:3, k] * length
        ax.plot([o[0], e[0]], [o[1], e[1]], [o[2], e[2]], color=color, lw=2)
    ax.text(*o, " " + name, fontsize=9)


def frames_plot(model, observations: list[Observation], verify_obs: list[Observation]) -> str:
    """3D view of the setup: base and camera frames, the flange at each sample, the marker."""
    fig = _figure(figsize=(6.5, 5.5), subplot_kw={"projection": "3d"})[0]
    ax = fig.axes[0]
    A = np.array([o.T_base_flange for o in observations]) if observations else np.zeros((0, 4, 4))
    span = max(float(np.ptp(A[:, :3, 3], axis=0).max()) if len(A) else 0.0, 0.3)
    L = span / 6
    _axes(ax, np.eye(4), "base", L)
    if model.setup == Setup.EYE_TO_HAND:
        _axes(ax, model.Y, "camera", L)
        marker = (A @ model.X)[:, :3, 3] if len(A) else np.zeros((0, 3))
    else:
        _axes(ax, model.Y, "marker", L)
        if len(A):
            _axes(ax, A[0] @ model.X, "camera (sample 0)", L)
        marker = np.broadcast_to(model.Y[:3, 3], (len(A), 3))
    if len(A):
        ax.scatter(*A[:, :3, 3].T, s=12, c="tab:blue", label="flange (calibration)")
        if model.setup == Setup.EYE_TO_HAND:
            ax.scatter(*marker.T, s=6, c="tab:orange", label="marker")
    if verify_obs:
        V = np.array([o.T_base_flange[:3, 3] for o in verify_obs])
        ax.scatter(*V.T, s=20, c="tab:green", marker="^", label="flange (verification)")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.legend(fontsize=8, loc="upper left")
    return _svg(fig)


def coverage_plot(observations: list[Observation], verify_obs: list[Observation]) -> str:
    """Flange positions in the base frame, three projections: how the samples cover the workspace."""
    fig, axs = _figure(1, 3, figsize=(11, 3.6))
    sets = [("calibration", observations, "tab:blue", "o"), ("verification", verify_obs, "tab:green", "^")]
    for ax, (i, j) in zip(axs, ((0, 1), (0, 2), (1, 2))):
        for label, obs, color, mark in sets:
            if obs:
                P = np.array([o.T_base_flange[:3, 3] for o in obs]) * 1e3
                ax.scatter(P[:, i], P[:, j], s=14, c=color, marker=mark, label=label)
        ax.set_xlabel("xyz"[i] + " [mm]")
        ax.set_ylabel("xyz"[j] + " [mm]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    axs[0].legend(fontsize=8)
    fig.tight_layout()
    return _svg(fig)


def residual_plot(errors_mm: np.ndarray, title: str, tolerance_mm: float | None = None) -> str:
    """Bar per sample: marker measured minus predicted, base frame, mm (and the tolerance line)."""
    fig, ax = _figure(figsize=(9, 3.2))
    ax.bar(np.arange(len(errors_mm)), errors_mm, color="tab:blue")
    if tolerance_mm is not None:
        ax.axhline(tolerance_mm, color="tab:red", ls="--", label=f"tolerance {tolerance_mm:g} mm")
        ax.legend(fontsize=8)
    ax.set_xlabel("sample" if tolerance_mm is None else "verification pose")
    ax.set_ylabel(title)
    ax.grid(alpha=0.3, axis="y")
    return _svg(fig)


def ellipsoid_plot(cov_t_m: np.ndarray) -> str:
    """1-sigma error ellipse of the camera translation in the xy, xz and yz planes of its parent frame, mm."""
    fig, axs = _figure(1, 3, figsize=(10, 3.4))
    C = np.asarray(cov_t_m, dtype=float) * 1e6
    s = np.linspace(0, 2 * np.pi, 100)
    for ax, (i, j) in zip(axs, ((0, 1), (0, 2), (1, 2))):
        sub = C[np.ix_([i, j], [i, j])]
        w, V = np.linalg.eigh(sub)
        pts = V @ (np.sqrt(np.maximum(w, 0))[:, None] * np.stack([np.cos(s), np.sin(s)]))
        ax.plot(pts[0], pts[1], color="tab:purple")
        ax.plot(0, 0, "k+")
        r = max(float(np.abs(pts).max()), 1e-3) * 1.2
        ax.set_xlim(-r, r)
        ax.set_ylim(-r, r)
        ax.set_aspect("equal")
        ax.set_xlabel("d" + "xyz"[i] + " [mm]")
        ax.set_ylabel("d" + "xyz"[j] + " [mm]")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return _svg(fig)


def correction_plot(cc: dict) -> str:
    """The camera correction's parameters with their 1-sigma error bars (% and mm, as labelled)."""
    fig, ax = _figure(figsize=(6, 2.8))
    names = list(cc)
    vals = [cc[n]["value"] for n in names]
    sig = [cc[n]["sigma"] for n in names]
    colors = ["tab:blue" if cc[n]["estimated"] else "tab:gray" for n in names]
    ax.barh(np.arange(len(names)), vals, xerr=sig, color=colors, capsize=4)
    ax.set_yticks(np.arange(len(names)), [n.replace("_percent", " [%]").replace("_mm", " [mm]") for n in names])
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("value ± 1-sigma (gray: not estimated, kept at zero)")
    ax.grid(alpha=0.3, axis="x")
    return _svg(fig)


def write_report(directory: Path, *, result_doc: dict, observations: list[Observation] | None = None,
                 verify_doc: dict | None = None, verify_observations: list[Observation] | None = None,
                 warnings: list[str] | None = None, title: str = "handeye calibration report") -> Path:
    """Write ``directory/report.html`` (module docstring); returns its path.

    ``result_doc``: the result document (``result.yaml``'s content); ``observations``:
    the calibration samples; ``verify_doc`` / ``verify_observations``: a verification
    and the per-pose samples it judged; ``warnings``: sentences to show besides
    those the documents carry.
    """
    from app.verify import models_of

    observations = list(observations or [])
    verify_observations = list(verify_observations or [])
    model, _ = models_of(result_doc, Path(directory) / "result")
    mdl = result_doc.get("model") or {}
    parts = [f"<h1>{html.escape(title)}</h1>", _verdict(verify_doc)]
    parts += _result_section(result_doc, len(observations))
    parts += _warnings_section(warnings, mdl, verify_doc)
    parts += _plots_section(model, result_doc["camera_transform"], observations, verify_observations)
    parts += _heldout_section(mdl, verify_doc)
    parts += _correction_section(mdl)
    if verify_doc is not None:
        parts.append("<h2>Verification</h2>" + _verification_table(verify_doc))
    page = ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>"
            + "".join(parts) + "</body></html>\n")
    path = Path(directory) / REPORT_NAME
    path.write_text(page, encoding="utf-8")
    return path


def _verdict(verify_doc: dict | None) -> str:
    """The PASS/FAIL line of a verification ("" without one)."""
    if verify_doc is None:
        return ""
    v = verify_doc["verification"]
    return (f'<p><span class="{"pass" if v["passed"] else "fail"}">{"PASS" if v["passed"] else "FAIL"}</span> '
            f'calibration error {v["calibration_error_mm"]:.2f} mm against the tolerance '
            f'{v["tolerance_mm"]:g} mm / {v["tolerance_deg"]:g} deg ({verify_doc["mode"]}, '
            f'{v["n_poses"]} poses)</p>')


def _result_section(result_doc: dict, n_observations: int) -> list[str]:
    """Setup, solver, samples, the camera transform with its 1-sigma, residual RMS."""
    setup = Setup(result_doc["setup"])
    cam = result_doc["camera_transform"]
    xyz = np.array(cam["translation_m"]) * 1e3
    summary = [["setup", f"{setup.value}: {setup.equation}"], ["solver", result_doc.get("solver", "")],
               ["samples", result_doc.get("n_samples", n_observations)],
               [f"{cam['name']} xyz [mm]", " ".join(f"{x:.2f}" for x in xyz)],
               [f"{cam['name']} quaternion (x, y, z, w)", " ".join(f"{q:.5f}" for q in cam["quaternion_xyzw"])],
               ["residual RMS [mm] (camera frame)", f"{result_doc['residuals']['rms_translation_mm']:.2f}"]]
    if "sigma_1" in cam:
        summary.append(["1-sigma per axis [mm]", " ".join(f"{s:.2f}" for s in cam["sigma_1"]["translation_mm"])])
        summary.append(["1-sigma per axis [deg]", " ".join(f"{s:.3f}" for s in cam["sigma_1"]["rotation_deg"])])
    summary.append(["written", _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")])
    return ["<h2>Result</h2>", _table(["quantity", "value"], summary)]


def _warnings_section(warnings: list[str] | None, mdl: dict, verify_doc: dict | None) -> list[str]:
    """The caller's warnings, the model's self-check and notes, and what a failed verification means."""
    notes = list(warnings or [])
    check = mdl.get("self_check") or {}
    if check.get("warning"):
        notes.append(check["warning"])
    notes += list(mdl.get("notes") or [])
    if verify_doc is not None:
        notes += list((verify_doc.get("frame_safety") or {}).get("warnings", []))
        if not verify_doc["verification"]["passed"]:
            notes.append("the verification failed: the result predicts the marker worse than the tolerance on poses "
                         "it did not see; recalibrate (more samples, more rotation between them) or check that the "
                         "camera did not move")
        rig = verify_doc.get("rigid_export")
        if rig is not None and not rig["passed"]:
            notes.append("the ROS/URDF exports (a rigid transform for uncorrected points) fail the tolerance: a "
                         "consumer without the camera correction sees larger errors")
    return ["<h2>Warnings</h2>",
            "".join(f'<div class="warn">{html.escape(n)}</div>' for n in notes) or "<p>none</p>"]


def _plots_section(model, cam: dict, observations: list[Observation],
                   verify_observations: list[Observation]) -> list[str]:
    """Frames, pose coverage, residuals per sample and the error ellipsoid of the camera transform."""
    from app.verify import pose_errors

    parts = ["<h2>Setup and frames</h2>",
             _plot("setup and frames (base frame, m; axes x red, y green, z blue)",
                   frames_plot(model, observations, verify_observations)),
             "<h2>Pose coverage</h2>",
             _plot("flange positions in the base frame", coverage_plot(observations, verify_observations),
                   "the spread of positions and orientations determines the camera transform; a verification "
                   "inside the calibration's region judges interpolation, outside it extrapolation")]
    if observations:
        e = np.linalg.norm(pose_errors(model, observations).translation, axis=1) * 1e3
        parts.append("<h2>Residuals per sample</h2>")
        parts.append(_plot("residual per calibration sample [mm] (base frame)", residual_plot(e, "residual [mm]"),
                           f"RMS {np.sqrt(np.mean(e**2)):.2f} mm, max {e.max():.2f} mm: the samples the result was "
                           "fitted to, so these understate its error on new poses"))
    if "covariance" in cam:
        C = np.array(cam["covariance"]["matrix"])
        parts.append("<h2>Error ellipsoid of the camera transform</h2>")
        parts.append(_plot(f"1-sigma error ellipse of the {cam['name']} translation [mm]", ellipsoid_plot(C[3:, 3:]),
                           "the translation block of the result's covariance, projected on the parent frame's planes"))
    elif "sigma_1" in cam:
        s = np.array(cam["sigma_1"]["translation_mm"]) * 1e-3
        parts.append("<h2>Error ellipsoid of the camera transform</h2>")
        parts.append(_plot(f"1-sigma error ellipse of the {cam['name']} translation [mm] (axes only)",
                           ellipsoid_plot(np.diag(s**2))))
    return parts


def _heldout_section(mdl: dict, verify_doc: dict | None) -> list[str]:
    """Held-out prediction: leave-one-out, blocked folds, the verification poses (and their error plot)."""
    check = mdl.get("self_check") or {}
    parts = ["<h2>Held-out prediction</h2>"]
    rows = []
    if check:
        rows.append(["leave-one-out over the calibration samples (camera frame)",
                     f"{check['heldout_observed_mm']:.2f}", f"{check['heldout_predicted_mm']:.2f}"])
    for c in (mdl.get("blocked_folds") or {}).get("candidates", []):
        what = (f"closed form {c['closed_form']}" if "closed_form" in c else
                ("points + orientations" if c["orientations"] else "points") + ", camera correction: "
                + (", ".join(c["camera_correction"]) or "none"))
        rows.append([f"contiguous stretches held out in turn ({mdl['blocked_folds']['folds']} folds): {what}",
                     f"{c['heldout_mm']:.2f}", "-"])
    if verify_doc is not None:
        v = verify_doc["verification"]
        rows.append([f"verification poses ({verify_doc['mode']}, base frame, observed RMS)",
                     f"{v['observed_mm']['rms']:.2f}",
                     "-" if v["measurement_noise_rms_mm"] is None else f"{v['measurement_noise_rms_mm']:.2f} (noise)"])
    parts.append(_table(["prediction of samples not fitted", "observed [mm]", "predicted [mm]"], rows) if rows
                 else "<p>no held-out prediction for this solver</p>")
    if verify_doc is not None:
        v = verify_doc["verification"]
        parts.append(_plot("error per verification pose [mm] (base frame, noise included)",
                           residual_plot(np.array(v["per_pose_mm"]), "error [mm]", v["tolerance_mm"])))
    return parts


def _correction_section(mdl: dict) -> list[str]:
    """The camera correction's table and plot (or why there is none)."""
    cc = mdl.get("camera_correction")
    parts = ["<h2>Camera correction</h2>"]
    if cc:
        parts.append(_table(["parameter", "value", "1-sigma", "estimated"],
                            [[k, f"{c['value']:+.3f}", f"{c['sigma']:.3f}", "yes" if c["estimated"] else "no"]
                             for k, c in cc.items()]))
        parts.append(_plot("camera correction ± 1-sigma", correction_plot(cc),
                           "measured depth (1 + scale) z + offset, lateral coordinates scaled by (1 + focal scale); "
                           "the ROS/URDF exports carry camera_transform_raw_points, the correction folded in"))
    else:
        parts.append("<p>none: this solver estimates no camera correction</p>")
    return parts


def _verification_table(doc: dict) -> str:
    v = doc["verification"]
    o = v["observed_mm"]
    rows = [["poses", v["n_poses"]], ["observed error [mm] mean / p95 / max",
                                      f"{o['mean']:.2f} / {o['p95']:.2f} / {o['max']:.2f}"]]
    if v["observed_deg"] is not None:
        d = v["observed_deg"]
        rows.append(["observed error [deg] mean / p95 / max", f"{d['mean']:.3f} / {d['p95']:.3f} / {d['max']:.3f}"])
    lo, hi = v["calibration_error_ci95_mm"]
    rows.append(["calibration error [mm], noise removed (95 % interval)",
                 f"{v['calibration_error_mm']:.2f} [{lo:.2f}, {hi:.2f}]"])
    if v["calibration_error_deg"] is not None:
        lo, hi = v["calibration_error_ci95_deg"]
        rows.append(["calibration error [deg], noise removed (95 % interval)",
                     f"{v['calibration_error_deg']:.3f} [{lo:.3f}, {hi:.3f}]"])
    rows.append(["tolerance", f"{v['tolerance_mm']:g} mm / {v['tolerance_deg']:g} deg"])
    rows.append(["verdict", "PASS" if v["passed"] else "FAIL"])
    if "rigid_export" in doc:
        rows.append(["ROS/URDF export (uncorrected points): calibration error [mm]",
                     f"{doc['rigid_export']['calibration_error_mm']:.2f}"])
    if "truth" in doc:
        rows.append(["true calibration error over these poses [mm] (simulator)",
                     f"{doc['truth']['calibration_error_mm']:.2f}"])
    per = _table(["pose", "error [mm]", "error [deg]"],
                 [[i, f"{mm:.2f}", "-" if dg is None else f"{dg:.3f}"]
                  for i, (mm, dg) in enumerate(zip(v["per_pose_mm"], v["per_pose_deg"] or [None] * v["n_poses"]))])
    return _table(["quantity", "value"], rows) + per
