"""`supportnet info` (issue 19, defects 7, 8, 10): images of different sizes, NaN poses, NaN and
decreasing time stamps are problems (exit 2); fx = 0 and an unknown camera are one line, no
traceback; `--camera` picks a KITTI camera or a bag's image topic."""

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from calib.data.io import format_row, write_image
from calib.data.kitti_odometry import write_kitti_odometry
from calib.data.rosbag import write_bag
from tests.conftest import make_frames

SUPPORTNET = Path(sys.executable).parent / "supportnet"


def run_cli(*args):
    env = dict(os.environ, COLUMNS="200")
    return subprocess.run(
        [str(SUPPORTNET), *map(str, args)], capture_output=True, text=True, env=env, timeout=120
    )


def assert_one_line_error(result, *expected):
    assert result.returncode == 2, (result.stdout, result.stderr)
    assert "Traceback" not in result.stderr and "Traceback" not in result.stdout
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("supportnet: error: "), result.stderr
    for text in expected:
        assert text in lines[0], (text, lines[0])
    return lines[0]


def test_images_of_different_sizes_are_a_problem_with_check_all(tmp_path):
    frames = make_frames(3)
    frames[2].image = frames[2].image[:150, :600].copy()
    frames[2].image_labels = None
    write_kitti_odometry(tmp_path, "00", frames)
    odd = tmp_path / "sequences" / "00" / "image_2" / "000002.png"
    assert run_cli("info", tmp_path).returncode == 0  # the first frame only: nothing to compare
    result = run_cli("info", tmp_path, "--check-all")
    assert "1 problem(s)" in result.stdout
    assert_one_line_error(result, str(odd), "image is 600x150 but frame 0's is 624x188")


def _write(tmp_path, poses=False):
    frames = make_frames(3)
    write_kitti_odometry(tmp_path, "00", frames, poses_lidar=np.tile(np.eye(4), (3, 1, 1)) if poses else None)
    return tmp_path / "sequences" / "00"


def test_nan_pose_is_a_problem(tmp_path):
    _write(tmp_path, poses=True)
    path = tmp_path / "poses" / "00.txt"
    rows = path.read_text().splitlines()
    rows[2] = format_row(np.array([1, 0, 0, np.nan, 0, 1, 0, 0, 0, 0, 1, 0])).strip()
    path.write_text("\n".join(rows) + "\n")
    result = run_cli("info", tmp_path, "--check-all")
    assert "1 problem(s)" in result.stdout and re.search(r"poses\s+none", result.stdout)
    assert_one_line_error(result, str(path), "1 pose(s) hold NaN or infinite values (first on line 3)")


@pytest.mark.parametrize(
    "stamps, expected",
    [
        ("0.0\nnan\n0.2\n", "1 time stamp(s) NaN or infinite (first at frame 1)"),
        ("0.0\n0.2\n0.1\n", "time stamps do not increase: frame 2 at 0.1 s follows 0.2 s"),
    ],
)
def test_bad_time_stamps_are_a_problem(tmp_path, stamps, expected):
    seq_dir = _write(tmp_path)
    (seq_dir / "times.txt").write_text(stamps)
    result = run_cli("info", tmp_path)
    assert "1 problem(s)" in result.stdout
    assert_one_line_error(result, str(seq_dir / "times.txt"), expected)


def test_fx_zero_is_one_line(tmp_path):
    seq_dir = _write(tmp_path)
    calib = (seq_dir / "calib.txt").read_text().splitlines()
    calib[2] = "P2: " + format_row(np.array([0, 0, 311.5, 0, 0, 360, 93.5, 0, 0, 0, 1, 0])).strip()
    (seq_dir / "calib.txt").write_text("\n".join(calib) + "\n")
    assert_one_line_error(
        run_cli("info", tmp_path), str(seq_dir / "calib.txt"), "'P2' has invalid intrinsics"
    )


def test_camera_choice_on_kitti_odometry(tmp_path):
    seq_dir = _write(tmp_path)
    assert_one_line_error(
        run_cli("info", tmp_path, "--camera", "3"), f"{seq_dir}: no camera 3", "available cameras: 2"
    )
    (seq_dir / "image_3").mkdir()
    for i, frame in enumerate(make_frames(3)):
        write_image(seq_dir / "image_3" / f"{i:06d}.png", frame.image[:, ::-1].copy())
    result = run_cli("info", tmp_path, "--camera", "3", "--check-all")
    assert result.returncode == 0, result.stderr
    assert re.search(r"camera\s+3\s*\n", result.stdout) and re.search(
        r"fingerprint\s+[0-9a-f]{16}", result.stdout
    )
    assert_one_line_error(run_cli("info", tmp_path, "--camera", "left"), "'left' is not a KITTI camera index")


def test_camera_and_sequence_on_a_bag(tmp_path):
    bag = write_bag(tmp_path / "rec", make_frames(3), second_image_topic="/right/image")
    assert_one_line_error(run_cli("info", bag), "found 2 image topics", "pick one with --camera")
    result = run_cli("info", bag, "--camera", "/right/image")
    assert result.returncode == 0, result.stderr
    assert "/right/image" in result.stdout
    assert_one_line_error(
        run_cli("info", bag, "--camera", "/right/image", "--sequence", "00"),
        "a ROS bag holds one sequence; leave out --sequence",
    )


def test_scene_and_camera_on_nuscenes(tmp_path):
    """A nuScenes root: ``--sequence`` picks a scene, ``--camera`` a channel; the camera's lead
    over the sweep is said; a missing scene or camera is one line."""
    from tests.calib.data.test_nuscenes import write_devkit

    root = write_devkit(tmp_path / "nus", scenes=("scene-0001", "scene-0002"))
    assert_one_line_error(run_cli("info", root), "holds 2 scenes", "pick one with --sequence")
    result = run_cli("info", root, "--sequence", "scene-0002", "--check-all")
    assert result.returncode == 0, result.stderr
    assert "layout: nuscenes" in result.stdout and re.search(r"camera\s+CAM_FRONT\s*\n", result.stdout)
    assert "CAM_FRONT exposes -30.0 ms from the sweep's stamp" in result.stdout
    assert_one_line_error(
        run_cli("info", root, "--sequence", "scene-0002", "--camera", "2"), "no camera '2'", "CAM_FRONT"
    )
