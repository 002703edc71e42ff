"""Input fuzzing: the solver API, the config loader, the session reader and the importers.

Run ``python -m bench.fuzz [--solver-cases N] [--file-cases N] [--bag-cases N] [--only CAMPAIGN]
[--seed S] [--out out/bench]``
(also ``python -m bench --fuzz``). Prints a markdown table and writes
``<out>/fuzz.md``.

What counts as a failure:

- solver API (`calib.solve`, `handeye.calib.api.closed_form`, `handeye.calib.refine.refine`,
  `handeye.calib.robust.robust_solve` and the public solvers of `handeye.calib.solvers`): an
  exception that is not a `handeye.calib.errors.HandeyeError`, a warning (e.g. complex
  inputs silently cast), or a result carrying NaN/inf (X, Y, residuals, cov);
- files (TOML configs, session directories, import files: easy_handeye,
  easy_handeye2, industrial_calibration, pose-stream CSV manifests, ViSP
  pose files, an image folder, OpenCV FileStorage, MoveIt Calibration, ROS 2
  bags; ``--bag-cases`` more bags, MCAP and sqlite3, damaged byte-wise too): an
  exception that is not a `HandeyeError` (a traceback), a read that does not
  return within ``HANG_S`` seconds, or a file opened outside the data
  directory (seen by an audit hook on ``open``).

- the monitoring engine (``--only monitor``, `bench.monitor_campaign`):
  its state machine (``--monitor-examples`` runs), composed production programs
  (``--monitor-runs``) and the same through ``replay --monitor`` armed from a
  session, a result.yaml and a previous run (``--monitor-replays`` each):
  a traceback, a broken invariant, a missed bump or a false moved alarm.

Inputs are seeded (``--seed``); every case is a small mutation of a valid
input, so most cases reach deep into the code instead of failing the first
shape check. Eye-to-hand data unless a case picks ``eye_in_hand``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
# Damaged images are the point here: keep OpenCV from logging each one.
os.environ.setdefault("OPENCV_LOG_LEVEL", "OFF")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from collections import Counter  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from handeye.calib import simulate, solvers  # noqa: E402
from handeye.calib import transforms as tf  # noqa: E402
from handeye.calib.api import METHODS, closed_form, solve  # noqa: E402
from handeye.calib.errors import HandeyeError  # noqa: E402
from handeye.calib.problem import CalibrationProblem  # noqa: E402
from handeye.calib.refine import refine  # noqa: E402
from handeye.calib.robust import robust_solve  # noqa: E402
from handeye.calib.setup import Setup  # noqa: E402

#: Public solver functions of `handeye.calib.solvers` taking ``(A, B)`` pose stacks.
POSE_SOLVERS = {
    "x_axis_rx": solvers.x_axis_rx,
    "x_quat_r_star": solvers.x_quat_r_star,
    "x_kron_r_star": solvers.x_kron_r_star,
    "x_kron_rt": solvers.x_kron_rt,
    "x_kron_t": solvers.x_kron_t,
    "y_axis_r": solvers.y_axis_r,
    "y_quat_r_star": solvers.y_quat_r_star,
    "y_kron_rt": solvers.y_kron_rt,
    "y_quat_t_prime": solvers.y_quat_t_prime,
}


@dataclass
class Tally:
    """Outcomes of one fuzz campaign, by kind; ``examples`` keeps the first few failures."""

    cases: int = 0
    ok: int = 0
    clean_errors: int = 0
    crashes: int = 0
    nan_results: int = 0
    warned: int = 0
    hangs: int = 0
    outside_reads: int = 0
    examples: list = field(default_factory=list)
    crash_types: Counter = field(default_factory=Counter)

    def fail(self, kind: str, what: str) -> None:
        if len(self.examples) < 8:
            self.examples.append(f"{kind}: {what}")

    @property
    def failures(self) -> int:
        return self.crashes + self.nan_results + self.warned + self.hangs + self.outside_reads

    @classmethod
    def total(cls, tallies) -> Tally:
        """The counts of several tallies summed (their examples stay with them)."""
        out = cls()
        for t in tallies:
            for name in ("cases", "ok", "clean_errors", "crashes", "nan_results", "warned", "hangs", "outside_reads"):
                setattr(out, name, getattr(out, name) + getattr(t, name))
            out.crash_types.update(t.crash_types)
        return out


# ------------------------------------------------------------------ solver cases


def _base_data(rng: np.random.Generator, n: int, setup: Setup):
    """A valid (A, B poses, points, point_cov) of ``n`` samples (the paper's simulated round)."""
    d = simulate.paper_setup(n, rng, noise_A=(np.deg2rad(0.5), 0.002), noise_B=(np.deg2rad(0.5), 0.002))
    B = d.B if setup == Setup.EYE_TO_HAND else tf.invert(d.B)
    return d.A.copy(), B.copy(), B[:, :3, 3].copy(), d.point_cov.copy()


def _mutate_array(a: np.ndarray, rng: np.random.Generator) -> tuple[str, object]:
    """One malformed variant of a valid float array ``a`` and the mutation's name."""
    kind = rng.choice([
        "huge", "huge", "tiny", "nan", "inf", "string", "ragged", "complex", "complex_real", "object",
        "object_str", "shape", "empty", "scalar", "none", "non_rotation", "reflection", "bool", "int",
        "mismatch", "dict", "nested_extra", "bottom_row", "zero_rotation",
    ])
    a = a.copy()
    flat_index = tuple(int(rng.integers(s)) for s in a.shape)
    if kind == "huge":
        a[flat_index] = float(10.0 ** rng.choice([10, 20, 100, 155, 200, 300, 308]))
        return kind, a
    if kind == "tiny":
        return kind, a * float(10.0 ** -rng.choice([50, 150, 300]))
    if kind == "nan":
        a[flat_index] = np.nan
        return kind, a
    if kind == "inf":
        a[flat_index] = -np.inf if rng.random() < 0.5 else np.inf
        return kind, a
    if kind == "string":
        lst = a.tolist()
        _set_nested(lst, flat_index, rng.choice(["abc", "1.0", "", "nan"]))
        return kind, lst
    if kind == "ragged":
        lst = a.tolist()
        i = int(rng.integers(len(lst)))
        lst[i] = lst[i][:-1] if isinstance(lst[i], list) and len(lst[i]) > 1 else [lst[i], lst[i]]
        return kind, lst
    if kind == "complex":
        return kind, a + 1e-3j * rng.random(a.shape)
    if kind == "complex_real":
        return kind, a.astype(complex)
    if kind == "object":
        return kind, a.astype(object)
    if kind == "object_str":
        o = a.astype(object)
        o[flat_index] = "x"
        return kind, o
    if kind == "shape":
        shapes = [(len(a), 3, 3), (len(a), 4), (4, 4), (len(a), 4, 4, 1), (len(a), 2), (len(a), 16)]
        shape = shapes[int(rng.integers(len(shapes)))]
        return kind, rng.normal(size=shape)
    if kind == "empty":
        return kind, np.zeros((0,) + a.shape[1:])
    if kind == "scalar":
        return kind, float(rng.normal())
    if kind == "none":
        return kind, None
    if kind == "non_rotation" and a.shape[-2:] == (4, 4):
        a[flat_index[0], :3, :3] *= 1.0 + rng.uniform(1e-4, 1.0)
        return kind, a
    if kind == "reflection" and a.shape[-2:] == (4, 4):
        a[flat_index[0], :3, 0] *= -1.0
        return kind, a
    if kind == "bottom_row" and a.shape[-2:] == (4, 4):
        a[flat_index[0], 3, :3] = rng.normal(size=3)
        return kind, a
    if kind == "zero_rotation" and a.shape[-2:] == (4, 4):
        a[flat_index[0], :3, :3] = 0.0
        return kind, a
    if kind == "bool":
        return kind, a > 0
    if kind == "int":
        return kind, np.round(a).astype(int)
    if kind == "mismatch":
        return kind, a[:-1] if len(a) > 1 else np.concatenate([a, a])
    if kind == "dict":
        return kind, {"A": a.tolist()}
    if kind == "nested_extra":
        return kind, [a.tolist()]
    return "none", None


def _set_nested(lst, index, value) -> None:
    for i in index[:-1]:
        lst = lst[i]
    lst[index[-1]] = value


def _degenerate(A: np.ndarray, B: np.ndarray, p: np.ndarray, rng: np.random.Generator, kind: str):
    """Well-formed but degenerate inputs: identical poses, one rotation axis, points at the camera origin."""
    A, B, p = A.copy(), B.copy(), p.copy()
    if kind == "identical":
        A[:] = A[0]
        B[:] = B[0]
        p[:] = p[0]
    elif kind == "one_axis":
        angles = rng.uniform(-1.0, 1.0, size=len(A))
        R = np.array([tf.from_rotvec_translation(np.array([0.0, 0.0, a]), np.zeros(3))[:3, :3] for a in angles])
        A[:, :3, :3] = R
    elif kind == "origin_point":
        p[int(rng.integers(len(p)))] = 0.0
        B[int(rng.integers(len(B))), :3, 3] = 0.0
    elif kind == "all_origin":
        p[:] = 0.0
        B[:, :3, 3] = 0.0
    elif kind == "duplicate_half":
        half = len(A) // 2
        A[half:] = A[0]
        B[half:] = B[0]
        p[half:] = p[0]
    elif kind == "huge_all":
        s = float(10.0 ** rng.choice([50, 150, 155, 200]))
        A[:, :3, 3] *= s
        B[:, :3, 3] *= s
        p *= s
    return A, B, p


def solver_case(rng: np.random.Generator):
    """One seeded solver fuzz case: ``(description, thunk)``; the thunk returns a result or raises."""
    setup = Setup.EYE_TO_HAND if rng.random() < 0.7 else Setup.EYE_IN_HAND
    n = int(rng.choice([1, 3, 4, 5, 6, 8, 12, 20]))
    A, B, p, cov = _base_data(rng, n, setup)
    A0, B0, p0 = A, B, p
    target = rng.choice(["solve", "solve", "solve", "closed_form", "solver_fn", "kron_t_prime", "refine", "robust"])
    method = str(rng.choice(list(METHODS)))
    if rng.random() < 0.05:
        method = "auto"  # handeye.calib.auto: the extended model on points or poses
    elif rng.random() < 0.03:
        method = rng.choice(["bogus", "", "YKRONT''", None, 5])
    uses_points = (method == "auto" or METHODS.get(method) is not None and METHODS[method].needs == "points") \
        and rng.random() < 0.7
    Bm = p if uses_points else B
    point_cov = None if rng.random() < 0.6 else (cov if rng.random() < 0.5 else cov[0])
    mut = "valid"
    r = rng.random()
    if r < 0.25:
        mut = str(rng.choice(["identical", "one_axis", "origin_point", "all_origin", "duplicate_half", "huge_all"]))
        A, B, p = _degenerate(A, B, p, rng, mut)
        Bm = p if uses_points else B
    elif r < 0.85:
        which = rng.choice(["A", "B", "B", "cov"] if point_cov is not None else ["A", "B"])
        kind, value = _mutate_array({"A": A, "B": np.asarray(Bm), "cov": np.asarray(point_cov)}[which], rng)
        mut = f"{which}:{kind}"
        if which == "A":
            A = value
        elif which == "B":
            Bm = value
        else:
            point_cov = value
    elif r < 0.88:
        setup_arg = rng.choice(["eye-to-hand", "", None, "EYE_TO_HAND"])
        mut = f"setup:{setup_arg!r}"
        setup = setup_arg
    refine_flag = bool(rng.random() < 0.3)
    robust_flag = bool(rng.random() < 0.15)
    desc = f"{target} {method!r} {setup} n={n} {mut} refine={refine_flag} robust={robust_flag}"

    if target == "solve":
        return desc, lambda: solve(method, A, Bm, setup=setup, refine=refine_flag, robust=robust_flag,
                                   point_cov=point_cov, rng=np.random.default_rng(0))
    if target == "closed_form":
        return desc, lambda: closed_form(method, A, Bm, setup=setup)
    if target == "solver_fn":
        name = str(rng.choice(list(POSE_SOLVERS)))
        poses = B if uses_points and not mut.startswith("B") else Bm
        return f"{name} {mut} n={n}", lambda: POSE_SOLVERS[name](A, poses)
    if target == "kron_t_prime":
        pts = Bm if uses_points or mut.startswith("B") else p
        return f"y_kron_t_prime {setup} {mut} n={n}", lambda: solvers.y_kron_t_prime(A, pts, setup)
    if target == "refine":
        def run_refine():
            # A valid starting point (the unmutated data) and the mutated data to refine on.
            init = closed_form(method, A0, p0 if uses_points else B0,
                               setup=setup if setup in ("eye_to_hand", "eye_in_hand") else "eye_to_hand")
            return refine(init, CalibrationProblem.from_arrays(A, Bm, setup=init.setup, point_cov=point_cov))
        return f"refine {desc}", run_refine
    return f"robust_solve {desc}", lambda: robust_solve(
        lambda sub: closed_form(method, sub), CalibrationProblem.from_arrays(A, Bm, setup=setup, point_cov=point_cov),
        rng=np.random.default_rng(0))


def _finite_result(res) -> str | None:
    """None if every number of a result is finite, else what is not."""
    if isinstance(res, tuple):
        for name, v in zip(("X", "Y"), res):
            if not np.isfinite(np.asarray(v, dtype=float)).all():
                return f"{name} has NaN/inf"
        return None
    for name in ("X", "Y", "cov"):
        v = getattr(res, name, None)
        if v is not None and not np.isfinite(np.asarray(v, dtype=float)).all():
            return f"{name} has NaN/inf"
    bad = _nonfinite_in(getattr(res, "info", None), "info")
    if bad:
        return f"{bad} is NaN/inf"
    resid = getattr(res, "residuals", None)
    if resid is not None:
        for name in ("translation", "rotation"):
            v = getattr(resid, name, None)
            if v is not None and not np.isfinite(np.asarray(v, dtype=float)).all():
                return f"residuals.{name} has NaN/inf"
    return None


def _nonfinite_in(value, where: str) -> str | None:
    """Path of the first NaN/inf float inside nested dicts/lists/arrays, or None."""
    if isinstance(value, dict):
        return next((b for k, v in value.items() if (b := _nonfinite_in(v, f"{where}.{k}"))), None)
    if isinstance(value, (list, tuple)):
        return next((b for i, v in enumerate(value) if (b := _nonfinite_in(v, f"{where}[{i}]"))), None)
    if isinstance(value, np.ndarray) and value.dtype.kind == "f":
        return None if np.isfinite(value).all() else where
    if isinstance(value, (float, np.floating)) and not np.isfinite(value):
        return where
    return None


def run_solver_campaign(n_cases: int, rng: np.random.Generator) -> Tally:
    """``n_cases`` solver fuzz cases; see the module docstring for what fails."""
    t = Tally()
    for _ in range(n_cases):
        desc, thunk = solver_case(rng)
        t.cases += 1
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                res = thunk()
            except HandeyeError:
                t.clean_errors += 1
                continue
            except Exception as e:  # noqa: BLE001 - counting exactly these is the point
                t.crashes += 1
                t.crash_types[type(e).__name__] += 1
                t.fail("crash", f"{desc}: {type(e).__name__}: {str(e)[:120]}")
                continue
            finally:
                if caught:
                    t.warned += 1
                    t.fail("warning", f"{desc}: {caught[0].category.__name__}: {str(caught[0].message)[:100]}")
        bad = _finite_result(res)
        if bad:
            t.nan_results += 1
            t.fail("nan", f"{desc}: {bad}")
        else:
            t.ok += 1
    return t


# ------------------------------------------------------------------- file cases

#: A read that has not returned after this long is counted as a hang (and interrupted).
HANG_S = 10.0


class _Hang(Exception):
    pass


class _OpenWatch:
    """Audit hook on ``open``: records files opened inside ``work`` but outside the case's data directory.

    The campaign plants a canary beside every data directory (``work/outside``)
    and points mutated file names at it, at ``/etc/hostname`` and through
    ``..``; opening any of them is a read outside the data directory.
    """

    def __init__(self, work: Path):
        self.work = os.path.realpath(work)
        self.data_dir: str | None = None
        self.outside: list[str] = []
        sys.addaudithook(self)

    def __call__(self, event: str, args) -> None:
        if event != "open" or self.data_dir is None or not isinstance(args[0], (str, bytes, os.PathLike)):
            return
        try:
            p = os.path.realpath(os.fsdecode(args[0]))
        except (ValueError, OSError):
            return
        inside_data = p == self.data_dir or p.startswith(self.data_dir + os.sep)
        if not inside_data and (p.startswith(self.work + os.sep) or p in ("/etc/hostname", "/etc/passwd")):
            self.outside.append(p)


def _run_file_case(t: Tally, watch: _OpenWatch, data_dir: Path, desc: str, fn) -> None:
    """Run ``fn`` with the hang alarm and the open watch; count its outcome in ``t``."""
    import signal

    def on_alarm(signum, frame):
        raise _Hang()

    t.cases += 1
    watch.data_dir, watch.outside = os.path.realpath(data_dir), []
    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, HANG_S)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fn()
        t.ok += 1
    except _Hang:
        t.hangs += 1
        t.fail("hang", desc)
    except HandeyeError as e:
        t.clean_errors += 1
        if "Traceback" in str(e):
            t.crashes += 1
            t.fail("traceback in message", desc)
    except Exception as e:  # noqa: BLE001 - counting exactly these is the point
        t.crashes += 1
        t.crash_types[type(e).__name__] += 1
        t.fail("crash", f"{desc}: {type(e).__name__}: {str(e)[:120]}")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
        opened, watch.data_dir = list(watch.outside), None
    if opened:
        t.outside_reads += 1
        t.fail("outside read", f"{desc}: opened {opened[0]}")


