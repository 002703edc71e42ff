"""Import formats register themselves: a new one is found by detection, loaded, and named in errors."""

import numpy as np
import pytest

from handeye.app.errors import SessionError
from handeye.app.formats import ImportedSamples, detect_format, import_formats, load, register_import
from handeye.calib.observation import Observation


def _is_toy(path, document) -> bool:
    return path.suffix == ".toyfmt"


@register_import("toy", _is_toy)
def load_toy(path) -> ImportedSamples:
    n = int(path.read_text())
    return ImportedSamples([Observation(i, float(i), np.eye(4), np.zeros(3)) for i in range(n)], "eye_to_hand",
                           {"format": "toy"})


def test_a_registered_format_is_detected_and_loaded(tmp_path):
    p = tmp_path / "three.toyfmt"
    p.write_text("3")
    assert detect_format(p) == "toy" and len(load(p).observations) == 3
    assert {"easy_handeye2", "easy_handeye", "industrial_calibration", "pose_csv", "toy"} <= set(import_formats())


def test_unknown_files_and_formats_name_the_known_ones(tmp_path):
    p = tmp_path / "x.txt"
    p.write_text("just: text\n")
    with pytest.raises(SessionError, match=r"not a known sample format; known: a handeye session \(a directory "
                                           r"with session.json\), or .*pose_csv"):
        detect_format(p)
    with pytest.raises(SessionError, match="unknown import format 'nope'"):
        load(p, "nope")


def test_the_formats_are_tried_in_the_listed_order_whatever_was_imported_first():
    # conftest imports every module, easy_handeye's before opencv_storage's: the order is still the list's, so
    # an OpenCV FileStorage file (%YAML:1.0, not YAML) reaches its detector before one that parses YAML.
    assert list(import_formats()) == ["opencv_storage", "pose_csv", "easy_handeye2", "easy_handeye",
                                      "industrial_calibration", "visp", "image_folder", "moveit_calibration",
                                      "ros2_bag", "toy"]
