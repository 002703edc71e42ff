"""``report.html``: one self-contained page per run that a user can hand over (no network, plots inline SVG).

Written by ``calibrate``, ``replay --out`` and ``verify`` (`write_report`) from
the result document (`handeye.app.formats.result_to_dict`, i.e. ``result.yaml``), the
calibration samples, and the verification (``verify.yaml``) when there is one.
In this order, so that it reads from the answer down to the evidence:

- the verdict (`handeye.calib.verdict`: pass, warn or fail, the summary, each reason with its fix);
- the cell: site, cell, operator, robot and camera as their drivers named them, handeye's
  version and commit, the date and time (`handeye.app.provenance`);
- the camera transform in every form people paste (4x4, xyz + quaternion, xyz + rpy,
  URDF ``<origin>``, ``static_transform_publisher``), its frames, and its predicted accuracy;
- the marker as configured and the marker-side transform;
- the verification (verify): its errors, per pose, and what they are made of;
- setup and frames in 3D, pose coverage, residuals per sample, the error ellipses, the camera
  correction;
- a sign-off block (prepared by, checked by, date);
- an appendix with the statistics in their own terms (which transform goes with which points,
  chi-square, noise levels, the solver's decisions, held-out prediction): the pages before it
  are for a customer and say these things in plain words.

It prints on A4 or Letter (print CSS). Eye-to-hand: ``X = T_flange_marker``, ``Y = T_base_cam``;
eye-in-hand: ``X = T_flange_cam``, ``Y = T_base_marker`` (paper eq. 1).
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from handeye.calib.observation import Observation
from handeye.calib.setup import Setup
from handeye.app.page import REPORT_STYLE, Raw, figure, svg_of, table
from handeye.calib.verdict import bounded

REPORT_NAME = "report.html"
#: Marker (class) of every plot's container: the browser test counts them.
PLOT_CLASS = "plot"
#: Id of the verdict block, the first thing on the page.
VERDICT_ID = "verdict"

def _plot(title: str, svg: str, caption: str = "") -> str:
    """A figure: the SVG and one caption under it (the section's heading names it; no second heading)."""
    return (f'<figure class="{PLOT_CLASS}" data-title="{html.escape(title)}">{svg}'
            f'<figcaption>{html.escape(caption or title)}</figcaption></figure>')


def _code(text: str) -> "Raw":
    return Raw(f"<pre>{html.escape(text)}</pre>")


def _axes(ax, T, name: str, length: float, offset) -> None:
    o = T[:3, 3]
    for k, color in enumerate(("r", "g", "b")):
        e = o + T[:3, k] * length
        ax.plot([o[0], e[0]], [o[1], e[1]], [o[2], e[2]], color=color, lw=2)
    p = o + np.asarray(offset, dtype=float)
    ax.text(*p, name, fontsize=10, fontweight="bold", ha="center", va="bottom",
            bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "0.6", "alpha": 0.85})


def frames_plot(model, observations: list[Observation], verify_obs: list[Observation]) -> str:
    """3D view of the setup in the base frame (m): base and camera frames, the flange at each sample, the marker.

    The axes are scaled alike (a metre is as long on each), the frames' names stand above their origins
    (one label per frame, the samples in the legend), so that they do not overlap the points.
    """
    fig = figure(figsize=(9, 7.5), subplot_kw={"projection": "3d"})[0]
    ax = fig.axes[0]
    A = np.array([o.T_base_flange for o in observations]) if observations else np.zeros((0, 4, 4))
    frames = [(np.eye(4), "base")]
    if model.setup == Setup.EYE_TO_HAND:
        frames.append((model.Y, "camera"))
        marker = (A @ model.X)[:, :3, 3] if len(A) else np.zeros((0, 3))
    else:
        frames.append((model.Y, "marker"))
        if len(A):
            frames.append((A[0] @ model.X, "camera (sample 0)"))
        marker = np.zeros((0, 3))
    V = np.array([o.T_base_flange[:3, 3] for o in verify_obs]) if verify_obs else np.zeros((0, 3))
    pts = np.vstack([A[:, :3, 3], marker, V] + [T[None, :3, 3] for T, _ in frames])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    span = float(max((hi - lo).max(), 0.3))
    L = span / 8
    for T, name in frames:
        _axes(ax, T, name, L, (0.0, 0.0, span / 12))
    if len(A):
        ax.scatter(*A[:, :3, 3].T, s=14, c="tab:blue", label="flange at each calibration sample", depthshade=False)
        if len(marker):
            ax.scatter(*marker.T, s=8, c="tab:orange", label="marker at each sample", depthshade=False)
    if len(V):
        ax.scatter(*V.T, s=24, c="tab:green", marker="^", label="flange at each verification pose", depthshade=False)
    mid = (lo + hi) / 2
    for setter, m in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid):
        setter(m - span * 0.6, m + span * 0.6)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.view_init(elev=22, azim=-60)
    ax.legend(fontsize=9, loc="upper left", bbox_to_anchor=(0.0, 1.02))
    return svg_of(fig)


