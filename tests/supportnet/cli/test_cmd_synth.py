"""``supportnet synth --out``: an existing dataset of another layout is refused before anything is
written into it; a new or empty folder and a KITTI odometry root (synth's own) still work."""

import os
import subprocess
import sys

import pytest

from calib.data import detect_layout
from calib.data.custom import write_custom
from calib.data.kitti_odometry import write_kitti_odometry
from calib.errors import DataError
from supportnet.cli.cmd_synth import run_synth
from tests.conftest import make_frames


def _kitti_raw(root):
    drive = root / "2011_09_26_drive_0001_sync"
    (drive / "velodyne_points" / "data").mkdir(parents=True)
    (root / "calib_velo_to_cam.txt").write_text("R: 1 0 0 0 1 0 0 0 1\nT: 0 0 0\n")
    return drive


def _nuscenes(root):
    (root / "v1.0-mini").mkdir(parents=True)
    (root / "v1.0-mini" / "sample_data.json").write_text("[]")
    (root / "samples").mkdir()
    return root


def _kitti_object(root):
    for name in ("calib", "velodyne", "image_2"):
        (root / "training" / name).mkdir(parents=True)
    return root


def _custom(root):
    write_custom(root, make_frames(1))
    return root


def _odometry_sequence(root):
    write_kitti_odometry(root, "00", make_frames(1))
    return root / "sequences" / "00"


def _bag(root):
    root.mkdir()
    (root / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    return root


@pytest.mark.parametrize(
    ("make", "layout", "words"),
    [
        (_kitti_raw, "kitti_raw", "a KITTI raw drive or date folder"),
        (lambda root: _kitti_raw(root).parent, "kitti_raw", "a KITTI raw drive or date folder"),
        (_nuscenes, "nuscenes", "a nuScenes root"),
        (_kitti_object, "kitti_object", "a KITTI object split"),
        (_custom, "custom", "a custom dataset folder"),
        (_odometry_sequence, "kitti_odometry", "a KITTI odometry sequence folder"),
        (_bag, "rosbag", "a ROS bag"),
    ],
)
@pytest.mark.parametrize("fmt", ["kitti", "bag"])
def test_synth_refuses_an_existing_dataset_of_another_layout(tmp_path, make, layout, words, fmt):
    out = make(tmp_path / "data")
    assert detect_layout(out) == layout
    before = sorted(os.listdir(out))
    with pytest.raises(DataError) as info:
        run_synth("urban", 1, 0, out, fmt=fmt, workers=1, small=True)
    assert str(info.value) == (
        f"{out}: --out is {words}; synth would write sequences/ and poses/ into that dataset: "
        "give a new or empty folder or a KITTI odometry root"
    )
    assert sorted(os.listdir(out)) == before  # nothing written


def test_synth_into_a_dataset_on_the_command_line_is_one_line_and_exit_2(tmp_path):
    """...while a new folder, an empty one, one of no known layout and synth's own root work."""
    drive = _kitti_raw(tmp_path / "raw")
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "supportnet",
            "synth",
            "--world",
            "urban",
            "--out",
            str(drive),
            "--frames",
            "1",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip() == (
        f"supportnet: error: {drive}: --out is a KITTI raw drive or date folder; synth would write "
        "sequences/ and poses/ into that dataset: give a new or empty folder or a KITTI odometry root"
    )
    assert sorted(os.listdir(drive)) == ["velodyne_points"]
    # the folders synth writes into still work
    first = run_synth("urban", 1, 0, tmp_path / "new", workers=1, small=True)
    assert (
        first == tmp_path / "new" / "sequences" / "00" and (tmp_path / "new" / "poses" / "00.txt").is_file()
    )
    second = run_synth("urban", 1, 1, tmp_path / "new", "01", workers=1, small=True)  # same root
    assert second.is_dir() and first.is_dir()
    (tmp_path / "empty").mkdir()
    assert run_synth("urban", 1, 0, tmp_path / "empty", workers=1, small=True).is_dir()
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "readme.txt").write_text("not a dataset")
    assert run_synth("urban", 1, 0, tmp_path / "notes", workers=1, small=True).is_dir()
