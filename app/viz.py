"""All rerun logging of handeye (the only module that imports ``rerun``).

Entity tree (base frame = ``world``, metres, z up)::

    world/base                   robot base axes
    world/flange                 robot flange pose (axes)
    world/camera                 estimated camera pose: T_base_cam (eye-to-hand)
    world/flange/camera          ... or T_flange_cam (eye-in-hand)
      .../image                  pinhole frustum, color image, depth image
      .../image/marker           detected marker center (2D)
    world/camera_truth           true camera pose (simulated cells only)
    world/samples/measured       marker centers seen by the camera, in the base frame
    world/samples/predicted      marker centers predicted by the estimate (A_i X)
    world/samples/residuals      segments measured -> predicted (one per sample)
    residuals/translation_mm     RMS residual of the latest estimate
    residuals/per_sample_mm      per-sample residuals of the latest estimate (bar chart, by sample)
    uncertainty/{sigma_mm,sigma_deg}   1-sigma of the camera transform over time
    drift/{translation_mm,rotation_deg} online estimate vs. the reference
    events                       alarms, skips, stops, the result (text log)
    result                       the final result (markdown)
    plan/flange                  planned flange poses (``handeye plan``; timeline ``plan_pose``)
    plan/camera/image            camera frustum and the predicted marker outline per planned pose
    plan/path                    the flange path through the planned poses
    plan/sigma_{mm,deg}          expected 1-sigma after each planned pose

A blueprint opens the recording in a useful layout: the 3D cell, the camera
image with the detected marker, residual / 1-sigma / drift plots, the events.

The live viewer is the ``rerun`` executable that ships with the installed
rerun-sdk (next to ``sys.executable``, else on PATH, else ``python -m
rerun``), started as our own child process listening on loopback only
(``viewer_bind``) so that the recording is not served to the network. The
viewer gets its own recording stream (same recording id) next to the one
that writes the ``.rrd``: a viewer that cannot start (no executable, no
display) or dies mid-run costs one warning line, never the file or the run.

A disabled `Viz` (``--no-viz``) logs nothing and never touches rerun.
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np

from handeye.calib import transforms as tf
from handeye.calib.result import worst_axis_sigma
from handeye.calib.setup import Setup, check_setup

log = logging.getLogger(__name__)


# A starting viewer gets this long to listen on its port; one that dies right after (no display:
# it binds first, then fails to open a window within ~50 ms) must stay up this much longer.
VIEWER_START_S = 10.0
VIEWER_GRACE_S = 0.7


class ViewerError(RuntimeError):
    """The live viewer could not be started (no executable, no display, ...); never fatal to a run."""


def viewer_command() -> list[str] | None:
    """Command that starts the rerun viewer shipped with the installed rerun-sdk, or None.

    The venv's ``rerun`` next to ``sys.executable`` comes first (a run as
    ``.venv/bin/handeye`` does not have the venv on PATH), then ``rerun`` on
    PATH, then ``python -m rerun_cli``.
    """
    exe = Path(sys.executable).with_name("rerun")
    if exe.is_file() and os.access(exe, os.X_OK):
        return [str(exe)]
    found = shutil.which("rerun")
    if found:
        return [found]
    import importlib.util

    if importlib.util.find_spec("rerun_cli") is not None:
        return [sys.executable, "-m", "rerun_cli"]
    return None


def open_command(rrd_path: Path) -> str:
    """Shell line that opens a recording in the viewer (printed at the end of a run)."""
    import shlex

    cmd = viewer_command() or ["rerun"]
    if cmd[0].startswith(os.getcwd() + os.sep):
        cmd[0] = os.path.relpath(cmd[0])
    return " ".join(shlex.quote(c) for c in [*cmd, str(rrd_path)])


def _free_port(host: str) -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


class Viewer:
    """A rerun viewer child process serving gRPC on ``bind`` (loopback unless asked otherwise).

    It runs in its own session so that Ctrl-C on the run leaves it open, and
    is left running when the run ends (the user closes it).

    Attributes
    ----------
    proc : subprocess.Popen
    url : str
        gRPC address the SDK connects to.
    """

    def __init__(self, proc: subprocess.Popen, url: str, stderr):
        self.proc, self.url, self._stderr = proc, url, stderr

    @classmethod
    def start(cls, bind: str = "127.0.0.1", *, timeout: float = VIEWER_START_S) -> "Viewer":
        """Start the viewer and wait until it listens and stays up.

        Raises
        ------
        ViewerError
            No viewer executable, or it exited / did not listen within ``timeout`` s
            (the message ends with the viewer's last stderr line).
        """
        import tempfile

        cmd = viewer_command()
        if cmd is None:
            raise ViewerError("no rerun viewer executable found (rerun-sdk ships one: pip install rerun-sdk)")
        # Connect through loopback also when the viewer listens on every interface.
        host = "127.0.0.1" if bind in ("0.0.0.0", "::", "") else bind
        port = _free_port(host)
        err = tempfile.TemporaryFile()
        try:
            proc = subprocess.Popen([*cmd, "--port", str(port), "--bind", bind, "--memory-limit", "25%"],
                                    stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err,
                                    start_new_session=True)
        except OSError as e:
            err.close()
            raise ViewerError(f"cannot run {cmd[0]}: {e}") from None
        viewer = cls(proc, f"rerun+http://{host}:{port}/proxy", err)
        deadline, listening_since = time.monotonic() + timeout, None
        while time.monotonic() < deadline:
            if proc.poll() is not None:
                raise ViewerError(f"viewer exited with status {proc.returncode}: {viewer.last_error()}")
            if listening_since is None:
                try:
                    socket.create_connection((host, port), timeout=0.2).close()
                    listening_since = time.monotonic()
                except OSError:
                    pass
            elif time.monotonic() - listening_since >= VIEWER_GRACE_S:
                return viewer
            time.sleep(0.05)
        viewer.stop()
        raise ViewerError(f"viewer not listening on {host}:{port} after {timeout:.0f} s")

    def alive(self) -> bool:
        return self.proc.poll() is None

    def last_error(self) -> str:
        """The viewer's last stderr line without terminal colours (why it died)."""
        import re

        self._stderr.seek(0)
        lines = [ln for ln in self._stderr.read().decode(errors="replace").splitlines() if ln.strip()]
        if not lines:
            return "no message"
        # Drop colour codes and the Rust source locations ("at /.../mod.rs:765:"), keep the reason.
        text = re.sub(r"\x1b\[[0-9;]*m", "", lines[-1])
        return re.sub(r"\s+at\s+\S+\.rs:\d+:?", "", text).strip()[:240]

    def stop(self) -> None:
        """Terminate the viewer (tests; a run leaves its viewer open)."""
        if self.alive():
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def blueprint(setup: Setup):
    """Layout the recording opens in: 3D cell | camera image with the marker, residual / 1-sigma /
    drift plots | per-sample residuals, events."""
    import rerun.blueprint as rrb

    cam = "world/flange/camera" if check_setup(setup).camera_on_flange else "world/camera"
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="cell (base frame)"),
            rrb.Vertical(
                rrb.Spatial2DView(origin=f"{cam}/image", name="camera + detected marker"),
                rrb.TimeSeriesView(origin="residuals", name="residual RMS [mm]"),
                rrb.TimeSeriesView(origin="uncertainty", name="1-sigma [mm, deg]"),
                rrb.TimeSeriesView(origin="drift", name="drift vs. reference [mm, deg]"),
            ),
            rrb.Vertical(
                rrb.BarChartView(origin="per_sample/residual_mm", name="residual per sample [mm]"),
                rrb.TextDocumentView(origin="result", name="result"),
                rrb.TextLogView(origin="events", name="events"),
            ),
            column_shares=[3, 2, 2],
        ),
        collapse_panels=True,
    )