#: Tokens a mutation puts in place of a value: wrong types, absurd numbers, traversal.
TOKENS = ["null", "[]", "{}", '"abc"', "true", "-1", "1e400", "nan", "1e155", '[[1, 2], [3]]', '[1, "x"]',
          '"../outside/secret.txt"', '"../../../../../../../../etc/hostname"', "0", '""', "[" * 60 + "]" * 60]


def _mutate_bytes(data: bytes, rng: np.random.Generator, canary: Path) -> tuple[str, bytes]:
    """One damaged variant of a text file's bytes and the damage's name."""
    kind = str(rng.choice(["insert", "delete", "truncate", "junk", "latin1", "token", "token", "token", "dup_line",
                           "swap_lines", "path", "empty", "deep"]))
    n = len(data)
    pos = int(rng.integers(0, n + 1))
    if kind == "insert":
        return kind, data[:pos] + rng.bytes(int(rng.integers(1, 9))) + data[pos:]
    if kind == "delete":
        return kind, data[:pos] + data[pos + int(rng.integers(1, 40)):]
    if kind == "truncate":
        return kind, data[:pos]
    if kind == "junk":
        return kind, rng.bytes(int(rng.integers(1, 4096)))
    if kind == "latin1":
        return kind, data[:pos] + b"caf\xe9 \xff\xfe" + data[pos:]
    if kind == "empty":
        return kind, b""
    if kind == "deep":
        return kind, data[:pos] + b"[" * 3000 + b"]" * 3000 + data[pos:]
    lines = data.split(b"\n")
    if kind in ("dup_line", "swap_lines") and len(lines) > 1:
        i, j = (int(x) for x in rng.integers(0, len(lines), size=2))
        if kind == "dup_line":
            lines.insert(j, lines[i])
        else:
            lines[i], lines[j] = lines[j], lines[i]
        return kind, b"\n".join(lines)
    if kind == "path":
        target = str(rng.choice(["../outside/secret.txt", "../../../../../../../../etc/hostname", str(canary),
                                 "/etc/hostname", "..", "."]))
        names = [m for m in _NAME_RE.finditer(data)]
        if names:
            m = names[int(rng.integers(len(names)))]
            return kind, data[:m.start(1)] + target.encode() + data[m.end(1):]
    # token: replace one number, string or bracketed value with a wrong one
    spans = [m.span() for m in _VALUE_RE.finditer(data)]
    if not spans:
        return "insert", data[:pos] + b"\x00" + data[pos:]
    a, b = spans[int(rng.integers(len(spans)))]
    return "token", data[:a] + str(rng.choice(TOKENS)).encode() + data[b:]


