"""``handeye replay --out DIR`` writes what calibrate writes into its session, for every importer's data."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from handeye.app import exit_status
from bench.fuzz import IMPORT_MAIN, write_import_seed
from handeye.app.cli import main
from handeye.app.devices import RESULT_FILES
from handeye.calib import transforms as tf
from tests.app.verdict_status import printed_status

DATA = Path(__file__).parents[1] / "data"

#: Importers whose seed (bench.fuzz) has enough samples to solve; industrial_calibration and
#: pose_csv take the real recordings in tests/data, image_folder is rendered in test_formats_people_bring.
SEEDED = ["easy_handeye2", "easy_handeye", "visp", "opencv_storage", "moveit_calibration"]


def check_outputs(out: Path, capsys) -> dict:
    """Every export of RESULT_FILES and report.html are in ``out``, the printout names them; returns
    result.yaml, whose verdict the printout opens with."""
    printed = capsys.readouterr().out
    for kind, name in {**RESULT_FILES, "report": "report.html"}.items():
        assert (out / name).is_file() and (out / name).stat().st_size > 0, kind
        assert str(out / name) in printed
    doc = yaml.safe_load((out / "result.yaml").read_text())
    assert doc["format"] == "handeye-result" and doc["solver"] == "auto"
    verdict = doc["verdict"]
    assert verdict["level"] in ("pass", "warn", "fail") and verdict["summary"]
    lines = printed.splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith(("PASS:", "WARN:", "FAIL:")))
    assert lines[first] == f"{verdict['level'].upper()}: {verdict['summary']}" and first <= 3, lines[:5]
    tf.check_transform(np.array(doc["camera_transform"]["matrix"]), "camera_transform")
    return doc


@pytest.mark.parametrize("kind", SEEDED)
def test_replay_out_on_each_seeded_importer(kind, tmp_path, capsys):
    folder = write_import_seed(kind, tmp_path / "seeds", np.random.default_rng(3))
    source = folder / IMPORT_MAIN[kind] if kind in IMPORT_MAIN else folder
    rc = main(["replay", str(source), "--out", str(tmp_path / "out")])
    doc = check_outputs(tmp_path / "out", capsys)
    assert doc["n_samples"] == 8 and rc == exit_status.of_verdict(doc["verdict"]["level"])


@pytest.mark.parametrize("source, setup, n", [(DATA / "circle_grid" / "cal_data.yaml", "eye_in_hand", 15),
                                              (DATA / "ethz" / "robot_arm_sim", "eye_in_hand", None)])
def test_replay_out_on_the_real_recordings(source, setup, n, tmp_path, capsys):
    rc = main(["replay", str(source), "--out", str(tmp_path / "out")])
    doc = check_outputs(tmp_path / "out", capsys)
    assert doc["setup"] == setup and (n is None or doc["n_samples"] == n)
    assert rc == exit_status.of_verdict(doc["verdict"]["level"])
    if n == 15:
        # The 10x10-circle recording: residuals 17x what the camera's noise explains, 8 mm over the workspace.
        assert doc["verdict"]["level"] in ("warn", "fail") and doc["accuracy"]["rms_mm"] > 2
        assert any(r.startswith("residuals are 17x what the camera's noise explains") for r in doc["verdict"]["reasons"])
    if n is None:
        # A long stream: auto's choices were checked on contiguous stretches, which result and report show.
        assert doc["model"]["blocked_folds"]["folds"] == 5
        assert "contiguous stretches held out in turn" in (tmp_path / "out" / "report.html").read_text()


def test_replay_out_writes_the_recommended_of_several(tmp_path, capsys):
    """With -m all the comparison stays and the recommended solver's result is the one written."""
    source = DATA / "circle_grid" / "cal_data.yaml"
    rc = main(["replay", str(source), "-m", "YKronT'", "-m", "YQuatT'", "--out", str(tmp_path)])
    printed = capsys.readouterr().out
    assert rc == printed_status(printed), printed
    best = next(line.split(":")[1].strip() for line in printed.splitlines() if line.startswith("recommended:"))
    doc = yaml.safe_load((tmp_path / "result.yaml").read_text())
    assert doc["solver"] == best and "| YKronT' |" in printed and "| YQuatT' |" in printed


def test_replay_out_into_a_file_is_one_line_error(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    assert main(["replay", str(DATA / "circle_grid" / "cal_data.yaml"), "--out", str(tmp_path / "file")]) == 1
    err = capsys.readouterr().err
    assert "--out" in err and len(err.strip().splitlines()) == 1


def test_the_verify_line_pastes_into_a_shell_with_spaces_in_the_paths(tmp_path, capsys):
    """The printed ``verify`` command is quoted: pasted, it names the cell and the result, spaces and all."""
    import shlex

    cell = tmp_path / "my cell.toml"
    cell.write_text((Path(__file__).parents[2] / "config" / "sim.toml").read_text())
    out = tmp_path / "my out"
    for config in (["-c", str(cell)], []):
        assert main(["replay", str(DATA / "ethz" / "robot_arm"), "--out", str(out), *config]) == 0   # a PASS
        line = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("  verify on fresh"))
        argv = shlex.split(line.split(":", 1)[1])
        assert argv[1:] == ["verify", "-c", str(cell) if config else "<cell.toml>", "--result",
                            str(out / "result.yaml"), "--yes-move"], line
