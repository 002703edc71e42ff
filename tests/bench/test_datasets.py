"""bench.datasets: the real sets are read from the upstream layout, missing ones left out."""

import gzip
from pathlib import Path

from bench.datasets import real_sets

DATA = Path(__file__).resolve().parents[1] / "data" / "ethz" / "robot_arm_sim"


def test_eth_streams_are_staged_with_a_manifest_and_loaded(tmp_path):
    root = tmp_path / "datasets"
    upstream = root / "ethz_hand_eye" / "robot_arm_w_color_camera_sim"
    upstream.mkdir(parents=True)
    for ours, theirs in [("robot_arm_sim_hand.csv.gz", "robot_arm_sim_hand.csv"),
                         ("robot_arm_sim_camera.csv.gz", "robot_arm_sim_camera.csv")]:
        (upstream / theirs).write_bytes(gzip.decompress((DATA / ours).read_bytes()))
    sets = dict(real_sets(tmp_path / "work", root))
    assert list(sets) == ["ETH robot_arm simulated"]
    imp = sets["ETH robot_arm simulated"]
    assert imp.setup == "eye_in_hand" and len(imp.A) > 100
    assert not any(upstream.glob("streams.toml")), "the upstream folder is read-only: stage, never write there"


def test_an_empty_datasets_folder_gives_no_sets(tmp_path):
    assert list(real_sets(tmp_path / "work", tmp_path)) == []
