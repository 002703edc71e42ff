"""Benchmark of the RealSense path: 640x480 at 30 fps through rs.align and the marker extraction.

Run ``python -m bench.realsense [--frames N] [--out DIR]``. Streams rendered frames of the demo cell
through librealsense's software device (`handeye.mocks.realsense.SoftwareRealSense`) and the backend
(`handeye.drivers.camera.realsense.RealSenseCamera`) and prints a markdown table (also
``<out>/realsense.md``), for the registered geometry (depth camera = colour camera) and a D435-like
one (depth camera 15 mm beside colour, fx 385 vs 570):

- per frame (ms, median and 95th percentile, wall clock): ``read`` (the SDK's syncer, ``rs.align``
  to colour, depth scaling, rgb -> BGR), ``extract`` (`handeye.calib.vision.extract.extract`), and both;
  rendering and pushing the frame are not counted;
- agreement (mm) of the marker point through the RealSense path with the rendered camera's own
  frame (depth registered by the renderer), mean and max; noise-free depth for the D435 geometry,
  the renderer's noise for the registered one (both sides then see the same depth pixels).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from handeye.calib import simulate
from handeye.calib.vision.extract import TargetConfig, extract
from handeye.drivers.camera.realsense import RealSenseCamera, RealSenseCameraConfig
from handeye.mocks.realsense import DepthModel, SoftwareRealSense
from handeye.mocks.render.camera import RenderedCameraConfig
from handeye.mocks.render.scene import RenderNoise

QUIET = RenderNoise(disparity_sigma_px=0, disparity_step_px=0, depth_bias_k=0, dropout=0)
GEOMETRIES = {
    "registered (depth = colour camera)": (RenderedCameraConfig(), DepthModel(baseline_m=0.0, intrinsics=None)),
    "D435-like (15 mm baseline, fx 385 / 570)": (RenderedCameraConfig(noise=QUIET), DepthModel()),
}


def run(name: str, n: int, seed: int) -> dict:
    camera, depth = GEOMETRIES[name]
    sw = SoftwareRealSense(camera, depth, fps=30)
    poses = simulate.realistic_cell(n, np.random.default_rng(seed)).A_true
    target = TargetConfig()
    t_read, t_extract, errs = [], [], []
    t0 = time.time()
    with RealSenseCamera(RealSenseCameraConfig(), device=sw.device) as cam:
        sw.push(poses[0], t0 - 1 / 30)  # the syncer passes the very first set alone
        for i, T in enumerate(poses):
            ref = sw.push(T, t0 + i / 30)
            a = time.perf_counter()
            f = cam.read()
            b = time.perf_counter()
            m = extract(f.color, f.depth, f.intrinsics, target)
            c = time.perf_counter()
            t_read.append(b - a)
            t_extract.append(c - b)
            r = extract(ref.color, ref.depth, ref.intrinsics, target)
            errs.append(np.linalg.norm(m.point_cam - r.point_cam) * 1e3)
    sw.close()
    both = np.add(t_read, t_extract) * 1e3
    return {"name": name, "n": n, "read": np.array(t_read) * 1e3, "extract": np.array(t_extract) * 1e3,
            "both": both, "err": np.array(errs)}


def format_table(rows: list[dict]) -> str:
    lines = ["| geometry | frames | read + align [ms] median / p95 | extract [ms] median / p95 "
             "| per frame [ms] median / p95 | marker point vs rendered [mm] mean / max |",
             "|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        def cell(v):
            return f"{np.median(v):.2f} / {np.percentile(v, 95):.2f}"
        lines.append(f"| {r['name']} | {r['n']} | {cell(r['read'])} | {cell(r['extract'])} | {cell(r['both'])} "
                     f"| {r['err'].mean():.3f} / {r['err'].max():.3f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.realsense", description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="out/bench")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)  # as bench.vision: one core for OpenCV
    rows = [run(name, args.frames, args.seed) for name in GEOMETRIES]
    report = "## RealSense path: 640x480 at 30 fps through rs.align and the extraction\n\n" + format_table(rows)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "realsense.md").write_text(report)
    print(report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