def coverage_plot(observations: list[Observation], verify_obs: list[Observation]) -> str:
    """Flange positions in the base frame, three projections: how the samples cover the workspace."""
    fig, axs = figure(1, 3, figsize=(11, 3.6))
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
    return svg_of(fig)


def residual_plot(errors_mm: np.ndarray, ylabel: str, xlabel: str, tolerance_mm: float | None = None) -> str:
    """Bar per sample or pose: the length of the marker point measured minus predicted, mm (and the tolerance)."""
    fig, ax = figure(figsize=(9, 3.2))
    ax.bar(np.arange(len(errors_mm)), errors_mm, color="tab:blue")
    if tolerance_mm is not None:
        ax.axhline(tolerance_mm, color="tab:red", ls="--", label=f"tolerance {tolerance_mm:g} mm")
        ax.legend(fontsize=8)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3, axis="y")
    return svg_of(fig)


def ellipsoid_plot(cov_t_m: np.ndarray, parent: str) -> str:
    """1-sigma error ellipse of the camera translation in the xy, xz and yz planes of its parent frame, mm."""
    fig, axs = figure(1, 3, figsize=(10, 3.4))
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
        ax.set_xlabel(f"d{'xyz'[i]} [mm] ({parent} frame)")
        ax.set_ylabel(f"d{'xyz'[j]} [mm] ({parent} frame)")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return svg_of(fig)


def correction_plot(cc: dict) -> str:
    """The camera correction's parameters with their 1-sigma error bars (% and mm, as labelled)."""
    fig, ax = figure(figsize=(6, 2.8))
    names = list(cc)
    vals = [cc[n]["value"] for n in names]
    sig = [cc[n]["sigma"] for n in names]
    colors = ["tab:blue" if cc[n]["estimated"] else "tab:gray" for n in names]
    ax.barh(np.arange(len(names)), vals, xerr=sig, color=colors, capsize=4)
    ax.set_yticks(np.arange(len(names)), [_param_label(n) for n in names])
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("value ± 1-sigma (gray: not estimated, kept at zero)")
    ax.grid(alpha=0.3, axis="x")
    return svg_of(fig)


def _param_label(name: str) -> str:
    return name.replace("_percent", " [%]").replace("_mm", " [mm]").replace("_", " ")


