"""Benchmark of ``handeye verify`` on the simulated cell (issue 21): markdown tables on stdout.

1. The demo calibrates the simulated cell (rendered camera, UR10 simulator);
   ``verify`` then moves to fresh planned poses and measures the marker there.
2. On those same verification samples, results off by a known amount are
   judged (`handeye.calib.verify.perturbed`: 3 mm, 0.3 deg across the view, both, both
   in random directions): the reported calibration error (noise removed)
   against the true error of each result over the same poses (the simulator
   knows the truth), and the verdict at the 2 mm tolerance.
3. The frame-safety check with a tape-measure prior 5 cm off: the result, and its inverse.
4. The report's size.

Run: ``python -m bench --verify [--host 127.0.0.2] [--poses 12]``.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from handeye.app import verify as av
from handeye.app.runs.demo import demo
from handeye.app.config import load_config
from handeye.calib import transforms as tf
from handeye.calib import verify as cv
from handeye.app.session import read_session
from bench.tables import markdown_table


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench --verify")
    ap.add_argument("--host", default="127.0.0.2", help="loopback address of the UR simulator")
    ap.add_argument("--poses", type=int, default=12, help="verification poses")
    ap.add_argument("--seeds", type=int, default=5, help="random directions per perturbed row")
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="handeye-bench-verify-"))
    cfg = load_config(None)
    data = cfg.model_dump()
    data["robot"]["host"] = args.host
    data["session"]["root"] = str(work)
    data["viz"]["enabled"] = False
    data["verify"]["poses"] = args.poses
    cfg = type(cfg).model_validate(data)
    out = demo(cfg, progress=False)
    loaded = av.load_result(out.report.session / "result.yaml")
    run = av.verify_active(cfg, loaded, rng=np.random.default_rng(cfg.verify.seed))
    obs = run.observations
    tol = dict(tolerance_mm=2.0, tolerance_deg=cfg.verify.tolerance_deg)
    print(f"demo: {out.report.n_samples} samples; verification: {len(obs)} fresh poses of {run.planned} planned "
          f"({cfg.verify.frames_per_pose} frames each), work dir {work}\n")

    def judge(model, label):
        w = cv.verify(av.pose_errors(model, obs), rng=np.random.default_rng(0), **tol)
        truth = av.true_error_mm(av.LoadedResult(loaded.path, model, None, loaded.doc), obs, run.truth,
                                 run.camera_bias)
        o = w.stats_mm()
        return [label, f"{truth:.2f}", f"{w.calibration_mm:.2f}",
                f"[{w.calibration_ci_mm[0]:.2f}, {w.calibration_ci_mm[1]:.2f}]",
                f"{o['mean']:.2f} / {o['p95']:.2f} / {o['max']:.2f}",
                f"{w.calibration_mm / truth:.2f}" if truth > 0 else "-", "pass" if w.passed else "FAIL"], w, truth

    T = loaded.model.camera_transform
    rows = [judge(loaded.model, "demo result")[0]]
    cases = [("3 mm", 0.0, 3.0, True), ("0.3 deg across the view", 0.3, 0.0, True),
             ("3 mm + 0.3 deg across the view", 0.3, 3.0, True), ("3 mm + 0.3 deg, random axis", 0.3, 3.0, False),
             ("1 mm", 0.0, 1.0, True), ("5 mm", 0.0, 5.0, True)]
    summary = []
    for label, deg, mm, across in cases:
        ratios, fails = [], 0
        for seed in range(args.seeds):
            off = cv.perturbed(T, deg, mm, np.random.default_rng(seed), axis=T[:3, 0] if across else None)
            row, w, truth = judge(loaded.model.with_camera_transform(off), f"{label} (seed {seed})")
            rows.append(row)
            ratios.append(w.calibration_mm / truth)
            fails += not w.passed
        summary.append([label, args.seeds, f"{min(ratios):.2f} .. {max(ratios):.2f}",
                        f"{max(abs(r - 1) for r in ratios) * 100:.0f} %", f"{fails}/{args.seeds}"])
    print("### Reported vs true error over the same fresh poses (tolerance 2 mm)\n")
    print(markdown_table(["result", "true [mm]", "reported, noise removed [mm]", "95 % interval", "observed mean / p95 / max",
               "reported / true", "verdict"], rows))
    print("\n### Summary per offset\n")
    print(markdown_table(["offset", "results", "reported / true", "worst deviation", "failed at 2 mm"], summary))
    prior = T[:3, 3] + np.array([0.03, -0.03, 0.025])
    fs = [["result", cv.frame_safety(T, cfg.setup, prior)], ["inverse of the result",
                                                           cv.frame_safety(tf.invert(T), cfg.setup, prior)]]
    print("\n### Frame safety (prior 5 cm from the true camera origin)\n")
    print(markdown_table(["transform", "distance [mm]", "inverse's distance [mm]", "warning"],
              [[n, f"{f.distance_m * 1e3:.0f}", f"{f.inverse_distance_m * 1e3:.0f}",
                (f.warnings[0][:60] + "...") if f.warnings else "none"] for n, f in fs]))
    sizes = [["demo (calibrate)", f"{(out.report.session / 'report.html').stat().st_size / 1e3:.0f}"]]
    calib = read_session(out.report.session).observations
    from handeye.app.report import write_report

    doc = av.verify_document(loaded, "active", run.session,
                             cv.verify(av.pose_errors(loaded.model, obs), rng=np.random.default_rng(0), **tol),
                             None, None)
    page = write_report(run.session, result_doc=loaded.doc, observations=calib, verify_doc=doc,
                        verify_observations=obs)
    sizes.append(["verify", f"{page.stat().st_size / 1e3:.0f}"])
    print("\n### report.html size\n")
    print(markdown_table(["report", "kB"], sizes))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