import re  # noqa: E402

_VALUE_RE = re.compile(rb'-?\d+(?:\.\d+)?(?:e-?\d+)?|"[^"\n]*"|\[[^\[\]\n]*\]|null|true|false')
_NAME_RE = re.compile(rb'["\' ]?([\w./-]+\.(?:png|yaml|csv|gz|jsonl|txt))')


def _mutate_binary(data: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    """One damaged variant of a binary file: flipped bytes, a length-like field set huge, a zeroed or
    repeated span, or a cut (record framing and length prefixes are what binary parsers trust)."""
    kind = str(rng.choice(["flip", "huge_field", "zero_span", "repeat_span", "truncate"]))
    buf = bytearray(data)
    n = len(buf)
    pos = int(rng.integers(0, max(n - 8, 1)))
    if kind == "flip":
        for i in rng.integers(0, n, size=int(rng.integers(1, 17))):
            buf[int(i)] ^= int(rng.integers(1, 256))
    elif kind == "huge_field":
        buf[pos:pos + 8] = bytes([0xFF] * 4 + [0x7F] * 4) if rng.random() < 0.5 else b"\xff" * 8
    elif kind == "zero_span":
        buf[pos:pos + int(rng.integers(1, 4096))] = b"\0" * len(buf[pos:pos + 4096])
    elif kind == "repeat_span":
        span = bytes(buf[pos:pos + int(rng.integers(1, 2048))])
        buf[pos:pos] = span
    else:
        del buf[pos:]
    return kind, bytes(buf)


def _fs_mutation(path: Path, rng: np.random.Generator, canary: Path) -> str:
    """Replace ``path`` by a FIFO, a directory, a symlink outside, or remove it."""
    kind = str(rng.choice(["fifo", "dir", "symlink_out", "missing"]))
    if path.is_dir() and not path.is_symlink():
        import shutil

        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "dir":
        path.mkdir()
    elif kind == "symlink_out":
        path.symlink_to(canary)
    return kind


#: Import formats of the "import" file campaign (`handeye.app.formats` names), in rotation order.
IMPORT_KINDS = ("easy_handeye2", "easy_handeye", "industrial_calibration", "pose_csv", "visp", "image_folder",
                "opencv_storage", "moveit_calibration", "ros2_bag")
#: Seeds of the bag campaign (``--bag-cases``): the same recording in both rosbag2 storages.
BAG_KINDS = ("ros2_bag", "ros2_bag_sqlite3")

#: The file each import kind hands to `handeye.app.formats.load` (the others load their directory).
IMPORT_MAIN = {"easy_handeye2": "cell.samples", "easy_handeye": "samples.yaml", "opencv_storage": "pairs.yaml",
               "moveit_calibration": "pose_samples.json"}


def _msg(T) -> dict:
    t, q = tf.to_xyz_quat(T)
    return {"translation": dict(zip("xyz", map(float, t))), "rotation": dict(zip("xyzw", map(float, q)))}


def _write_image_folder(folder: Path, d) -> None:
    """Three tiny (96 px) rendered views of a 5 cm DICT_4X4_50 marker, flat depth, plain intrinsics.

    The robot poses are the simulated cell's; the images are not consistent with
    them (a fuzz seed only has to load, not to calibrate), which keeps a case fast.
    """
    import json

    import cv2

    marker = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), 0, 40)
    rows = []
    for i in range(3):
        img = np.full((96, 96), 255, np.uint8)
        img[24 + 4 * i:64 + 4 * i, 28:68] = marker
        cv2.imwrite(str(folder / f"img_{i}.png"), img)
        cv2.imwrite(str(folder / f"depth_{i}.png"), np.full((96, 96), 250, np.uint16))  # mm
        xyz, q = tf.to_xyz_quat(d.A[i])
        rows.append({"image": f"img_{i}.png", "depth": f"depth_{i}.png",
                     **dict(zip(("x", "y", "z", "qx", "qy", "qz", "qw"), map(float, [*xyz, *q])))})
    (folder / "poses.json").write_text(json.dumps({"setup": "eye_to_hand", "poses": rows}, indent=1))
    (folder / "intrinsics.yaml").write_text("fx: 200.0\nfy: 200.0\ncx: 48.0\ncy: 48.0\n"
                                            "dist: [0.0, 0.0, 0.0, 0.0, 0.0]\n")


