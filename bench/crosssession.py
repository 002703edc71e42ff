"""Cross-session prediction on the shared real recordings (issue 21): does a calibration hold on other data?

Each real set (`bench.datasets.real_sets`) is split into separate
"sessions": the first half against the second half of each ETH stream (both
directions), three contiguous blocks of the 15-sample sets (each predicted
from the other two). A solver calibrates on one part; its result predicts the
marker point of every sample of the other part from the robot pose (the
result's camera correction applied, `handeye.calib.model.predict_points`), and the RMS
of the misses is the cross-session error (mm). ``auto`` beside its own closed-
form start (as ``auto`` used it: after its outlier search, the closed form of
the samples it kept), our best closed form and OpenCV's best.

The monitoring engine over the same splits (`monitor_rows`): armed by
``auto`` from one half of each ETH stream, fed the other half one sample per
second or per 3 s (the robot moves continuously in these recordings; a
production monitor samples standstills, poses apart), with and without the
calibration's shared error in the *moved* test
(`handeye.calib.monitor.shared_error_var`). The camera never moved, so every *moved*
alarm is false; the live verification (each sample's prediction before it
is fused) beside the arming calibration's error on the same samples. Then
the same streams with the camera bumped a third of the way in (5 mm and
0.3 deg in random directions, the measured points moved accordingly): how
many of 5 bumps the engine flags, and after how many samples.

Run: ``python -m bench --cross-session`` (or ``python -m bench.crosssession``).
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import cv2
import numpy as np

from bench.datasets import datasets_dir, real_sets
from handeye.calib import model, solve
from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError
from handeye.calib.monitor import MonitorEngine
from handeye.calib.problem import CalibrationProblem
from handeye.calib.setup import Setup
from bench.tables import markdown_table

OURS = ["YKronT'", "YQuatT'", "YKronRT", "YQuatR*", "YAxisR", "XKronRT"]
OPENCV = {"cv2.TSAI": cv2.CALIB_HAND_EYE_TSAI, "cv2.PARK": cv2.CALIB_HAND_EYE_PARK,
          "cv2.HORAUD": cv2.CALIB_HAND_EYE_HORAUD, "cv2.ANDREFF": cv2.CALIB_HAND_EYE_ANDREFF,
          "cv2.DANIILIDIS": cv2.CALIB_HAND_EYE_DANIILIDIS}
#: OpenCV pairs every two samples (O(N^2) motions): long streams are thinned to this many for it.
OPENCV_MAX = 150


def opencv_solve(name: str, A, B, setup: str):
    """(X, Y) by OpenCV's calibrateHandEye; the marker-side transform as the chordal mean over the samples."""
    keep = np.linspace(0, len(A) - 1, min(OPENCV_MAX, len(A))).round().astype(int)
    A_, B_ = A[keep], B[keep]
    G = A_ if setup == Setup.EYE_IN_HAND else tf.invert(A_)
    R, t = cv2.calibrateHandEye(list(G[:, :3, :3]), list(G[:, :3, 3]), list(B_[:, :3, :3]), list(B_[:, :3, 3]),
                                method=OPENCV[name])
    H = tf.make_transform(tf.project_to_so3(R), t.ravel())   # eye-in-hand T_flange_cam; eye-to-hand T_base_cam
    if setup == Setup.EYE_IN_HAND:
        Ys = A @ H @ B
        X, Y = H, tf.make_transform(tf.project_to_so3(Ys[:, :3, :3].sum(axis=0)), Ys[:, :3, 3].mean(axis=0))
    else:
        Xs = tf.invert(A) @ H @ B
        X, Y = tf.make_transform(tf.project_to_so3(Xs[:, :3, :3].sum(axis=0)), Xs[:, :3, 3].mean(axis=0)), H
    return X, Y


def prediction_rms(X, Y, theta, A, B, setup: str) -> float:
    """RMS (m) of the marker points of samples (A, B) missed by the result (X, Y, camera correction theta)."""
    C, K, M = model.split(X, Y, A, setup)
    p = B[:, :3, 3] if B.ndim == 3 else B
    pred = model.predict_points(C, K[:3, 3], M, theta)
    return float(np.sqrt(np.mean(np.sum((p - pred) ** 2, axis=1))))