def write_report(directory: Path, *, result_doc: dict, observations: list[Observation] | None = None,
                 verify_doc: dict | None = None, verify_observations: list[Observation] | None = None,
                 title: str = "handeye calibration report", cell: dict | None = None) -> Path:
    """Write ``directory/report.html`` (module docstring); returns its path.

    ``result_doc``: the result document (``result.yaml``'s content); ``observations``:
    the calibration samples; ``verify_doc`` / ``verify_observations``: a verification
    and the per-pose samples it judged; ``cell``: who made it, where and with what
    (`handeye.app.provenance.cell`; default: the result document's ``cell``).
    """
    from handeye.app.verify import models_of

    observations = list(observations or [])
    verify_observations = list(verify_observations or [])
    model, _ = models_of(result_doc, Path(directory) / "result")
    mdl = result_doc.get("model") or {}
    verdict = _verification_verdict(verify_doc) if verify_doc is not None else result_doc.get("verdict")
    cell = cell if cell is not None else result_doc.get("cell") or {}
    parts = [_verdict_block(verdict), f"<h1>{html.escape(title)}</h1>", _subtitle(result_doc, cell, verify_doc)]
    parts += _cell_section(cell, result_doc)
    parts += _transform_section(result_doc, verify_doc is not None)
    parts += _marker_section(cell, result_doc)
    if verify_doc is not None:
        parts += _verification_section(verify_doc)
    parts += _plots_section(model, result_doc, observations, verify_observations)
    parts += _correction_section(mdl)
    parts += _sign_off(cell)
    parts += _appendix(result_doc, mdl, verify_doc)
    parts += _heldout_section(mdl, verify_doc)
    page = ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{REPORT_STYLE}</style></head><body>"
            + "".join(parts) + "</body></html>\n")
    path = Path(directory) / REPORT_NAME
    path.write_text(page, encoding="utf-8")
    return path


def _verification_verdict(verify_doc: dict) -> dict:
    """A verification's verdict (``verify.yaml``'s), or one from its pass/fail alone for a document without."""
    if verify_doc.get("verdict"):
        return verify_doc["verdict"]
    v = verify_doc["verification"]
    return {"level": "pass" if v["passed"] else "fail", "reasons": [],
            "summary": f"calibration error {v['calibration_error_mm']:.2f} mm on {v['n_poses']} poses against the "
                       f"tolerance {v['tolerance_mm']:g} mm / {v['tolerance_deg']:g} deg"}


def _verdict_block(verdict: dict | None) -> str:
    """The verdict: level, summary, each reason (the first thing on the page)."""
    if not verdict:
        return (f'<div class="verdict warn" id="{VERDICT_ID}"><span class="level">NO VERDICT</span>this result was '
                "written before results carried one: replay its session to judge it</div>")
    reasons = "".join(f"<li>{html.escape(r)}</li>" for r in verdict["reasons"])
    return (f'<div class="verdict {verdict["level"]}" id="{VERDICT_ID}"><span class="level">'
            f'{verdict["level"].upper()}</span>{html.escape(verdict["summary"])}'
            + (f"<ul>{reasons}</ul>" if reasons else "") + "</div>")


def _subtitle(result_doc: dict, cell: dict, verify_doc: dict | None) -> str:
    setup = Setup(result_doc["setup"])
    bits = [setup.value.replace("_", "-"), f"solver {result_doc.get('solver', '')}",
            f"{result_doc.get('n_samples', '?')} calibration samples"]
    if verify_doc is not None:
        bits.append(f"{verify_doc['verification']['n_poses']} verification poses ({verify_doc['mode']})")
    if cell.get("written"):
        bits.append(f"written {cell['written']}")
    return f'<p class="sub">{html.escape(" · ".join(bits))}</p>'


def _cell_section(cell: dict, result_doc: dict) -> list[str]:
    """Who, where, with what: `handeye.app.provenance.cell`'s fields, each on a row (blank where not known)."""
    robot, camera, sw = cell.get("robot") or {}, cell.get("camera") or {}, cell.get("software") or {}
    unknown = "not recorded"

    def named(d: dict, key: str, label: str) -> str:
        """``UR10 (driver ur_sim)``: the device's own name and the backend that spoke to it."""
        return " ".join(p for p in (d.get("model", ""), f"({label} {d[key]})" if d.get(key) else "") if p) or unknown

    rows = [["site", cell.get("site") or unknown], ["cell", cell.get("cell") or unknown],
            ["operator", cell.get("operator") or unknown],
            ["robot", named(robot, "type", "driver")], ["robot serial number", robot.get("serial") or unknown],
            ["robot controller software", robot.get("software") or unknown],
            ["robot address", robot.get("host") or unknown],
            ["camera", named(camera, "backend", "backend")], ["camera serial number", camera.get("serial") or unknown],
            ["camera resolution [px]", camera.get("resolution") or unknown],
            ["handeye", f"{sw.get('handeye', unknown)} (commit {sw.get('commit', unknown)})"],
            ["written (local time)", cell.get("written") or unknown],
            ["samples from", shown_path(result_doc["samples_from"]) if result_doc.get("samples_from") else unknown]]
    return ["<h2>Cell</h2>", table(None, rows, "kv")]