def _write_bag(out: Path, storage: str, rng: np.random.Generator) -> None:
    """Three stops of the rendered demo at 480x360 and 5 fps, near the start pose (every marker found),
    moving frames not rendered (to keep a case fast)."""
    from handeye.mocks.render.camera import RenderedCameraConfig
    from handeye.mocks.ros2_bag import write_demo_bag

    out.rmdir()  # rosbags creates the bag directory itself
    small = RenderedCameraConfig(width=480, height=360, fx=427.5, fy=427.5, cx=239.5, cy=179.5)
    write_demo_bag(out, storage=storage, n_poses=3, seed=int(rng.integers(1 << 16)), fps=5.0, tf_hz=50.0,
                   render_moving=False, marker_topic=True, spread=(0.1, 25.0), camera=small)


def write_import_seed(kind: str, seeds: Path, rng: np.random.Generator) -> Path:
    """A valid file set of importer ``kind`` (`IMPORT_KINDS`) in ``seeds / kind``, from simulated data.

    Returns the directory; `handeye.app.formats.load` takes it, or its `IMPORT_MAIN` file.
    The industrial_calibration seed copies three views of the shared data set
    (`bench.datasets.datasets_dir`); `SystemExit` if it is missing.
    """
    import shutil

    import yaml

    from bench.datasets import datasets_dir
    from handeye.app.formats.moveit import write_moveit
    from handeye.app.formats.opencv_storage import write_opencv_storage
    from handeye.app.formats.visp import write_visp

    out = seeds / kind
    out.mkdir(parents=True)
    d = simulate.realistic_cell(8, rng)
    stored = tf.invert(d.A)  # eye-on-base files of easy_handeye store T_effector_base
    if kind == "easy_handeye2":
        (out / IMPORT_MAIN[kind]).write_text(yaml.safe_dump(
            {"parameters": {"name": "cell", "calibration_type": "eye_on_base"},
             "samples": [{"robot": _msg(R), "tracking": _msg(B)} for R, B in zip(stored, d.B)]}))
    elif kind == "easy_handeye":
        (out / IMPORT_MAIN[kind]).write_text(yaml.safe_dump(
            {"parameters": {"eye_on_hand": False},
             "samples": {"hand_world_samples": [_msg(R) for R in stored],
                         "camera_marker_samples": [_msg(B) for B in d.B]}}))
    elif kind == "industrial_calibration":
        src = datasets_dir() / "industrial_calibration" / "test_set_10x10"
        if not (src / "cal_data.yaml").exists():
            raise SystemExit(f"the industrial_calibration seed needs the shared datasets: {src} is missing "
                             "(set HANDEYE_DATASETS)")
        (out / "images").mkdir()
        (out / "poses").mkdir()
        doc = yaml.safe_load((src / "cal_data.yaml").read_text())
        doc["data"] = doc["data"][:3]  # three views keep a case fast
        for e in doc["data"]:
            shutil.copy(src / e["image"], out / e["image"])
            shutil.copy(src / e["pose"], out / e["pose"])
        (out / "cal_data.yaml").write_text(yaml.safe_dump(doc))
    elif kind == "pose_csv":
        t = np.arange(60) * 0.05
        A = simulate.realistic_cell(60, rng).A
        for name, T in (("hand.csv", A), ("target.csv", tf.invert(A))):
            xyz, q = tf.to_xyz_quat(T)
            rows = np.column_stack([t, xyz, q])
            (out / name).write_text("t,x,y,z,qx,qy,qz,qw\n" + "\n".join(",".join(f"{v:.9f}" for v in r)
                                                                         for r in rows))
        (out / "streams.toml").write_text('format = "pose_csv"\nsetup = "eye_in_hand"\nrobot = "hand.csv"\n'
                                          'camera = "target.csv"\nclock_offset = 0.0\nrefine = false\n')
    elif kind == "visp":
        write_visp(out, d.A, d.B)
    elif kind == "image_folder":
        _write_image_folder(out, d)
    elif kind == "opencv_storage":
        write_opencv_storage(out / IMPORT_MAIN[kind], d.A, d.B, setup="eye_to_hand")
    elif kind == "moveit_calibration":
        write_moveit(out / IMPORT_MAIN[kind], d.A, d.B)
    elif kind in BAG_KINDS:
        _write_bag(out, "sqlite3" if kind.endswith("sqlite3") else "mcap", rng)
    else:
        raise ValueError(f"unknown import kind {kind!r} (one of {IMPORT_KINDS})")
    return out