def splits(n: int, stream: bool) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(label, train, test): halves both ways for a stream, else three contiguous blocks."""
    idx = np.arange(n)
    if stream:
        a, b = idx[: n // 2], idx[n // 2:]
        return [("1st -> 2nd half", a, b), ("2nd -> 1st half", b, a)]
    blocks = np.array_split(idx, 3)
    return [(f"block {k + 1} from the others", np.setdiff1d(idx, blk), blk) for k, blk in enumerate(blocks)]


def cross_session_rows(sets) -> list[list]:
    rows = []
    for name, imp in sets:
        A, B, setup = imp.A, imp.B, imp.setup
        stream = len(A) > 60
        for label, train, test in splits(len(A), stream):
            errs, refused = {}, None
            for m in OURS:
                try:
                    r = solve(m, A[train], B[train], setup=setup)
                    errs[m] = prediction_rms(r.X, r.Y, None, A[test], B[test], setup)
                except CalibrationError as e:
                    refused = refused or e
            if not errs:
                # E.g. a block whose training poses all turn about one axis: every solver refuses it, as it should.
                rows.append([name, label, f"{len(train)} / {len(test)}", f"every solver refused: {refused}"]
                            + [""] * 7)
                continue
            for m in OPENCV:
                try:
                    X, Y = opencv_solve(m, A[train], B[train], setup)
                    errs[m] = prediction_rms(X, Y, None, A[test], B[test], setup)
                except (cv2.error, np.linalg.LinAlgError, CalibrationError):
                    pass
            try:
                auto = solve("auto", A[train], B[train], setup=setup)
            except CalibrationError as e:
                rows.append([name, label, f"{len(train)} / {len(test)}", f"failed: {e}"] + [""] * 7)
                continue
            e_auto = prediction_rms(auto.X, auto.Y, auto.camera_correction.as_array(), A[test], B[test], setup)
            start = auto.auto.start.split("+")[0]
            e_start = errs.get(start, float("nan"))
            if auto.inliers is not None:
                # The outlier search ran: auto's start is the closed form of the samples it kept.
                kept = train[auto.inliers]
                own = solve(start, A[kept], B[kept], setup=setup)
                e_start = prediction_rms(own.X, own.Y, None, A[test], B[test], setup)
                start += "+LMedS"
            ours = min((m for m in errs if m in OURS), key=errs.get)
            cv_best = min((m for m in errs if m in OPENCV), key=errs.get)
            best = min(errs[ours], errs[cv_best])
            corr = ", ".join(f"{k} {v.value * (1e3 if k == 'depth_offset' else 100):+.2f}"
                             for k, v in auto.auto.camera_correction.items() if v.estimated) or "none"
            rows.append([name, label, f"{len(train)} / {len(test)}", f"{e_auto * 1e3:.2f}",
                         f"{start} {e_start * 1e3:.2f}", f"{ours} {errs[ours] * 1e3:.2f}",
                         f"{cv_best} {errs[cv_best] * 1e3:.2f}",
                         "yes" if e_auto <= e_start * 1.0001 else "**no**",
                         f"{e_auto / best:.2f}" + ("" if e_auto <= 1.1 * best else " **>1.1**"),
                         " + ".join(auto.auto.measurements), corr])
    return rows


#: Seconds between the samples the monitor takes of a continuous stream (`monitor_rows`).
MONITOR_SPACING_S = (1.0, 3.0)


def spaced(observations, spacing_s: float) -> list:
    """The first observation, then each one at least ``spacing_s`` after the last taken."""
    taken = [observations[0]]
    for o in observations[1:]:
        if o.t - taken[-1].t >= spacing_s:
            taken.append(o)
    return taken


#: The camera bump put into the streams (`monitor_rows`): mm, deg, random directions, a third of the way in.
MONITOR_BUMP = (5.0, 0.3)
MONITOR_BUMPS = 5


def _monitor_run(problem, result, t0: float, samples, shared: bool, bump=None) -> tuple[list, list, float]:
    """Moved alarms (sample numbers), verification errors (mm) and the shared error variance (m^2 per axis) of
    the engine armed from ``result``. ``bump``: ``(k, D)``, the camera moved by ``D`` (its own frame) before
    sample ``k``: the marker points it measures from then on are ``D^-1 p``."""
    engine = MonitorEngine()
    ref = engine.arm(result, problem, t=t0)
    if not shared:
        engine.detector.shared_var = 0.0
    alarms, verify = [], []
    for k, o in enumerate(samples):
        p = o.point_cam if bump is None or k < bump[0] else tf.transform_points(tf.invert(bump[1]), o.point_cam)
        upd = engine.update(o.t, o.T_base_flange, p, o.point_cov)
        verify.append(upd.verify_mm)
        if upd.alarm == "moved":
            alarms.append(k)
    return alarms, verify, ref.shared_var


def _bump_delays(problem, result, t0: float, samples, rng: np.random.Generator) -> list:
    """Samples from a `MONITOR_BUMP` a third of the way into ``samples`` to its *moved* alarm (None: not
    flagged, or a false alarm before it), `MONITOR_BUMPS` random directions."""
    k = len(samples) // 3
    delays = []
    for _ in range(MONITOR_BUMPS):
        u, v = (x / np.linalg.norm(x) for x in rng.normal(size=(2, 3)))
        D = tf.from_rotvec_translation(np.deg2rad(MONITOR_BUMP[1]) * v, MONITOR_BUMP[0] * 1e-3 * u)
        alarms, _, _ = _monitor_run(problem, result, t0, samples, True, (k, D))
        delays.append(alarms[0] - k if alarms and alarms[0] >= k else None)
    return delays


def monitor_rows(sets, rng: np.random.Generator) -> list[list]:
    """The monitoring engine on the ETH streams: armed from one half, the other half streamed (module docstring)."""
    rows = []
    for name, imp in sets:
        obs = imp.observations
        if len(obs) <= 60:
            continue
        half = len(obs) // 2
        for label, arm, stream in (("1st -> 2nd half", obs[:half], obs[half:]),
                                   ("2nd -> 1st half", obs[half:], obs[:half])):
            problem = CalibrationProblem.from_observations(arm, imp.setup)
            result = solve("auto", problem)
            t0 = max(o.t for o in arm)
            # The first half streamed after the second: its clock moved past the arming's.
            shift = 0.0 if stream[0].t >= t0 else t0 + 1.0 - stream[0].t
            stream = [dataclasses.replace(o, t=o.t + shift) for o in stream]
            for spacing in MONITOR_SPACING_S:
                samples = spaced(stream, spacing)
                alarms, verify, shared_var = _monitor_run(problem, result, t0, samples, shared=True)
                white, _, _ = _monitor_run(problem, result, t0, samples, shared=False)
                A = np.array([o.T_base_flange for o in samples])
                P = np.array([o.point_cam for o in samples])
                static = prediction_rms(result.X, result.Y, result.camera_correction.as_array(), A, P, imp.setup)
                shared_mm = np.sqrt(shared_var) * 1e3

                delays = _bump_delays(problem, result, t0, samples, rng)
                flagged = sorted(d for d in delays if d is not None)

                def said(a):
                    return f"{len(a)} (sample {a[0]})" if a else "0"

                bumps = f"{len(flagged)}/{len(delays)}" + (f" ({', '.join(map(str, flagged))})" if flagged else "")
                rows.append([name, label, f"{spacing:g} s", len(samples), f"{shared_mm:.2f}", said(alarms), said(white),
                             f"{np.sqrt(np.mean(np.square(verify))):.2f}", f"{static * 1e3:.2f}", bumps])
    return rows


def main(argv=None) -> int:
    argparse.ArgumentParser(prog="python -m bench --cross-session").parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="handeye-bench-") as work:
        rows = cross_session_rows(real_sets(Path(work)))
        mon = monitor_rows(real_sets(Path(work)), np.random.default_rng(0))
    if not rows:
        print(f"no real recordings under {datasets_dir()} (set HANDEYE_DATASETS)")
        return 0
    print("### Cross-session prediction of the marker point on the real recordings [mm]\n")
    print(markdown_table(["set", "split", "N train / test", "auto", "auto's start", "our best closed form", "OpenCV's best",
               "auto <= its start", "auto / best closed form", "auto used", "auto's camera correction"], rows))
    print("\n### The monitoring engine on the other half of each ETH stream (a still camera: every *moved* alarm "
          "is false)\n")
    print(markdown_table(["set", "armed from -> streamed", "one sample per", "samples", "shared error per axis [mm]",
                          "moved alarms", "moved alarms, errors taken as white", "live verification RMS [mm]",
                          "arming calibration on them [mm]",
                          f"a {MONITOR_BUMP[0]:g} mm / {MONITOR_BUMP[1]:g} deg bump a third in: "
                          "flagged (samples after)"],
                         mon))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
