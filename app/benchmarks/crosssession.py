"""Cross-session prediction on the shared real recordings (issue 21): does a calibration hold on other data?

Each real set (`app.benchmarks.datasets.real_sets`) is split into separate
"sessions": the first half against the second half of each ETH stream (both
directions), three contiguous blocks of the 15-sample sets (each predicted
from the other two). A solver calibrates on one part; its result predicts the
marker point of every sample of the other part from the robot pose (the
result's camera correction applied, `calib.model.predict_points`), and the RMS
of the misses is the cross-session error (mm). ``auto`` beside its own closed-
form start (as ``auto`` used it: after its outlier search, the closed form of
the samples it kept), our best closed form and OpenCV's best.

Run: ``handeye bench --cross-session`` (or ``python -m app.benchmarks.crosssession``).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np

from app.benchmarks.datasets import datasets_dir, real_sets
from calib import model, solve
from calib import transforms as tf
from calib.errors import CalibrationError
from calib.setup import Setup
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
            errs = {}
            for m in OURS:
                try:
                    r = solve(m, A[train], B[train], setup=setup)
                    errs[m] = prediction_rms(r.X, r.Y, None, A[test], B[test], setup)
                except CalibrationError:
                    pass
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


def main(argv=None) -> int:
    argparse.ArgumentParser(prog="handeye bench --cross-session").parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="handeye-bench-") as work:
        rows = cross_session_rows(real_sets(Path(work)))
    if not rows:
        print(f"no real recordings under {datasets_dir()} (set HANDEYE_DATASETS)")
        return 0
    print("### Cross-session prediction of the marker point on the real recordings [mm]\n")
    print(markdown_table(["set", "split", "N train / test", "auto", "auto's start", "our best closed form", "OpenCV's best",
               "auto <= its start", "auto / best closed form", "auto used", "auto's camera correction"], rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