def _seed_files(work: Path, kind: str, rng: np.random.Generator) -> dict[str, Path]:
    """Valid inputs to damage for campaign ``kind``: a config, a session with frames, or one file set per importer."""
    import shutil

    from handeye.app.session import SessionWriter
    from handeye.calib.observation import Observation

    seeds = work / "seeds"
    seeds.mkdir(parents=True)
    if kind == "config":
        shutil.copy(Path(__file__).resolve().parents[1] / "config" / "sim.toml", seeds / "config.toml")
        return {"config": seeds / "config.toml"}
    if kind in ("import", "bags"):
        return {name: write_import_seed(name, seeds, rng) for name in (IMPORT_KINDS if kind == "import" else BAG_KINDS)}
    d = simulate.realistic_cell(8, rng)
    with SessionWriter.create(seeds, "eye_to_hand", name="session", truth={"T_base_cam": d.Y}) as w:
        img = np.zeros((8, 8, 3), np.uint8)
        for i in range(len(d.A)):
            w.add_sample(Observation(i, float(i), d.A[i], d.points[i], d.point_cov[i], d.B[i]),
                         color=img if i < 2 else None, depth=np.ones((8, 8), np.float32) if i < 2 else None)
            if i == 3:
                w.add_skip(3.5, "marker not found", T_base_flange=d.A[i])
                w.add_event(3.6, "note", text="x")
    return {"session": seeds / "session"}


