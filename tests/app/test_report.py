"""report.html as a customer reads it: plain words before the appendix, the marker and its transform, a
sign-off block, the session named relative to where the run was started."""

import re
import shutil
from pathlib import Path

import pytest
import yaml

from handeye.app.cli import main
from handeye.app.config import load_config
from handeye.app.provenance import marker_description
from handeye.calib.vision.extract import TargetConfig

DATA = Path(__file__).resolve().parents[1] / "data"
#: The statisticians' words that belong in the appendix only.
TERMS = ("camera_transform_raw_points", "chi-square", "GLR", "held-out", "held out", "leave-one-out")


def _front_and_appendix(page: str) -> tuple[str, str]:
    """The page before its first appendix heading (plots' SVG left out) and from there on."""
    i = page.index("<h2>Appendix")
    return re.sub(r"<svg.*?</svg>", "", page[:i], flags=re.S), page[i:]


def test_the_customer_pages_speak_plainly_and_name_the_marker_and_who_signs(tmp_path, capsys, monkeypatch):
    """A replayed real recording (its result has a transform for corrected points and a self-check): none of the
    statisticians' terms before the appendix, the appendix keeps them; the marker-side transform, a sign-off
    block with the operator, and the recording named relative to where the command ran (it was absolute)."""
    monkeypatch.chdir(tmp_path)
    shutil.copytree(DATA / "ethz" / "robot_arm", tmp_path / "recording")
    main(["replay", "recording", "--out", "out", "--operator", "A. Smith"])
    capsys.readouterr()
    page = (tmp_path / "out" / "report.html").read_text()
    doc = yaml.safe_load((tmp_path / "out" / "result.yaml").read_text())
    assert "camera_transform_raw_points" in doc and doc["model"]["self_check"]   # the terms have a reason to be
    front, appendix = _front_and_appendix(page)
    assert [t for t in TERMS if t in front] == [], [t for t in TERMS if t in front]
    assert all(t in appendix for t in ("camera_transform_raw_points", "chi-square", "held-out"))
    mt = doc["marker_transform"]
    assert (f"<tr><td>{mt['name']}: the marker in the {mt['parent_frame']} frame, xyz [mm]</td><td>"
            + " ".join(f"{v * 1e3:.2f}" for v in mt["translation_m"]) + "</td></tr>") in front
    assert ("<h2>Sign-off</h2>" in front and "<tr><td>prepared by</td><td>A. Smith</td><td></td></tr>" in front
            and "<tr><td>checked by</td><td></td><td></td></tr>" in front)
    assert "<tr><td>samples from</td><td>recording</td></tr>" in front and str(tmp_path) not in front


@pytest.mark.parametrize("marker, words", [
    ({}, "ArUco DICT_4X4_50, id 0, 50 mm square"),
    ({"kind": "charuco", "squares": [5, 7], "square_size": 0.03, "marker_size": 0.022},
     "ChArUco DICT_4X4_50, 5x7 squares of 30 mm (markers 22 mm)"),
    ({"kind": "chessboard", "squares": [9, 6], "square_size": 0.025}, "chessboard, 9x6 squares of 25 mm")])
def test_the_marker_is_named_as_configured(marker, words):
    """The ``[marker]`` target in the words report.html's Marker section shows (type, dictionary, id, size)."""
    base = load_config(None).marker.model_dump()
    assert marker_description(TargetConfig(**{**base, **marker})) == words
