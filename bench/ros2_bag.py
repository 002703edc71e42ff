"""ROS 2 bag import: time of a long recording of the demo, and its calibration against the session's.

Run ``python -m bench.ros2_bag [--minutes 2] [--fps 30] [--storage mcap sqlite3] [--out out/bench]``.
Writes a bag of the rendered demo (`handeye.mocks.ros2_bag.write_demo_bag`: stop-and-go through
`handeye.calib.simulate.realistic_cell` poses, tf at 125 Hz, 640x480 ``rgb8`` colour, ``16UC1`` depth
registered to it, ``CameraInfo``) for each storage, imports it with `handeye.app.formats.load`
(`handeye.app.formats.ros2_bag`) and prints a markdown table (also ``<out>/ros2_bag.md``):

- import time: the whole ``load`` (both passes over the bag, tf composition, standstill
  detection, decoding and marker extraction of the chosen frames);
- agreement: the camera transform solved from the imported samples against the one solved from the
  equivalent session (the frame a live run takes at each stop, its exact flange pose, the app's
  extraction), for YKronT' and YQuatT'; and the error of the imported result vs the rendered truth.

Every stop frame is rendered; frames while the robot moves repeat the last stop's pixels
(``render_moving=False``): the importer never measures those, but it reads and pairs every one.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from handeye.calib import transforms as tf
from handeye.calib.api import solve_observations
from handeye.calib.observation import Observation

METHODS = ("YKronT'", "YQuatT'")


def _session(bag) -> tuple[list[int], list[Observation]]:
    """The equivalent session's messages and samples (`handeye.mocks.ros2_bag.session_frames`, the app's extraction)."""
    from handeye.calib.vision.extract import TargetConfig, extract
    from handeye.mocks.ros2_bag import session_frames

    target = TargetConfig()
    taken = session_frames(bag, lambda c: extract(c.color, c.depth, bag.intrinsics, target))
    return [c.message for c, _ in taken], [Observation.from_measurement(i, c.t, c.T_base_flange, m)
                                           for i, (c, m) in enumerate(taken)]


def run(storage: str, minutes: float, fps: float, work: Path) -> dict:
    """Write, import and compare one bag; returns the table row's figures."""
    from handeye.app.formats import load
    from handeye.mocks.ros2_bag import write_demo_bag

    stop_s, move_s = 1.5, 1.5
    n_poses = max(2, int(round(minutes * 60 / (stop_s + move_s))))
    path = work / f"demo_{storage}"
    t0 = time.perf_counter()
    bag = write_demo_bag(path, storage=storage, n_poses=n_poses, fps=fps, stop_s=stop_s, move_s=move_s,
                         render_moving=False)
    t_write = time.perf_counter() - t0
    size = sum(p.stat().st_size for p in path.iterdir())
    t0 = time.perf_counter()
    imported = load(path)
    t_import = time.perf_counter() - t0
    messages, session = _session(bag)
    row = {"storage": storage, "duration_s": bag.duration_s, "images": bag.n_images, "size_gb": size / 1e9,
           "write_s": t_write, "import_s": t_import, "samples": len(imported.observations),
           "session_samples": len(session),
           "same_frames": [o.meta["message"] for o in imported.observations] == messages}
    for method in METHODS:
        a = solve_observations(method, imported.observations, "eye_to_hand")
        b = solve_observations(method, session, "eye_to_hand")
        rot, trans = tf.pose_error(a.camera_transform, b.camera_transform)
        rot_t, trans_t = tf.pose_error(a.camera_transform, bag.truth["T_base_cam"])
        row[method] = (float(trans) * 1e3, float(np.rad2deg(rot)), float(trans_t) * 1e3)
    shutil.rmtree(path)
    return row


def format_table(rows: list[dict]) -> str:
    lines = ["| storage | recording [s] | images | bag [GB] | write [s] | import [s] | samples (session) "
             "| same frames | " + " | ".join(f"{m} vs session [mm] / [deg] | {m} vs truth [mm]" for m in METHODS)
             + " |",
             "|---|---:|---:|---:|---:|---:|---:|---|" + "---:|---:|" * len(METHODS)]
    for r in rows:
        cells = [r["storage"], f"{r['duration_s']:.0f}", str(r["images"]), f"{r['size_gb']:.2f}",
                 f"{r['write_s']:.1f}", f"{r['import_s']:.1f}", f"{r['samples']} ({r['session_samples']})",
                 "yes" if r["same_frames"] else "no"]
        for m in METHODS:
            mm, deg, truth = r[m]
            cells += [f"{mm:.4f} / {deg:.5f}", f"{truth:.2f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.ros2_bag", description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=2.0)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--storage", nargs="+", default=["mcap", "sqlite3"], choices=["mcap", "sqlite3"])
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--work", help="directory for the bags (default: a temporary one; they take ~1.5 MB a frame)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="handeye-bag-", dir=args.work) as tmp:
        rows = []
        for storage in args.storage:
            rows.append(run(storage, args.minutes, args.fps, Path(tmp)))
            print(format_table(rows[-1:]), flush=True)
    report = (f"## ROS 2 bag import ({args.minutes:g} min of the demo at {args.fps:g} fps)\n\n"
              + format_table(rows))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "ros2_bag.md").write_text(report)
    print(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
