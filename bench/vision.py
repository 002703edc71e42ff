"""Benchmark of marker extraction on rendered 640x480 RGB-D frames.

Run ``python -m bench.vision [--frames N] [--seed S] [--out DIR]``. Prints
markdown tables and writes ``vision_accuracy.png`` to ``out/bench/``:

- per-frame time of detection + depth lifting (`handeye.calib.vision.extract`) on one
  core: OpenCV limited to one thread, timed as the thread's CPU time so that
  other processes on a shared machine do not inflate it;
- accuracy of the 3D marker center vs distance (median / 95 % error, NEES of
  the 3x3 covariance, which should be ~3), of the depth-refined and PnP-only
  rotations, the NEES of the depth-refined 6x6 pose covariance (~6), and the
  skip rate, for a 5 cm DICT_4X4_50 marker on an
  Xtion-like sensor (`handeye.mocks.render.scene.RenderNoise` defaults).

The measurement is the same for eye-to-hand and eye-in-hand (the marker seen
from the camera), so one table serves both setups.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from handeye.calib import transforms as tf
from handeye.calib.vision.extract import TargetConfig, extract, try_extract
from handeye.calib.vision.markers import detect_markers
from handeye.drivers.camera.base import CameraIntrinsics
from handeye.mocks.render.scene import MarkerSceneRenderer, RenderNoise

INTR = CameraIntrinsics(640, 480, 570.0, 570.0, 319.5, 239.5)
BINS = [(0.4, 0.5), (0.5, 0.6), (0.6, 0.7), (0.7, 0.8), (0.8, 0.9), (0.9, 1.0), (1.0, 1.2), (1.2, 1.5)]


def _pose(rng: np.random.Generator, z_lo: float, z_hi: float) -> np.ndarray:
    """Marker facing the camera within ~40 deg, anywhere in the central 60 % of the view."""
    z = rng.uniform(z_lo, z_hi)
    tilt = Rotation.from_rotvec(rng.normal(size=3) / np.sqrt(3) * np.deg2rad(32)).as_matrix()
    t = np.array([rng.uniform(-0.3, 0.3) * z * INTR.width / INTR.fx,
                  rng.uniform(-0.3, 0.3) * z * INTR.height / INTR.fy, z])
    return tf.make_transform(tilt @ np.diag([1.0, -1.0, -1.0]), t)


def run(frames_per_bin: int, seed: int) -> tuple[list[dict], dict]:
    rng = np.random.default_rng(seed)
    renderer = MarkerSceneRenderer(INTR, "DICT_4X4_50", 0, 0.05, 0.08, RenderNoise())
    target = TargetConfig()
    rows, t_extract, t_detect, t_render = [], [], [], []
    for lo, hi in BINS:
        err, nees, pose_nees, rot_d, rot_p, err_pnp, skips = [], [], [], [], [], [], []
        for _ in range(frames_per_bin):
            T = _pose(rng, lo, hi)
            t0 = time.thread_time()
            color, depth, truth = renderer.render(T, rng, T_cam_flange=T @ tf.make_transform(np.eye(3), [0, 0, -0.012]))
            t_render.append(time.thread_time() - t0)
            t0 = time.thread_time()
            m, reason = try_extract(color, depth, INTR, target)
            dt = time.thread_time() - t0
            if m is None:
                skips.append(reason)
                continue
            t_extract.append(dt)
            t0 = time.thread_time()
            detect_markers(color, target.dictionary, target.marker_size)
            t_detect.append(time.thread_time() - t0)
            e = m.point_cam - truth["point_cam"]
            err.append(np.linalg.norm(e))
            nees.append(float(e @ np.linalg.solve(m.point_cov, e)))
            # Pose error in the covariance's convention: R_true = Exp(d) R_est, t_true = t_est + dt.
            d = cv2.Rodrigues(T[:3, :3] @ m.T_cam_marker[:3, :3].T)[0].ravel()
            ep = np.r_[d, T[:3, 3] - m.T_cam_marker[:3, 3]]
            pose_nees.append(float(ep @ np.linalg.solve(m.pose_cov, ep)))
            rot_d.append(tf.pose_error(m.T_cam_marker, T)[0])
            rot_p.append(tf.pose_error(m.T_cam_marker_pnp, T)[0])
            mp = extract(color, None, INTR, TargetConfig(use_depth=False))
            err_pnp.append(np.linalg.norm(mp.point_cam - truth["point_cam"]))
        if not err:  # every frame of the bin skipped
            err = nees = pose_nees = rot_d = rot_p = err_pnp = [np.nan]
        rows.append({
            "bin": f"{lo:.1f}-{hi:.1f}", "z": (lo + hi) / 2, "n": frames_per_bin - len(skips), "skipped": len(skips),
            "med_mm": 1e3 * np.median(err), "p95_mm": 1e3 * np.percentile(err, 95),
            "nees": np.mean(nees), "nees_med": np.median(nees), "pose_nees": np.mean(pose_nees),
            "rot_d_deg": np.rad2deg(np.median(rot_d)), "rot_p_deg": np.rad2deg(np.median(rot_p)),
            "pnp_med_mm": 1e3 * np.median(err_pnp), "reasons": sorted(set(skips)),
            "err": np.array(err), "nees_all": np.array(nees),
        })
    timing = {"extract_ms": 1e3 * np.array(t_extract), "detect_ms": 1e3 * np.array(t_detect),
              "render_ms": 1e3 * np.array(t_render)}
    return rows, timing


def _plot(rows: list[dict], out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    z = [r["z"] for r in rows]
    ax1.plot(z, [r["med_mm"] for r in rows], "o-", label="depth-lifted center, median")
    ax1.plot(z, [r["p95_mm"] for r in rows], "s--", label="depth-lifted center, 95 %")
    ax1.plot(z, [r["pnp_med_mm"] for r in rows], "^:", label="PnP-only center, median")
    ax1.set_xlabel("distance (m)")
    ax1.set_ylabel("3D center error (mm)")
    ax1.set_yscale("log")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)
    all_nees = np.concatenate([r["nees_all"] for r in rows])
    all_nees = all_nees[np.isfinite(all_nees)]
    ax2.hist(np.clip(all_nees, 0, 20), bins=40, density=True, alpha=0.7, label="NEES (clipped at 20)")
    from scipy.stats import chi2

    x = np.linspace(0.01, 20, 200)
    ax2.plot(x, chi2.pdf(x, 3), "k-", label="chi2(3)")
    ax2.set_xlabel("NEES of the 3D center")
    ax2.legend(fontsize=8)
    fig.suptitle("Marker center from rendered Xtion-like RGB-D (5 cm DICT_4X4_50, 640x480)")
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    path = out / "vision_accuracy.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.vision", description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=60, help="rendered frames per distance bin (default 60)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path("out/bench"))
    args = p.parse_args(argv)
    cv2.setNumThreads(1)  # the target is one core
    rows, timing = run(args.frames, args.seed)

    print("## Extraction time per 640x480 frame (one core, thread CPU time)\n")
    print("| step | median ms | 95 % ms |")
    print("|---|---|---|")
    steps = (("detect (ArUco, subpixel)", "detect_ms"),
             ("extract = detect + PnP + depth plane + center", "extract_ms"),
             ("render (mock, for reference)", "render_ms"))
    for name, key in steps:
        v = timing[key]
        print(f"| {name} | {np.median(v):.2f} | {np.percentile(v, 95):.2f} |")
    print("\n## 3D marker center vs distance (rendered, 5 cm marker, tilt up to ~40 deg)\n")
    print("| distance m | frames | skipped | median mm | 95 % mm | NEES mean | NEES median | "
          "pose NEES mean (6) | rot depth-refined deg | rot PnP deg | PnP-only center mm |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['bin']} | {r['n']} | {r['skipped']} | {r['med_mm']:.2f} | {r['p95_mm']:.2f} | "
              f"{r['nees']:.2f} | {r['nees_med']:.2f} | {r['pose_nees']:.2f} | {r['rot_d_deg']:.2f} | "
              f"{r['rot_p_deg']:.2f} | {r['pnp_med_mm']:.1f} |")
    sel = [r for r in rows if 0.5 <= r["z"] <= 1.0]
    err = np.concatenate([r["err"] for r in sel])
    nees = np.concatenate([r["nees_all"] for r in sel])
    err, nees = err[np.isfinite(err)], nees[np.isfinite(nees)]
    print(f"\n0.5-1.0 m overall: median {1e3 * np.median(err):.2f} mm, 95 % {1e3 * np.percentile(err, 95):.2f} mm, "
          f"NEES mean {nees.mean():.2f} (chi2(3): 3), median {np.median(nees):.2f} (chi2(3): 2.37), n = {len(err)}")
    reasons = sorted({s for r in rows for s in r["reasons"]})
    if reasons:
        print("\nskip reasons: " + "; ".join(reasons))
    print(f"\nplot: {_plot(rows, args.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
