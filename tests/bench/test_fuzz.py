"""bench.fuzz: every import seed is a valid file set before the campaign damages it."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from bench.fuzz import BAG_KINDS, IMPORT_KINDS, IMPORT_MAIN, write_import_seed
from handeye.app.formats import detect_format, load

CIRCLE_GRID = Path(__file__).resolve().parents[1] / "data" / "circle_grid"


@pytest.mark.parametrize("kind", IMPORT_KINDS + BAG_KINDS[1:])
def test_each_import_seed_loads_cleanly(tmp_path, monkeypatch, kind):
    # The industrial_calibration seed copies views of the shared test_set_10x10; the suite's trimmed copy
    # of it stands in (same dot centers), laid out as upstream.
    shared = tmp_path / "datasets"
    shutil.copytree(CIRCLE_GRID, shared / "industrial_calibration" / "test_set_10x10")
    monkeypatch.setenv("HANDEYE_DATASETS", str(shared))
    folder = write_import_seed(kind, tmp_path, np.random.default_rng(0))
    path = folder / IMPORT_MAIN[kind] if kind in IMPORT_MAIN else folder
    assert detect_format(path) == kind.removesuffix("_sqlite3")  # so the damage is judged by the right importer
    imported = load(path)
    assert len(imported.observations) >= 3
    assert not imported.meta.get("skipped"), imported.meta.get("skipped")
    assert np.isfinite(imported.A).all()
    assert all(np.isfinite(o.point_cam).all() for o in imported.observations)