#: The main file of each kind: damaged most of the time, so the damage reaches its parser.
MAIN_FILES = ("samples.jsonl", "session.json", "cal_data.yaml", "streams.toml", "poses.json", "intrinsics.yaml",
              "config.toml", "ros2_bag.mcap", "ros2_bag_sqlite3.db3", *IMPORT_MAIN.values())
#: Binary files: damaged byte-wise (`_mutate_binary`) as often as like text.
BINARY_SUFFIXES = (".mcap", ".db3")


def _pick_file(case_dir: Path, rng: np.random.Generator) -> Path:
    files = sorted(p for p in case_dir.rglob("*") if p.is_file())
    main = [p for p in files if p.name in MAIN_FILES]
    pool = main if main and rng.random() < 0.7 else files
    return pool[int(rng.integers(len(pool)))]


def run_file_campaign(kind: str, n_cases: int, rng: np.random.Generator, work: Path,
                      watch: _OpenWatch) -> dict[str, Tally]:
    """``n_cases`` damaged files of ``kind`` ("config", "session", "import", "bags"): a tally per seed file set.

    The import cases rotate over `IMPORT_KINDS`, so each importer gets ``n_cases / 9``; the bag cases
    over `BAG_KINDS` (MCAP and sqlite3).
    """
    import shutil

    from handeye.app import devices
    from handeye.app.config import load_config
    from handeye.app.formats import load
    from handeye.app.session import SessionWriter, read_session

    seeds = _seed_files(work / kind, kind, rng)
    outside = work / kind / "cases" / "outside"
    outside.mkdir(parents=True)
    canary = outside / "secret.txt"
    canary.write_text("not yours\n")
    names = list(seeds)
    tallies = {name: Tally() for name in names}
    for i in range(n_cases):
        name = names[i % len(names)]
        case = work / kind / "cases" / f"{i:04d}"
        src = seeds[name]
        if src.is_dir():
            shutil.copytree(src, case / src.name)
        else:
            case.mkdir(parents=True)
            shutil.copy(src, case / src.name)
        data_dir = case / src.name if src.is_dir() else case
        target = _pick_file(case, rng)
        # A config is named by the user, who may well symlink it: only data files must stay inside.
        if rng.random() < 0.12 and target.name not in ("config.toml", *IMPORT_MAIN.values()):
            mut = f"{target.name}:{_fs_mutation(target, rng, canary)}"
        else:
            binary = target.suffix in BINARY_SUFFIXES and rng.random() < 0.5
            m, damaged = _mutate_binary(target.read_bytes(), rng) if binary \
                else _mutate_bytes(target.read_bytes(), rng, canary)
            target.write_bytes(damaged)
            mut = f"{target.name}:{m}"
        desc = f"{name} #{i} {mut}"
        if name == "config":
            def fn(p=case / src.name, tmp=case):
                cfg = load_config(p)
                cfg = cfg.model_copy(update={"session": cfg.session.model_copy(update={"root": str(tmp / "sessions")})})
                devices.check_session_root(cfg)
        elif name == "session":
            def fn(p=data_dir):
                s = read_session(p)
                for obs in s.observations:
                    s.load_frames(obs)
                SessionWriter.resume(p).close()
        else:
            def fn(p=data_dir / IMPORT_MAIN[name] if name in IMPORT_MAIN else data_dir):
                load(p)
        _run_file_case(tallies[name], watch, data_dir, desc, fn)
        shutil.rmtree(case, ignore_errors=True)
    return tallies