def _transform_section(result_doc: dict, verified: bool) -> list[str]:
    """The camera transform to paste in every form, its frames, which transform for which points, its accuracy."""
    setup = Setup(result_doc["setup"])
    paste = result_doc.get("camera_transform_raw_points") or result_doc["camera_transform"]
    cam = result_doc["camera_transform"]
    parent, child = paste["parent_frame"], paste["child_frame"]
    T = np.array(paste["matrix"])
    xyz = np.array(paste["translation_m"])
    q = paste["quaternion_xyzw"]
    rpy = paste["rpy_deg"]
    matrix = "\n".join(" ".join(f"{v:+.6f}" for v in row) for row in T)
    rows = [["4x4 matrix (m), p_parent = T p_child", _code(matrix)],
            ["xyz [m] + quaternion (x, y, z, w)",
             _code(" ".join(f"{v:.6f}" for v in xyz) + "   " + " ".join(f"{v:.6f}" for v in q))],
            ["xyz [m] + rpy [deg] (URDF: roll about x, pitch about y, yaw about z, fixed axes)",
             _code(" ".join(f"{v:.6f}" for v in xyz) + "   " + " ".join(f"{v:.4f}" for v in rpy))]]
    if result_doc.get("urdf_origin"):
        rows.append(["URDF <origin> (rad)", _code(result_doc["urdf_origin"])])
    if result_doc.get("ros2_static_transform_publisher"):
        rows.append(["ROS 2 static_transform_publisher", _code(result_doc["ros2_static_transform_publisher"])])
    link = (result_doc.get("camera_frame") or {}).get("camera_link_transform")
    if link:
        rows.append([f"a ROS camera_link at the same origin: xyz [m] + quaternion (x, y, z, w) in {parent}",
                     _code(" ".join(f"{v:.6f}" for v in link["translation_m"]) + "   "
                           + " ".join(f"{v:.6f}" for v in link["quaternion_xyzw"]))])
    where = "base" if setup == Setup.EYE_TO_HAND else "flange"
    parts = ["<h2>Camera transform</h2>",
             f"<p><b>{html.escape(setup.camera_name)}</b>: the pose of the camera's optical frame "
             f"(<code>{html.escape(child)}</code>: z forward, x right, y down in the image) in the {where} frame "
             f"(<code>{html.escape(parent)}</code>); {html.escape(setup.equation)}.</p>"]
    if "camera_transform_raw_points" in result_doc:
        parts.append('<p class="use">Paste these forms into ROS, a URDF or a robot program: they hold for the '
                     "points the camera's driver publishes. handeye's own verification and monitoring also correct "
                     "the camera's depth and use a transform for corrected points (appendix).</p>")
    elif result_doc.get("which_transform"):
        parts.append('<p class="use">One transform: it holds for the points the camera\'s driver publishes; paste '
                     "these forms into ROS, a URDF or a robot program.</p>")
    parts.append(table(["form", "value"], rows, "kv"))
    acc = result_doc.get("accuracy")
    summary = []
    if acc:
        summary.append([f"predicted error over the workspace [mm], RMS / at most at 95 %",
                        f"{acc['rms_mm']:.2f} / {acc['p95_mm']:.2f}"])
        summary.append([f"predicted error of the camera's rotation [deg], RMS / at most at 95 %",
                        f"{acc['rms_deg']:.3f} / {acc['p95_deg']:.3f}"])
    if "sigma_1" in cam:
        summary.append([f"1-sigma per axis of {cam['name']}: translation [mm] (x y z, {parent} frame)",
                        " ".join(f"{v:.2f}" for v in cam["sigma_1"]["translation_mm"])])
        summary.append(["1-sigma per axis: rotation [deg]", " ".join(f"{v:.3f}" for v in cam["sigma_1"]["rotation_deg"])])
    residuals = result_doc.get("residuals") or {}
    if "rms_translation_mm" in residuals:
        summary.append(["residual RMS [mm] (marker point measured minus predicted, over the calibration samples)",
                        f"{residuals['rms_translation_mm']:.2f}"])
    elif residuals.get("note"):
        # A monitoring run's calibration in use: a live estimate, fitted to no fixed set of samples.
        summary.append(["residuals", residuals["note"]])
    parts.append(table(["accuracy", "value"], summary))
    if not verified:
        parts.append('<p class="note">A verification on fresh poses (handeye verify) measures the error instead of '
                     "predicting it.</p>")
    return parts


