"""Latency of the ROS 2 camera path: a frame published -> a sample (the marker measured), 640x480 at 30 Hz.

Run ``python -m bench.ros2 [--frames N] [--out DIR]`` (``python -m bench --ros2``). A publisher process
(this module with ``--publish``, as realsense2_camera would be) sends rendered frames of the demo cell
(`handeye.mocks.render.camera`, rendered beforehand) at 30 Hz through real DDS on loopback (ROS_DOMAIN_ID and
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST as set here unless given), stamped when published (colour rgb8,
aligned depth 16UC1, CameraInfo). This process reads them with `handeye.drivers.camera.ros2.Ros2Camera` (the newest
pair) and measures the marker (`handeye.calib.vision.extract.extract`), one frame after the other as a run does.
``--flood SECONDS``: a 100 Hz publisher with every third stamp out of order instead, read as fast as it
comes: frames read, messages skipped (logged), this process's resident memory over the run.

Per frame (ms, median and 95th percentile, wall clock): ``transport`` (stamp -> the colour message in the
camera's queue: building the messages, DDS), ``decode`` (to BGR and metres), ``extract``, and ``frame ->
sample`` (stamp -> measurement, also the time a frame waits while the one before is measured); the table
also gives the frames measured of those published (the camera hands out the newest).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

TOPICS = {"color_topic": "/bench/color/image_raw", "depth_topic": "/bench/aligned_depth_to_color/image_raw",
          "info_topic": "/bench/color/camera_info"}


def publish(n: int, rate: float, shuffle: bool = False) -> int:
    """The publisher process: render ``min(n, 30)`` poses, then publish ``n`` frames at ``rate`` (``shuffle``:
    every third one stamped 0.2 s back, out of order)."""
    from handeye.calib import simulate
    from handeye.drivers.camera.ros2 import Ros2CameraConfig
    from handeye.drivers.ros2 import Ros2Node
    from handeye.mocks.render.camera import RenderedCamera, RenderedCameraConfig
    from handeye.mocks.ros2_cell import FramePublisher

    poses = iter(simulate.realistic_cell(min(n, 30), np.random.default_rng(0)).A_true)
    cam = RenderedCamera(RenderedCameraConfig(), lambda: next(poses))
    cam.connect()
    frames = [cam.read() for _ in range(min(n, 30))]
    with Ros2Node("bench_camera") as node:
        out = FramePublisher(node, Ros2CameraConfig(**TOPICS))
        print("ready", flush=True)
        sys.stdin.readline()  # the reader is subscribed
        due = time.monotonic()
        for k in range(n):
            f = frames[k % len(frames)]
            out.publish(f.color, f.depth, f.intrinsics, time.time() - (0.2 if shuffle and k % 3 == 2 else 0.0))
            due += 1.0 / rate
            time.sleep(max(due - time.monotonic(), 0.0))
    return 0


def _env() -> None:
    """This run's ROS graph: the given one, else this machine only and a domain from the pid."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(50 + os.getpid() % 50))