class Viz:
    """rerun recording of a calibration or monitoring run.

    Parameters
    ----------
    setup : {"eye_to_hand", "eye_in_hand"}
    rrd_path : Path or None
        Where to save the recording (``.rrd`` beside the session).
    viewer : bool
        Also start a live viewer (`Viewer`); if it cannot start or dies, one
        warning is logged and the run and the file go on.
    viewer_bind : str
        Address the viewer listens on: loopback unless asked otherwise.
    enabled : bool
        False makes every method a no-op (rerun is not even imported).
    log_images : bool
        Log color and depth images (large recordings; off for long monitors).
    """

    def __init__(self, setup: Setup, rrd_path: Path | None = None, *, viewer: bool = False,
                 viewer_bind: str = "127.0.0.1", enabled: bool = True, log_images: bool = True):
        self.setup = check_setup(setup)
        self.enabled = enabled
        self.log_images = log_images
        self.rrd_path = rrd_path if enabled else None
        self.viewer: Viewer | None = None
        self._recs: list = []
        self._live = None
        self._file = None  # the stream writing rrd_path
        if not enabled:
            return
        # We report viewer trouble ourselves in one line; rerun's own log would repeat it every few seconds.
        os.environ.setdefault("RUST_LOG", "off")
        import rerun as rr

        self._rr = rr
        recording_id = self._recording_id = str(uuid.uuid4())
        if rrd_path is not None:
            self._file = self._open_file()
            self._recs.append(self._file)
        if viewer:
            try:
                self.viewer = Viewer.start(viewer_bind)
            except ViewerError as e:
                log.warning("rerun viewer not available (%s); the run goes on%s", e,
                            f" and is recorded in {rrd_path}" if rrd_path else "")
            else:
                # A separate stream (same recording id) so a dead viewer never touches the file's sink.
                self._live = rr.RecordingStream("handeye", recording_id=recording_id)
                self._live.set_sinks(rr.GrpcSink(self.viewer.url))
                self._live.send_blueprint(blueprint(setup))
                self._recs.append(self._live)
        for rec in self._recs:
            self._log_static(rec)
        self._cam_path = "world/flange/camera" if self.setup.camera_on_flange else "world/camera"
        self._measured: list[np.ndarray] = []

    def _open_file(self):
        rec = self._rr.RecordingStream("handeye", recording_id=self._recording_id)
        rec.save(str(self.rrd_path), default_blueprint=blueprint(self.setup))
        return rec

    def _log_static(self, rec) -> None:
        rr = self._rr
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log("world/base", rr.TransformAxes3D(0.2), static=True)
        rec.log("events", rr.TextLog(f"setup: {self.setup}"), static=True)

    def rotate(self, max_bytes: float) -> None:
        """Bounded disk for long runs: once the ``.rrd`` exceeds ``max_bytes``, it becomes
        ``<name>.old.rrd`` (replacing the previous one) and a fresh file starts (same recording id)."""
        if self._file is None or not self.rrd_path.exists() or self.rrd_path.stat().st_size <= max_bytes:
            return
        self._file.flush()
        self._file.disconnect()
        self._recs.remove(self._file)
        self.rrd_path.replace(self.rrd_path.with_name(self.rrd_path.stem + ".old.rrd"))
        self._file = self._open_file()
        self._log_static(self._file)
        self._recs.append(self._file)
        log.info("rerun recording rotated at %.0f MB: %s", max_bytes / 1e6, self.rrd_path)

    def _drop_live(self, why: str) -> None:
        log.warning("rerun viewer %s; the run goes on%s", why,
                    f" and is recorded in {self.rrd_path}" if self.rrd_path else "")
        live, self._live = self._live, None
        self._recs.remove(live)
        # Its sink may wait seconds for the dead viewer: let that happen off the sampling thread.
        import threading

        threading.Thread(target=live.disconnect, daemon=True).start()

    def _log(self, path: str, *entity, static: bool = False) -> None:
        if self._live is not None and not self.viewer.alive():
            self._drop_live(f"exited ({self.viewer.last_error()})")
        for rec in self._recs:
            rec.log(path, *entity, static=static)

    def _time(self, t: float, index: int | None = None) -> None:
        for rec in self._recs:
            rec.set_time("time", timestamp=t)
            if index is not None:
                rec.set_time("sample", sequence=index)

    def _transform(self, path: str, T: np.ndarray, *, static: bool = False) -> None:
        rr = self._rr
        self._log(path, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=static)
        self._log(path, rr.TransformAxes3D(0.1), static=static)

    def truth(self, T_camera_true: np.ndarray) -> None:
        """True camera transform of a simulated cell (static)."""
        if not self.enabled:
            return
        path = "world/flange/camera_truth" if self.setup.camera_on_flange else "world/camera_truth"
        self._transform(path, T_camera_true, static=True)

    def robot(self, t: float, T_base_flange: np.ndarray) -> None:
        """Flange pose at host time ``t``."""
        if not self.enabled:
            return
        self._time(t)
        self._transform("world/flange", T_base_flange)

    def frame(self, t: float, color, depth, intrinsics, marker_px=None) -> None:
        """Color/depth image with its pinhole, and the detected marker center (pixels) if any."""
        if not self.enabled:
            return
        rr = self._rr
        self._time(t)
        img = f"{self._cam_path}/image"
        self._log(img, rr.Pinhole(image_from_camera=intrinsics.K, width=intrinsics.width,
                                  height=intrinsics.height, camera_xyz=rr.ViewCoordinates.RDF))
        if self.log_images and color is not None:
            self._log(img, rr.Image(color, color_model="BGR"))
        if self.log_images and depth is not None:
            self._log(f"{img}/depth", rr.DepthImage(depth, meter=1.0))
        if marker_px is not None:
            self._log(f"{img}/marker", rr.Points2D([marker_px], radii=4.0, colors=[255, 0, 0]))

    def sample(self, obs, T_camera: np.ndarray | None) -> None:
        """An accepted sample: its flange pose and, given a camera estimate, the marker point in the base frame."""
        if not self.enabled:
            return
        self._time(obs.t, obs.index)
        self._transform("world/flange", obs.T_base_flange)
        if T_camera is not None and obs.point_cam is not None:
            T_base_cam = T_camera if self.setup == Setup.EYE_TO_HAND else obs.T_base_flange @ T_camera
            self._measured.append(tf.transform_points(T_base_cam, obs.point_cam))
            self._log("world/samples/measured",
                      self._rr.Points3D(np.array(self._measured), radii=0.004, colors=[0, 160, 255]))

    def estimate(self, t: float, result, observations) -> None:
        """Latest estimate: camera pose, predicted marker points, residuals (RMS and per sample), 1-sigma."""
        if not self.enabled:
            return
        rr = self._rr
        self._time(t, result.n_samples)
        self._transform(self._cam_path, result.camera_transform)
        A = np.array([o.T_base_flange for o in observations])
        if self.setup == Setup.EYE_TO_HAND:
            predicted = tf.transform_points(A @ result.X, np.zeros(3))
            T_base_cams = np.broadcast_to(result.Y, A.shape)
        else:
            predicted = np.broadcast_to(result.Y[:3, 3], (len(A), 3))
            T_base_cams = A @ result.X
        measured = np.array([tf.transform_points(T, o.point_cam if o.point_cam is not None else o.T_cam_marker[:3, 3])
                             for T, o in zip(T_base_cams, observations)])
        self._measured = list(measured)
        self._log("world/samples/measured", rr.Points3D(measured, radii=0.004, colors=[0, 160, 255]))
        self._log("world/samples/predicted", rr.Points3D(predicted, radii=0.003, colors=[255, 160, 0]))
        self._log("world/samples/residuals", rr.LineStrips3D(np.stack([measured, predicted], axis=1),
                                                             colors=[255, 60, 60]))
        self._log("residuals/translation_mm", rr.Scalars(result.residuals.rms_translation * 1e3))
        self._log("per_sample/residual_mm", rr.BarChart(np.asarray(result.residuals.translation) * 1e3))
        if result.sigma is not None:
            s_deg, s_mm = _sigma_deg_mm(result)
            self._log("uncertainty/sigma_mm", rr.Scalars(s_mm))
            self._log("uncertainty/sigma_deg", rr.Scalars(s_deg))

    def result(self, t: float, result) -> None:
        """The final result: a line in the events and a markdown summary (``result``)."""
        if not self.enabled:
            return
        rr = self._rr
        self._time(t, result.n_samples)
        cam = self.setup.camera_name
        xyz, q = tf.to_xyz_quat(result.camera_transform)
        line = (f"result: {cam} xyz [mm] = {np.array2string(xyz * 1e3, precision=2)}, "
                f"solver {result.method}, {result.n_samples} samples, "
                f"residual RMS {result.residuals.rms_translation * 1e3:.2f} mm")
        rows = [f"| {cam} xyz [mm] | {' '.join(f'{v:.2f}' for v in xyz * 1e3)} |",
                f"| {cam} quat (x,y,z,w) | {' '.join(f'{v:.5f}' for v in q)} |",
                f"| solver | {result.method} |", f"| samples | {result.n_samples} |",
                f"| residual RMS [mm] | {result.residuals.rms_translation * 1e3:.2f} |"]
        if result.sigma is not None:
            s_deg, s_mm = _sigma_deg_mm(result)
            line += f", 1-sigma {s_mm:.2f} mm / {s_deg:.3f} deg"
            rows.append(f"| 1-sigma [mm, deg] | {s_mm:.2f}, {s_deg:.3f} |")
        self._log("events", rr.TextLog(line, level="INFO"))
        self._log("result", rr.TextDocument(f"## handeye result ({self.setup})\n\n| | |\n|---|---|\n"
                                            + "\n".join(rows), media_type=rr.MediaType.MARKDOWN))

    def drift(self, t: float, translation_mm: float, rotation_deg: float) -> None:
        """Online estimate vs. the reference calibration."""
        if not self.enabled:
            return
        self._time(t)
        self._log("drift/translation_mm", self._rr.Scalars(translation_mm))
        self._log("drift/rotation_deg", self._rr.Scalars(rotation_deg))

    def event(self, t: float, text: str, level: str = "INFO") -> None:
        """An alarm, skip or stop, as a text log line."""
        if not self.enabled:
            return
        self._time(t)
        self._log("events", self._rr.TextLog(text, level=level))

    def plan(self, poses, X: np.ndarray, Y: np.ndarray, intrinsics, marker_size_m: float) -> None:
        """Planned poses (`handeye.calib.planner.PlannedPose`) of a dry run, one step of the ``plan_pose`` timeline
        each: flange axes, the camera frustum and what the camera would see (predicted marker outline and center).

        Eye-to-hand: ``X = T_flange_marker``, ``Y = T_base_cam``; eye-in-hand:
        ``X = T_flange_cam``, ``Y = T_base_marker``.
        """
        if not self.enabled:
            return
        rr = self._rr
        A = np.array([p.T_base_flange for p in poses])
        self._log("plan/path", rr.LineStrips3D([A[:, :3, 3]], colors=[200, 200, 200]), static=True)
        h = marker_size_m / 2
        corners = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0], [-h, -h, 0]])
        for i, p in enumerate(poses):
            for rec in self._recs:
                rec.set_time("plan_pose", sequence=i)
            T_base_cam = Y if not self.setup.camera_on_flange else p.T_base_flange @ X
            T_cam_marker = tf.invert(T_base_cam) @ (p.T_base_flange @ X if not self.setup.camera_on_flange else Y)
            self._transform("plan/flange", p.T_base_flange)
            self._transform("plan/camera", T_base_cam)
            img = "plan/camera/image"
            self._log(img, rr.Pinhole(image_from_camera=intrinsics.K, width=intrinsics.width,
                                      height=intrinsics.height, camera_xyz=rr.ViewCoordinates.RDF))
            pc = tf.transform_points(T_cam_marker, corners)
            uv = np.stack([intrinsics.fx * pc[:, 0] / pc[:, 2] + intrinsics.cx,
                           intrinsics.fy * pc[:, 1] / pc[:, 2] + intrinsics.cy], -1)
            self._log(f"{img}/marker", rr.LineStrips2D([uv], colors=[255, 0, 0]))
            self._log(f"{img}/center", rr.Points2D([p.pixel], radii=4.0, colors=[255, 0, 0]))
            s_rot, s_t = worst_axis_sigma(p.cov)
            self._log("plan/sigma_mm", rr.Scalars(s_t * 1e3))
            self._log("plan/sigma_deg", rr.Scalars(np.degrees(s_rot)))

    def close(self) -> None:
        """Flush and close the recording; viewer trouble is a warning, never an exception."""
        if self._live is not None:
            if not self.viewer.alive():
                self._drop_live(f"exited ({self.viewer.last_error()})")
            else:
                live, self._live = self._live, None
                self._recs.remove(live)
                try:
                    live.flush(timeout_sec=5.0)
                    live.disconnect()
                except RuntimeError as e:
                    log.warning("rerun viewer did not take the whole recording (%s); it is complete in %s",
                                str(e).splitlines()[0], self.rrd_path)
        for rec in self._recs:
            rec.flush()
            rec.disconnect()
        self._recs = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def _sigma_deg_mm(result) -> tuple[float, float]:
    """1-sigma of the camera transform at the edge units: (rotation deg, translation mm)."""
    s_rot, s_t = result.sigma
    return float(np.rad2deg(s_rot)), s_t * 1e3