def shown_path(path) -> str:
    """``path`` as the report shows it: relative to where the run was started when it lies below it (a
    customer's copy names the session, not the machine's directories), else as given."""
    p = Path(path)
    try:
        return str(p.resolve().relative_to(Path.cwd().resolve()))
    except (ValueError, OSError):
        return str(path)


def _marker_section(cell: dict, result_doc: dict) -> list[str]:
    """The marker as configured (type, size, id) and where the calibration puts it (the marker-side transform)."""
    marker = cell.get("marker") or {}
    rows = [["marker", marker.get("description") or "not recorded"]]
    mt = result_doc.get("marker_transform")
    if mt:
        where = f"{mt['name']}: the marker in the {mt['parent_frame']} frame"
        rows.append([f"{where}, xyz [mm]", " ".join(f"{v * 1e3:.2f}" for v in mt["translation_m"])])
        rows.append(["quaternion (x, y, z, w)", " ".join(f"{v:.5f}" for v in mt["quaternion_xyzw"])
                     if mt.get("rotation_known", True) else "not determined: the solver used the marker's centre only"])
    return ["<h2>Marker</h2>", table(None, rows, "kv")]


def _sign_off(cell: dict) -> list[str]:
    """Lines to sign when the page is handed over: who prepared it, who checked it, the date."""
    rows = [["prepared by", cell.get("operator") or "", ""], ["checked by", "", ""], ["date", "", ""]]
    return ["<h2>Sign-off</h2>", table(["", "name", "signature"], rows, "kv signoff")]


def _verification_section(doc: dict) -> list[str]:
    """The verification: its table, what the per-pose errors are made of, each pose, and their plot."""
    v = doc["verification"]
    parts = ["<h2>Verification</h2>",
             f'<p>{html.escape(doc["mode"])} verification of {html.escape(shown_path(doc["result"]["path"]))} '
             f'against {html.escape(shown_path(doc["source"]))}. Each error is the length of the marker point measured minus the one '
             "the result predicts, in the base frame.</p>"]
    if doc.get("per_pose_note"):
        parts.append(f'<p class="use">{html.escape(doc["per_pose_note"])}.</p>')
    parts.append(_verification_table(doc))
    parts.append(_plot("error per verification pose", residual_plot(np.array(v["per_pose_mm"]), "error [mm]",
                                                                     "verification pose", v["tolerance_mm"]),
                       "error per verification pose [mm], measurement noise included; dashed: the tolerance"))
    return parts


def _plots_section(model, result_doc: dict, observations: list[Observation],
                   verify_observations: list[Observation]) -> list[str]:
    """Frames, pose coverage, residuals per sample and the error ellipses of the camera transform."""
    from handeye.app.verify import pose_errors

    cam = result_doc["camera_transform"]
    parent = cam["parent_frame"]
    parts = ["<h2>Setup and frames</h2>",
             _plot("setup and frames", frames_plot(model, observations, verify_observations),
                   "base frame, m; each frame's axes: x red, y green, z blue"),
             "<h2>Pose coverage</h2>",
             _plot("pose coverage", coverage_plot(observations, verify_observations),
                   "flange positions in the base frame, mm: the spread of positions and orientations determines "
                   "the camera transform; a verification inside the calibration's region judges interpolation, "
                   "outside it extrapolation")]
    if observations:
        e = np.linalg.norm(pose_errors(model, observations).translation, axis=1) * 1e3
        parts.append("<h2>Residuals per sample</h2>")
        parts.append(_plot("residuals per sample", residual_plot(e, "residual [mm]", "calibration sample"),
                           f"length of the marker point measured minus predicted [mm] (the same in every frame): "
                           f"RMS {np.sqrt(np.mean(e**2)):.2f} mm, max {e.max():.2f} mm, over the samples the result "
                           "was fitted to, so they understate its error on new poses"))
    if "covariance" in cam or "sigma_1" in cam:
        C = (np.array(cam["covariance"]["matrix"])[3:, 3:] if "covariance" in cam
             else np.diag((np.array(cam["sigma_1"]["translation_mm"]) * 1e-3) ** 2))
        parts.append("<h2>Error ellipses of the camera position</h2>")
        parts.append(_plot("error ellipses", ellipsoid_plot(C, parent),
                           f"1-sigma error ellipse of the {cam['name']} translation [mm] in the {parent} frame's "
                           "planes (the translation block of the result's covariance"
                           + ("" if "covariance" in cam else ", axes only") + ")"))
    return parts


