"""``handeye verify --session`` (offline, the cross-session check) and report.html in headless Chromium."""

import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from handeye.app import exit_status
from handeye.app import verify as av
from handeye.app.cli import main
from handeye.app.errors import SessionError
from handeye.app.report import PLOT_CLASS
from handeye.app.session import SessionWriter
from handeye.calib import simulate
from handeye.calib import transforms as tf
from handeye.calib import verify as cv
from handeye.calib.observation import Observation


@pytest.fixture
def two_sessions(tmp_path):
    """One eye-to-hand cell recorded twice (the same truth): 25 samples each, sub-millimetre point noise."""
    d = simulate.realistic_cell(50, np.random.default_rng(4), sigma_lateral=3e-4, sigma_depth=6e-4)
    paths = []
    for k, part in enumerate((range(25), range(25, 50))):
        with SessionWriter.create(tmp_path / "sessions", "eye_to_hand", name=f"s{k}", truth={"T_base_cam": d.Y},
                                  source="test") as w:
            for i in part:
                w.add_sample(Observation(i, float(i), d.A[i], d.points[i], d.point_cov[i], d.B[i], None))
        paths.append(w.path)
    return paths, d


def _verify(capsys, *argv):
    rc = main(["verify", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


def _doc(out):
    path = re.search(r"verify.yaml \(the figures\): (\S+)", out).group(1)
    return yaml.safe_load(open(path)), path


def test_cross_session_pass_and_a_shifted_result_fails(two_sessions, tmp_path, capsys):
    (s0, s1), d = two_sessions
    assert main(["replay", str(s0), "--out", str(s0)]) == 0
    capsys.readouterr()
    rc, out, err = _verify(capsys, "--result", s0 / "result.yaml", "--session", s1, "--session-root", tmp_path / "v")
    assert rc == 0, err
    doc, path = _doc(out)
    v = doc["verification"]
    assert doc["mode"] == "offline" and doc["source"] == str(s1) and v["n_poses"] == 25 and v["passed"]
    assert v["calibration_error_mm"] < 1.0 and "PASS" in out
    assert (tmp_path / "v").glob("*/report.html")
    # The same result 3 mm off (in the file, as a user's edit or another tool's output would be): exit 4.
    res = yaml.safe_load((s0 / "result.yaml").read_text())
    T = np.array(res["camera_transform"]["matrix"])
    res["camera_transform"]["matrix"] = cv.perturbed(T, 0.0, 3.0, np.random.default_rng(0)).tolist()
    del res["camera_transform_raw_points"]
    bad = tmp_path / "bad" / "result.yaml"
    bad.parent.mkdir()
    bad.write_text(yaml.safe_dump(res))
    rc, out, _ = _verify(capsys, "--result", bad, "--session", s1, "--session-root", tmp_path / "v")
    assert rc == 4 and "FAIL" in out
    assert _doc(out)[0]["verification"]["calibration_error_mm"] == pytest.approx(3.0, rel=0.2)
    # A looser tolerance passes it.
    assert _verify(capsys, "--result", bad, "--session", s1, "--session-root", tmp_path / "v",
                   "--tolerance", "5,1")[0] == 0


def test_verification_poses_that_repeat_the_calibrations_are_flagged(two_sessions, tmp_path, capsys):
    """A verification session whose first 13 poses are the calibration's own (replay --out's result names its
    samples): the verdict warns, says how many, and verify.yaml lists them."""
    (s0, s1), d = two_sessions
    out_dir = tmp_path / "out"
    assert main(["replay", str(s0), "--out", str(out_dir)]) == 0
    capsys.readouterr()
    with SessionWriter.create(tmp_path / "sessions", "eye_to_hand", name="mixed", source="test") as w:
        for i in list(range(13)) + list(range(25, 37)):
            w.add_sample(Observation(i, float(i), d.A[i], d.points[i], d.point_cov[i], d.B[i], None))
    rc, out, _ = _verify(capsys, "--result", out_dir / "result.yaml", "--session", w.path, "--session-root",
                         tmp_path / "v")
    doc, _ = _doc(out)
    assert rc == exit_status.WARN and doc["verdict"]["level"] == "warn"
    assert doc["repeated_calibration_poses"] == list(range(13))
    assert "13 of 25 verification poses repeat calibration poses" in out
    # The fresh session alone: no such warning.
    rc, out, _ = _verify(capsys, "--result", out_dir / "result.yaml", "--session", s1, "--session-root",
                         tmp_path / "v")
    assert rc == 0 and "repeat calibration poses" not in out and _doc(out)[0]["repeated_calibration_poses"] == []


def test_frame_safety_warns_about_an_inverted_result(two_sessions, tmp_path, capsys):
    (s0, s1), d = two_sessions
    assert main(["replay", str(s0), "--out", str(s0)]) == 0
    capsys.readouterr()
    prior = ",".join(f"{v:.0f}" for v in (d.Y[:3, 3] * 1e3 + [40, -30, 20]))
    rc, out, _ = _verify(capsys, "--result", s0, "--session", s1, "--session-root", tmp_path / "v",
                         "--expect-xyz", prior)
    assert rc == 0 and "warning:" not in out
    res = yaml.safe_load((s0 / "result.yaml").read_text())
    res["camera_transform"]["matrix"] = tf.invert(np.array(res["camera_transform"]["matrix"])).tolist()
    (tmp_path / "inv.yaml").write_text(yaml.safe_dump(res))
    rc, out, _ = _verify(capsys, "--result", tmp_path / "inv.yaml", "--session", s1, "--session-root",
                         tmp_path / "v", "--expect-xyz", prior)
    assert rc == 4 and "probably inverted" in out
    assert "probably inverted" in _doc(out)[0]["frame_safety"]["warnings"][0]


def test_verify_refuses_its_own_session_and_bad_input(two_sessions, tmp_path, capsys):
    (s0, s1), d = two_sessions
    assert main(["replay", str(s0), "--out", str(s0)]) == 0
    capsys.readouterr()
    rc, _, err = _verify(capsys, "--result", s0 / "result.yaml", "--session", s0, "--session-root", tmp_path)
    assert rc == 1 and "did not see" in err and len(err.strip().splitlines()) == 1
    (tmp_path / "junk.yaml").write_text("format: handeye-result\nsetup: eye_to_hand\n")
    rc, _, err = _verify(capsys, "--result", tmp_path / "junk.yaml", "--session", s1, "--session-root", tmp_path)
    assert rc == 1 and "camera_transform.matrix missing" in err
    # A recording of two samples: one line naming it, and no empty verify directory left behind.
    few = tmp_path / "few"
    with SessionWriter.create(tmp_path, "eye_to_hand", name="few", source="test") as w:
        for i in range(2):
            w.add_sample(Observation(i, float(i), d.A[i], d.points[i], d.point_cov[i], d.B[i], None))
    rc, _, err = _verify(capsys, "--result", s0 / "result.yaml", "--session", few, "--session-root",
                         tmp_path / "verify")
    assert rc == 1 and err.strip() == (f"handeye verify: error: verification needs at least 3 poses with a "
                                       f"measurement, {few} has 2") and not list((tmp_path / "verify").glob("*"))
    with pytest.raises(SystemExit):
        main(["verify", "--result", str(s0), "--tolerance", "2"])
    with pytest.raises(SystemExit):
        main(["verify", "--result", str(s0), "--expect-xyz", "1,2"])


def test_report_renders_in_headless_chromium(two_sessions, tmp_path, capsys, render_page, render_pdf):
    """replay --out's and verify's report.html: every plot present, no console message, nothing fetched, one
    heading per section; printed to PDF, the verdict is the first text (and the calibration's verdict is the
    one in result.yaml, the verification's the one in verify.yaml)."""
    (s0, s1), _ = two_sessions
    assert main(["replay", str(s0), "--out", str(s0)]) == 0
    capsys.readouterr()
    rc, out, _ = _verify(capsys, "--result", s0, "--session", s1, "--session-root", tmp_path / "v")
    assert rc == 0
    verify_report = re.search(r"hand over the report: (\S+)", out).group(1)
    for page, n_plots in ((s0 / "report.html", 5), (verify_report, 6)):
        text = open(page, encoding="utf-8").read()
        assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", text), "the page must not fetch anything"
        dom, console = render_page(page)
        assert console == [], console
        plots = re.findall(rf'<figure class="{PLOT_CLASS}" data-title="([^"]+)"><svg', dom)
        assert len(plots) == n_plots, plots
        headings = re.findall(r"<h2>([^<]+)</h2>", dom)
        for heading in ("Cell", "Camera transform", "Marker", "Setup and frames", "Pose coverage",
                        "Residuals per sample", "Error ellipses of the camera position", "Camera correction",
                        "Sign-off", "Appendix: statistics", "Appendix: held-out prediction"):
            assert heading in headings, heading
        assert len(headings) == len(set(headings)) and not re.search(r"<h3>", dom)   # no heading twice
        verdict = yaml.safe_load(open(Path(page).parent / ("verify.yaml" if page == verify_report
                                                          else "result.yaml")))["verdict"]
        pdf, first_page = render_pdf(page)
        words = " ".join(first_page.split())
        assert words.startswith(f"{verdict['level'].upper()} {' '.join(verdict['summary'].split()[:6])}"), words[:300]
        assert "Cell" in words and pdf.stat().st_size < 2e6
    assert "<h2>Verification</h2>" in dom and '<span class="level">PASS</span>' in dom


def test_the_browser_check_sees_console_errors_and_missing_plots(tmp_path, render_page):
    """The check above can fail: a page with a script error and no plots is caught."""
    page = tmp_path / "broken.html"
    page.write_text('<!DOCTYPE html><html><body><div class="plot"></div><script>console.error("x"); nope();'
                    "</script></body></html>")
    dom, console = render_page(page)
    assert len(console) == 2 and "nope is not defined" in console[1]
    assert not re.findall(rf'<figure class="{PLOT_CLASS}" data-title="([^"]+)"><svg', dom)


RESULT_PATHS = [("setup",), ("camera_transform",), ("camera_transform", "matrix"), ("camera_transform", "matrix", 0),
                ("camera_transform", "matrix", 1, 3), ("marker_transform", "matrix", 2), ("marker_transform",),
                ("marker_transform", "rotation_known"), ("camera_transform_raw_points", "matrix"), ("model",),
                ("model", "noise"), ("model", "noise", "camera_point_scale"), ("model", "noise", "robot_mm"),
                ("model", "noise", "marker_rotation_deg"), ("model", "camera_correction"),
                ("model", "camera_correction", "depth_scale_percent"),
                ("model", "camera_correction", "depth_offset_mm", "value"), ("format",)]


@pytest.fixture(scope="module")
def result_doc(tmp_path_factory):
    """A result.yaml of auto with a camera correction and a noise model (every field load_result reads)."""
    from handeye.app.formats import write_result
    from handeye.calib import solve

    d = simulate.realistic_cell(30, np.random.default_rng(5))
    path = write_result(solve("auto", d.A, d.points * 1.02), tmp_path_factory.mktemp("res") / "result.yaml")
    doc = yaml.safe_load(path.read_text())
    assert doc["model"]["camera_correction"]["depth_scale_percent"]["estimated"]
    return doc


def test_every_result_field_damaged_is_a_session_error_or_loads(result_doc, tmp_path):
    """Any value anywhere in result.yaml: a SessionError naming the file, or a model that judges finitely."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    values = st.recursive(st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=5),
                          lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=3), inner,
                                                                                       max_size=3), max_leaves=12)

    @settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(where=st.sampled_from(RESULT_PATHS), value=values)
    def check(where, value):
        import copy

        doc = copy.deepcopy(result_doc)
        node = doc
        for k in where[:-1]:
            node = node[k]
        node[where[-1]] = value
        path = tmp_path / "result.yaml"
        path.write_text(yaml.safe_dump(doc))
        try:
            loaded = av.load_result(path)
        except SessionError as e:
            assert str(path) in str(e)
            return
        d = simulate.realistic_cell(5, np.random.default_rng(1))
        e = cv.prediction_errors(loaded.model, d.A, d.points, d.point_cov)
        assert np.isfinite(e.translation).all() and np.isfinite(e.noise_var).all()

    check()
    # A depth scale of -100 % (a division by zero for the correction) is refused by name.
    doc = yaml.safe_load(yaml.safe_dump(result_doc))
    doc["model"]["camera_correction"]["depth_scale_percent"]["value"] = -100.0
    (tmp_path / "r.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(SessionError, match="correction"):
        av.load_result(tmp_path / "r.yaml")


def test_verify_connects_before_it_asks(two_sessions, tmp_path, capsys, monkeypatch, loopback):
    """Active verify with no controller at robot.host and no --yes-move: the one line is the connection's, not
    the question about motion, which comes once the devices answer and the poses are planned (it came first)."""
    (s0, _), _ = two_sessions
    main(["replay", str(s0), "--out", str(s0)])
    capsys.readouterr()
    asked = []
    monkeypatch.setattr("handeye.app.commands.verify.confirm_motion", lambda yes_move: asked.append(yes_move))
    p = tmp_path / "c.toml"
    p.write_text(Path("config/ur10_xtion_eye_to_hand.toml").read_text().replace('"192.168.1.10"',
                                                                                f'"{loopback(70)}"'))
    rc, _, err = _verify(capsys, "-c", p, "--result", s0 / "result.yaml", "--session-root", tmp_path / "v", "--no-viz")
    assert rc == 1 and "cannot open RTDE receive on UR controller" in err and asked == [], err
