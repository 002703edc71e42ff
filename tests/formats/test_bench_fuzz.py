"""app.benchmarks.fuzz: every import seed is a valid file set before the campaign damages it."""

import numpy as np
import pytest

from app.benchmarks.datasets import datasets_dir
from app.benchmarks.fuzz import IMPORT_KINDS, IMPORT_MAIN, write_import_seed
from app.formats import detect_format, load

@pytest.mark.parametrize("kind", IMPORT_KINDS)
def test_each_import_seed_loads_cleanly(tmp_path, kind):
    if kind == "industrial_calibration" and not (datasets_dir() / "industrial_calibration").is_dir():
        pytest.skip("the industrial_calibration seed copies the shared data set (HANDEYE_DATASETS)")
    folder = write_import_seed(kind, tmp_path, np.random.default_rng(0))
    path = folder / IMPORT_MAIN[kind] if kind in IMPORT_MAIN else folder
    assert detect_format(path) == kind  # so the damage is judged by the right importer
    imported = load(path)
    assert len(imported.observations) >= 3
    assert not imported.meta.get("skipped"), imported.meta.get("skipped")
    assert np.isfinite(imported.A).all()
    assert all(np.isfinite(o.point_cam).all() for o in imported.observations)