def _heldout_section(mdl: dict, verify_doc: dict | None) -> list[str]:
    """Held-out prediction: leave-one-out, blocked folds, the verification poses."""
    check = mdl.get("self_check") or {}
    parts = ["<h2>Appendix: held-out prediction</h2>"]
    rows = []
    if check:
        rows.append(["leave-one-out over the calibration samples", f"{check['heldout_observed_mm']:.2f}",
                     f"{check['heldout_predicted_mm']:.2f}"])
    for c in (mdl.get("blocked_folds") or {}).get("candidates", []):
        what = (f"closed form {c['closed_form']}" if "closed_form" in c else
                ("points + orientations" if c["orientations"] else "points") + ", camera correction: "
                + (", ".join(c["camera_correction"]) or "none"))
        rows.append([f"contiguous stretches held out in turn ({mdl['blocked_folds']['folds']} folds): {what}",
                     f"{c['heldout_mm']:.2f}", "-"])
    if verify_doc is not None:
        v = verify_doc["verification"]
        rows.append([f"verification poses ({verify_doc['mode']}), observed RMS", f"{v['observed_mm']['rms']:.2f}",
                     "-" if v["measurement_noise_rms_mm"] is None else f"{v['measurement_noise_rms_mm']:.2f} (noise)"])
    parts.append(table(["prediction of samples not fitted (marker point)", "observed [mm]", "predicted [mm]"], rows)
                 if rows else "<p>no held-out prediction for this solver</p>")
    return parts


def _correction_section(mdl: dict) -> list[str]:
    """The camera correction's table and plot (or why there is none)."""
    cc = mdl.get("camera_correction")
    parts = ["<h2>Camera correction</h2>"]
    if cc:
        parts.append(table(["parameter", "value", "1-sigma", "estimated"],
                            [[_param_label(k), f"{c['value']:+.3f}", f"{c['sigma']:.3f}",
                              "yes" if c["estimated"] else "no"] for k, c in cc.items()]))
        parts.append(_plot("camera correction", correction_plot(cc),
                           "camera correction ± 1-sigma: measured depth (1 + scale) z + offset, lateral coordinates "
                           "scaled by (1 + focal scale)"))
    else:
        parts.append("<p>none: this solver estimates no camera correction</p>")
    return parts


