"""The smallest bump the *moved* test flags, beside the detection limit the noise model implies (issue 32):
``python -m bench --detection``.

For each program (the realistic eye-to-hand cell of `bench.shift`
with 4 and with 14 stops, and its eye-in-hand shift) and each bump size
(0.5-5 mm, 0.06 deg per mm, random directions, three per 8-hour shift),
the share of bumps the engine flags within `shift.DETECT_WITHIN` samples,
against the share the best test could flag.

The limit (`handeye.calib.change.move_information`, `handeye.calib.change.detection_power`):
the camera's move as a rigid 6-dof motion, its onset known, the noise known
(the simulator's: the marker point's covariance and, eye-to-hand, the robot's
repeatability), and each stop's marker point over the 20 samples after the
bump compared with its mean over the visits since the previous bump's
re-learn (`shift.RECOVER_WITHIN` samples after it), so that the calibration's
systematic error at each stop cancels. Its GLR statistic is tested at the
engine's threshold (the same false-alarm rate per test) once, at the 20th
sample. The engine does not know the onset and tests every sample; the
camera drift between the baselines and the bump is left out of the limit.
Per bump the limit is the probability that this test flags that bump; the
table gives its mean over the bumps beside the engine's share.

Run: ``python -m bench --detection [--seeds 20] [--first-seed 0] [--programs 4,14,eih]``;
a table on stdout and in out/bench/detection.md.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import copy  # noqa: E402
import dataclasses  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from bench import shift as shiftbench  # noqa: E402
from handeye.calib import simulate  # noqa: E402
from handeye.calib import transforms as tf  # noqa: E402
from handeye.calib.change import ChangeDetector, window_power  # noqa: E402
from handeye.calib.model import point_jacobians  # noqa: E402
from handeye.calib.monitor import MonitorSettings  # noqa: E402
from handeye.calib.setup import Setup  # noqa: E402

SIZES_MM = (0.5, 1.0, 2.0, 3.0, 4.0, 5.0)
DEG_PER_MM = 0.06


def bump_limits(stream: simulate.ShiftData, K: np.ndarray, setup: Setup, robot_cov: np.ndarray | None,
                threshold: float) -> list[float]:
    """The limit's probability of flagging each bump of ``stream`` within `shift.DETECT_WITHIN` samples
    (`handeye.calib.change.window_power`: ``K`` and ``robot_cov`` as there)."""
    out = []
    for k, b in enumerate(stream.bumped):
        start = 0 if k == 0 else stream.bumped[k - 1] + shiftbench.RECOVER_WITHIN
        end = min(b + shiftbench.DETECT_WITHIN, len(stream.t))
        stops = np.unique(stream.stop[b:end])
        first = [b + int(np.argmax(stream.stop[b:end] == j)) for j in stops]
        visits = [int(np.sum(stream.stop[b:end] == j)) for j in stops]
        baseline = [int(np.sum(stream.stop[start:b] == j)) for j in stops]
        out.append(window_power(stream.Y[b - 1], stream.Y[b], K, stream.A[first], stream.point_cov[first], visits,
                                baseline, setup, robot_cov, threshold))
    return out


def engine_delays(engine, stream: simulate.ShiftData, factors: np.ndarray | None) -> tuple[list, int, int]:
    """Run ``engine`` over ``stream``: samples from each bump to its first *moved* alarm (None: none before the
    next bump), the bumps flagged later than `shift.DETECT_WITHIN` samples, and the false *moved* alarms (any but
    a bump's first)."""
    moved = []
    for i in range(len(stream.t)):
        upd = engine.update(stream.t[i], stream.A[i], stream.points[i], stream.point_cov[i],
                            None if factors is None else factors[i])
        if upd.alarm == "moved":
            moved.append(i)
    ends = list(stream.bumped[1:]) + [len(stream.t)]
    first = [next((i for i in moved if b <= i < end), None) for b, end in zip(stream.bumped, ends)]
    delays = [None if i is None else i - b for i, b in zip(first, stream.bumped)]
    late = sum(d is not None and d > shiftbench.DETECT_WITHIN for d in delays)
    return [None if d is None or d > shiftbench.DETECT_WITHIN else d for d in delays], late, len(moved) - sum(
        i is not None for i in first)


def program_rows(program: str, seeds: list[int], settings: MonitorSettings, sizes=SIZES_MM) -> list[list]:
    """One row per bump size of ``program`` (``"4"``, ``"14"`` stops eye-to-hand, or ``"eih"``)."""
    threshold = ChangeDetector(settings.detector).threshold
    per_size = {mm: ([], [], 0, 0) for mm in sizes}
    for seed in seeds:
        if program == "eih":
            cell, _, armed, rng = shiftbench.eye_in_hand_armed(seed, settings)
        else:
            prof = simulate.RealisticProfile()
            real, _, armed = shiftbench.armed_cell(seed, settings, prof)
            robot_cov = prof.repeatability_cov()
        for mm in sizes:
            shift = dataclasses.replace(simulate.Shift(), stops=4 if program == "eih" else int(program),
                                        bumps=tuple((h, mm, mm * DEG_PER_MM) for h, _, _ in simulate.Shift().bumps))
            engine = copy.deepcopy(armed)
            if program == "eih":
                stream = simulate.eye_in_hand_shift(cell, cell.A_true[30:34], shift,
                                                    np.random.default_rng([seed, 4, int(mm * 10)]))
                limits = bump_limits(stream, cell.Y, Setup.EYE_IN_HAND, None, threshold)
                delays, late, false = engine_delays(engine, stream, None)
            else:
                stream = simulate.shift_stream(real, shift, np.random.default_rng([seed, 1, int(mm * 10)]), prof)
                limits = bump_limits(stream, real.data.X, Setup.EYE_TO_HAND, robot_cov, threshold)
                delays, late, false = engine_delays(engine, stream, prof.dh_error_factor(stream.q))
            d, lim, lt, f = per_size[mm]
            per_size[mm] = (d + delays, lim + limits, lt + late, f + false)
    rows = []
    for mm in sizes:
        delays, limits, late, false = per_size[mm]
        flagged = [d for d in delays if d is not None]
        rows.append([{"eih": "eye-in-hand, 4 stops"}.get(program, f"eye-to-hand, {program} stops"),
                     f"{mm:g} mm / {mm * DEG_PER_MM:.2f} deg",
                     f"{len(flagged)}/{len(delays)} ({100 * len(flagged) / max(len(delays), 1):.0f} %)",
                     f"{100 * np.mean(limits):.0f} %", "-" if not flagged else f"{np.median(flagged):.0f}", late, false])
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench --detection", description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--programs", default="4,14,eih", help="comma-separated: 4 and/or 14 (stops, eye-to-hand), eih")
    ap.add_argument("--sizes", default=",".join(f"{s:g}" for s in SIZES_MM), help="bump sizes, mm")
    ap.add_argument("--out", type=Path, default=Path("out/bench"))
    args = ap.parse_args(argv)
    settings = MonitorSettings()
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    sizes = tuple(float(s) for s in args.sizes.split(","))
    t0 = time.monotonic()
    rows = []
    for program in args.programs.split(","):
        rows += program_rows(program.strip(), seeds, settings, sizes)
    text = (f"### Smallest bump flagged within {shiftbench.DETECT_WITHIN} samples, and the limit (seeds "
            f"{seeds[0]}-{seeds[-1]}, three bumps per 8-hour shift)\n\n"
            + shiftbench.markdown(["program", "bump", f"engine: flagged within {shiftbench.DETECT_WITHIN}",
                                   "limit: known onset and noise", "median samples to the alarm",
                                   "flagged later", "false moved alarms"], rows)
            + f"\n\n({time.monotonic() - t0:.0f} s)")
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "detection.md").write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
