"""Real recordings laid out as their tools write them, for the importers."""

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

DATA = Path(__file__).parents[1] / "data"


@pytest.fixture(scope="session")
def charuco_set(tmp_path_factory) -> Path:
    """industrial_calibration's test_set_charuco rebuilt from tests/data/charuco (the vision tests' copy).

    That copy stores grey crops around the board plus their origins and the
    robot poses in ``views.yaml``; here each crop is pasted back into a
    full-size 1600x1200 frame (median grey elsewhere) and ``poses/N.yaml`` are
    written, so `cal_data.yaml` and its intrinsics apply unchanged.
    """
    src = DATA / "charuco"
    out = tmp_path_factory.mktemp("test_set_charuco")
    (out / "images").mkdir()
    (out / "poses").mkdir()
    (out / "cal_data.yaml").write_text((src / "cal_data.yaml").read_text())
    for view in yaml.safe_load((src / "views.yaml").read_text())["views"]:
        crop = cv2.imread(str(src / view["image"]), cv2.IMREAD_GRAYSCALE)
        x0, y0 = view["crop_origin_px"]
        full = np.full((1200, 1600), int(np.median(crop)), dtype=np.uint8)
        full[y0:y0 + crop.shape[0], x0:x0 + crop.shape[1]] = crop
        cv2.imwrite(str(out / view["image"]), full)
        x, y, z = view["T_base_flange_xyz"]
        qx, qy, qz, qw = view["T_base_flange_quat_xyzw"]
        name = Path(view["image"]).stem
        (out / "poses" / f"{name}.yaml").write_text(yaml.safe_dump(dict(x=x, y=y, z=z, qx=qx, qy=qy, qz=qz, qw=qw)))
    return out