# -------------------------------------------------------------------- reporting


def format_table(rows: dict[str, Tally], elapsed: float) -> str:
    lines = [
        "| campaign | cases | ok | clean errors | crashes (non-HandeyeError) | NaN results | warnings | hangs "
        "| reads outside data dir |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, t in rows.items():
        lines.append(f"| {name} | {t.cases} | {t.ok} | {t.clean_errors} | {t.crashes} | {t.nan_results} | "
                     f"{t.warned} | {t.hangs} | {t.outside_reads} |")
    lines.append("")
    lines.append(f"Time: {elapsed:.0f} s.")
    for name, t in rows.items():
        if t.examples:
            lines.append(f"\nFirst failures of {name}:")
            lines.extend(f"- {e}" for e in t.examples)
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    """Run the campaign; returns 1 if any case failed, else 0."""
    ap = argparse.ArgumentParser(prog="python -m bench.fuzz", description=__doc__.split("\n")[0])
    ap.add_argument("--solver-cases", type=int, default=10_000)
    ap.add_argument("--file-cases", type=int, default=500, help="cases for each of configs, sessions, imports")
    ap.add_argument("--bag-cases", type=int, default=500, help="damaged ROS 2 bags (MCAP and sqlite3)")
    ap.add_argument("--only", choices=["solver", "config", "session", "import", "bags", "monitor"], action="append",
                    help="run only these campaigns (repeatable; default all)")
    ap.add_argument("--monitor-examples", type=int, default=300, help="runs of the monitoring engine's state machine")
    ap.add_argument("--monitor-runs", type=int, default=200, help="composed production programs through the engine")
    ap.add_argument("--monitor-replays", type=int, default=20,
                    help="composed programs through replay --monitor, per kind of reference")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="out/bench")
    args = ap.parse_args(argv)
    import logging

    logging.disable(logging.WARNING)  # torn lines and skipped images are expected by the thousand
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    only = set(args.only or ["solver", "config", "session", "import", "bags", "monitor"])
    rows = {"solver API": run_solver_campaign(args.solver_cases, rng)} if "solver" in only else {}
    monitor_text, monitor_failed = "", False
    if "monitor" in only:
        from bench import monitor_campaign

        monitor_text = monitor_campaign.report(args.monitor_examples, args.monitor_runs, args.monitor_replays,
                                               args.seed)
        monitor_failed = "FAILED" in monitor_text or monitor_campaign.failed(monitor_text)
    import tempfile

    with tempfile.TemporaryDirectory(prefix="handeye-fuzz-") as tmp:
        watch = _OpenWatch(Path(tmp))
        for kind, label in (("config", "config files"), ("session", "session directories"),
                            ("import", "import files"), ("bags", "ROS 2 bags")):
            if kind not in only:
                continue
            by_seed = run_file_campaign(kind, args.bag_cases if kind == "bags" else args.file_cases, rng,
                                        Path(tmp), watch)
            if kind in ("import", "bags"):  # the total, then one row per importer
                rows[label] = Tally.total(by_seed.values())
                rows.update({f"- {name}": t for name, t in by_seed.items()})
            else:
                rows[label] = by_seed[kind]
    report = ("## Input fuzzing\n\n" + format_table(rows, time.perf_counter() - t0) if rows else "") + monitor_text
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fuzz.md").write_text(report)
    print(report)
    return 1 if monitor_failed or any(t.failures for t in rows.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
