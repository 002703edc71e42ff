"""bench.plan: the fixed 17-pose baseline and the report table."""

import numpy as np

from bench.plan import fixed_pattern, format_report
from handeye.calib import transforms as tf


def test_fixed_pattern_is_17_distinct_poses_within_the_ranges():
    T0 = tf.make_transform(tf.random_rotations(1, 1.0, np.random.default_rng(0))[0], [0.9, 0.1, 0.5])
    P = fixed_pattern(T0, 0.1, 30.0)
    assert P.shape == (17, 4, 4)
    tf.check_transforms(P)
    rot, dist = tf.pose_error(P, np.broadcast_to(T0, P.shape))
    assert np.allclose(P[0], T0) and np.all(dist <= 0.1 + 1e-9) and np.all(np.degrees(rot) <= 30 + 1e-6)
    flat = np.round(P.reshape(17, -1), 6)
    assert len(np.unique(flat, axis=0)) == 17


def test_report_gives_the_ratio_and_marks_runs_that_missed_the_target():
    runs = [dict(setup="eye_to_hand", strategy=s, seed=k, reached=r, stopped_by="target_sigma" if r else "plan_done",
                 motions=m, samples=m + 1, robot_s=2.0 * m, sigma_mm=0.9, sigma_deg=0.08, err_mm=0.5, err_deg=0.05,
                 lost_marker=0, limit_refused=0)
            for s, ms in (("optimal", (4, 5, 6)), ("random", (9, 10, 12)), ("fixed17", (17, 17, 17)))
            for k, m in enumerate(ms) for r in [not (s == "fixed17" and k == 0)]]
    runs += [dict(runs[0], strategy="plan", seed=k, motions=5, planned_motions=6, expected_mm=e, expected_deg=0.09,
                  noise_model="anchored") for k, e in enumerate((1.1, 1.2, 1.3))]
    val = {"poses": 12000, "invalid_robot": 0, "invalid_view": 1, "no_valid_pose": 2, "cells": 300, "check_calls": 4,
           "check_cpu_s": 0.8, "wall_ms": [10.0, 20.0, 30.0], "cpu_ms": [10.0, 20.0, 30.0],
           "cpu_planner_ms": [5.0, 6.0, 7.0], "reached": [20, 30]}
    text = format_report(runs, val, 1.0)
    assert "= 0.50 (target <= 0.5)" in text
    assert "| eye_to_hand | fixed17 | 3 | 2 | > 17 (not all reached) | 17*, 17, 17 |" in text
    assert "| eye_to_hand | 3 | 6 / 5 | 1.20 / 0.090 | 0.90 / 0.080 | 1.10 / 0.90, 1.20 / 0.90, 1.30 / 0.90 |" in text
    assert "1 invalid of 12000 planned poses" in text and "| 200 (mean of 4) |" in text