def _publisher(n: int, rate: float, shuffle: bool) -> subprocess.Popen:
    pub = subprocess.Popen([sys.executable, "-m", "bench.ros2", "--publish", "--frames", str(n), "--rate", str(rate)]
                           + ["--shuffle"] * shuffle, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert pub.stdout.readline().strip() == "ready"
    return pub


def flood(seconds: float, rate: float = 100.0) -> dict:
    """A publisher flooding 640x480 frames at ``rate`` with every third stamp out of order, read as fast as they
    come: frames read, skips, and this process's resident memory (MB) over the run."""
    import resource

    from handeye.drivers.camera.ros2 import Ros2Camera, Ros2CameraConfig
    from handeye.drivers.errors import ConnectionLostError

    _env()
    n = int(seconds * rate)
    pub = _publisher(n, rate, True)
    cam = Ros2Camera(Ros2CameraConfig(**TOPICS, timeout_s=3.0, connect_timeout_s=20.0))
    pub.stdin.write("go\n")
    pub.stdin.flush()
    rss, reads, t_next = [], 0, 0.0

    def rss_mb() -> float:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * resource.getpagesize() / 1e6

    try:
        with cam:
            while True:
                try:
                    cam.read()
                except ConnectionLostError:
                    break
                reads += 1
                if time.monotonic() > t_next:
                    rss.append(rss_mb())
                    t_next = time.monotonic() + 1.0
    finally:
        pub.wait(60)
    return {"published": n, "read": reads, "skips": sum(cam.skips.counts.values()), "rss": np.array(rss)}


def run(n: int, rate: float) -> dict:
    from handeye.calib.errors import ExtractionError
    from handeye.calib.vision.extract import TargetConfig, extract
    from handeye.drivers.camera.ros2 import Ros2Camera, Ros2CameraConfig
    from handeye.drivers.errors import ConnectionLostError

    _env()
    pub = _publisher(n, rate, False)
    target = TargetConfig()
    rows = {"transport": [], "decode": [], "extract": [], "total": []}
    cam = Ros2Camera(Ros2CameraConfig(**TOPICS, timeout_s=3.0, connect_timeout_s=20.0))
    pub.stdin.write("go\n")
    pub.stdin.flush()
    try:
        with cam:
            while True:
                try:
                    f = cam.read()
                except ConnectionLostError:
                    break  # the publisher is done
                b = time.perf_counter()
                try:
                    extract(f.color, f.depth, f.intrinsics, target)
                except ExtractionError:
                    continue
                c = time.perf_counter()
                rows["transport"].append(f.meta["arrival_ms"])
                rows["decode"].append(f.meta["decode_ms"])
                rows["extract"].append((c - b) * 1e3)
                rows["total"].append((time.time() - f.t) * 1e3)
    finally:
        pub.wait(30)
    return {"n": n, "rate": rate, **{k: np.array(v) for k, v in rows.items()}}


def format_table(r: dict) -> str:
    def cell(v):
        return f"{np.median(v):.2f} / {np.percentile(v, 95):.2f}"

    return ("| path | frames measured / published | transport [ms] | decode [ms] | extract [ms] "
            "| frame -> sample [ms] median / p95 |\n|---|---:|---:|---:|---:|---:|\n"
            f"| ROS 2 (Fast DDS, loopback), 640x480 @ {r['rate']:g} Hz | {len(r['total'])} / {r['n']} "
            f"| {cell(r['transport'])} | {cell(r['decode'])} | {cell(r['extract'])} | **{cell(r['total'])}** |\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.ros2", description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--flood", type=float, metavar="SECONDS",
                    help="instead: a 100 Hz publisher with out-of-order stamps for SECONDS; memory and skips")
    ap.add_argument("--publish", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--shuffle", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.publish:
        return publish(args.frames, args.rate, args.shuffle)
    if args.flood:
        r = flood(args.flood)
        rss = r["rss"]
        quarters = " / ".join(f"{rss[int(q * (len(rss) - 1))]:.0f}" for q in (0, 0.25, 0.5, 0.75, 1))
        print(f"| flood | published | read | skipped (logged) | RSS at 0, 1/4, 1/2, 3/4, end [MB] |\n"
              f"|---|---:|---:|---:|---:|\n| 640x480 @ 100 Hz, every third stamp 0.2 s back, {args.flood:g} s "
              f"| {r['published']} | {r['read']} | {r['skips']} | {quarters} |")
        return 0
    import cv2

    cv2.setNumThreads(1)  # as bench.vision and bench.realsense: one core for OpenCV
    report = ("## ROS 2 camera path: a published frame -> a sample, 640x480 at 30 Hz\n\n"
              + format_table(run(args.frames, args.rate)))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "ros2.md").write_text(report)
    print(report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
