"""`supportnet predict` (issue 19, defects 5 and 7): predictions carry the dataset's fingerprint;
`--maps` made from another dataset, or without a fingerprint, is refused before any work, in one
line naming both; a corrupt map file is one line, not a zipfile traceback."""

import json

import numpy as np
import pytest

from calib.data import open_dataset
from calib.data.kitti_odometry import write_kitti_odometry
from calib.errors import DataError
from supportnet.cli.cmd_predict import run_predict
from tests.calib.support.test_map_files import write_maps_folder
from tests.conftest import make_frames
from tests.supportnet.cli.test_cmd_info import assert_one_line_error, run_cli


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("predict")
    write_kitti_odometry(root / "a", "00", make_frames(3, seed=0))
    write_kitti_odometry(root / "b", "00", make_frames(3, seed=1))
    with open_dataset(root / "a") as a:
        maps = write_maps_folder(root / "maps_a", a)
    return root, maps


def test_predictions_carry_the_fingerprint_and_accept_their_maps(datasets, tmp_path):
    root, maps = datasets
    summary = run_predict(None, root / "a", None, tmp_path / "p", maps=maps)
    with open_dataset(root / "a") as a:
        assert summary["dataset_fingerprint"] == a.fingerprint()
    stored = json.loads((tmp_path / "p" / "summary.json").read_text())
    assert stored["dataset_fingerprint"] == summary["dataset_fingerprint"] and "sequence_map" in stored
    with pytest.raises(DataError, match="no camera 3"):
        run_predict(None, root / "a", None, tmp_path / "q", camera="3")


def test_maps_of_another_dataset_are_refused_before_any_work(datasets, tmp_path):
    root, maps = datasets
    result = run_cli("predict", "--data", root / "b", "--maps", maps, "--out", tmp_path / "p")
    line = assert_one_line_error(result, f"{maps}: was made from another dataset", "than b/00 (fingerprint")
    assert "a/00" in line  # both datasets named
    assert not (tmp_path / "p").exists()


def test_old_maps_without_a_fingerprint_are_refused(datasets, tmp_path):
    root, maps = datasets
    old = tmp_path / "old_maps"
    old.mkdir()
    for name in ("sequence.npz",):
        (old / name).write_bytes((maps / name).read_bytes())
    (old / "summary.json").write_text(json.dumps({"data": str(root / "a"), "frames": 3}))
    result = run_cli("predict", "--data", root / "a", "--maps", old, "--out", tmp_path / "p")
    assert_one_line_error(result, "carries no dataset fingerprint", "remake the maps with `supportnet maps`")


def test_a_corrupt_map_file_is_one_line(datasets, tmp_path):
    root, maps = datasets
    with open_dataset(root / "a") as a:
        broken = write_maps_folder(tmp_path / "broken", a)
    victim = broken / "frames" / "000001.npz"
    victim.write_bytes(victim.read_bytes()[:100])
    result = run_cli("predict", "--data", root / "a", "--maps", broken, "--out", tmp_path / "p")
    assert_one_line_error(result, str(victim), "is not a readable maps file")
    assert not (tmp_path / "p").exists()
    assert np.load(maps / "sequence.npz")["support"].shape == (188, 624)  # the good maps untouched