def _appendix(result_doc: dict, mdl: dict, verify_doc: dict | None) -> list[str]:
    """The statistics behind the verdict: consistency tests, noise levels, the solver's decisions, the other
    camera transform."""
    rows = []
    check = mdl.get("self_check") or {}
    if check:
        rows.append(["chi-square of the residuals against the camera's noise model (dof, p-value)",
                     f"{check['chi2']:.1f} ({check['dof']}, {check['p_value']:.3g})"])
        rows.append(["held-out error observed / predicted", f"{check['heldout_ratio']:.2f}"])
    noise = mdl.get("noise") or {}
    if noise:
        rows.append(["camera point noise: scale on its covariance", f"{noise['camera_point_scale']:.3g}"])
        rows.append(["robot flange error [mm] (estimated)", f"{noise['robot_mm']:.3f}"])
        if noise.get("marker_rotation_deg") is not None:
            rows.append(["marker orientation noise [deg]", f"{noise['marker_rotation_deg']:.3f}"])
    if mdl.get("robot_shared_error_mm") is not None:
        rows.append(["robot kinematic error in the 1-sigma [mm]", f"{mdl['robot_shared_error_mm']:.3f}"])
    if mdl.get("raw_points_misfit_mm") is not None:
        rows.append(["camera_transform_raw_points: RMS misfit of the rigid stand-in for the correction [mm]",
                     f"{mdl['raw_points_misfit_mm']:.3f}"])
    if result_doc.get("which_transform"):
        rows.append(["which transform goes with which points", result_doc["which_transform"]])
    if "camera_transform_raw_points" in result_doc:
        cam = result_doc["camera_transform"]
        rows.append([f"camera_transform ({cam['name']} for corrected points): xyz [m] + quaternion (x, y, z, w)",
                     _code(" ".join(f"{v:.6f}" for v in cam["translation_m"]) + "   "
                           + " ".join(f"{v:.6f}" for v in cam["quaternion_xyzw"]))])
    rows.append(["samples rejected as outliers", ", ".join(map(str, result_doc.get("rejected_samples") or []))
                 or "none"])
    rows.append(["converged, iterations", f"{result_doc.get('converged')}, {result_doc.get('iterations')}"])
    if verify_doc is not None and "truth" in verify_doc:
        rows.append(["true calibration error over the verification poses [mm] (simulator)",
                     f"{verify_doc['truth']['calibration_error_mm']:.2f}"])
    parts = ["<h2>Appendix: statistics</h2>", table(["quantity", "value"], rows, "kv")]
    notes = list(mdl.get("notes") or [])
    if notes:
        parts.append("<p>How the solver decided:</p><ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes)
                     + "</ul>")
    return parts


def _verification_table(doc: dict) -> str:
    v = doc["verification"]
    o = v["observed_mm"]
    rows = [["poses", v["n_poses"]], ["observed error [mm] mean / p95 / max",
                                      f"{o['mean']:.2f} / {o['p95']:.2f} / {o['max']:.2f}"]]
    if v["observed_deg"] is not None:
        d = v["observed_deg"]
        rows.append(["observed error [deg] mean / p95 / max", f"{d['mean']:.3f} / {d['p95']:.3f} / {d['max']:.3f}"])
    if v["measurement_noise_rms_mm"] is not None:
        rows.append(["measurement noise per pose [mm] RMS (noise model)", f"{v['measurement_noise_rms_mm']:.2f}"])
    if v.get("measurement_noise_rms_deg") is not None:
        rows.append(["measurement noise per pose [deg] RMS (noise model)", f"{v['measurement_noise_rms_deg']:.3f}"])
    rows.append(["calibration error, noise removed",
                 bounded(v["calibration_error_mm"], v["calibration_error_ci95_mm"], "mm", 2, v.get("noise_floor_mm"))])
    if v["calibration_error_deg"] is not None:
        rows.append(["calibration error of the rotation, noise removed",
                     bounded(v["calibration_error_deg"], v["calibration_error_ci95_deg"], "deg", 3,
                             v.get("noise_floor_deg"))])
    rows.append(["tolerance", f"{v['tolerance_mm']:g} mm / {v['tolerance_deg']:g} deg"])
    if "rigid_export" in doc:
        rows.append(["the transform to paste (ROS, URDF; for the driver's uncorrected points): calibration error [mm]",
                     f"{doc['rigid_export']['calibration_error_mm']:.2f}"])
    repeated = set(doc.get("repeated_calibration_poses") or [])
    per = table(["pose", "error [mm]", "error [deg]"],
                 [[f"{i}{' (repeats a calibration pose)' if i in repeated else ''}", f"{mm:.2f}",
                   "-" if dg is None else f"{dg:.3f}"]
                  for i, (mm, dg) in enumerate(zip(v["per_pose_mm"], v["per_pose_deg"] or [None] * v["n_poses"]))])
    return table(["quantity", "value"], rows) + per
