"""Issue 19, defect 10 and 5 in the readers: ``camera`` picks one where a dataset has several (KITTI
image_N folders, a bag's image topics) and an unknown one is refused with the list; ``sequence`` is
refused where a layout holds one; the dataset fingerprint tells datasets apart, cheaply."""

import shutil

import numpy as np
import pytest

from calib.data import open_dataset
from calib.data.custom import write_custom
from calib.data.io import format_kv_line, write_bin, write_image
from calib.data.kitti_odometry import write_kitti_odometry
from calib.data.rosbag import write_bag
from calib.errors import DataError
from tests.calib.data.test_readers import _write_kitti_raw
from tests.conftest import KITTI_K, make_frames

BASELINE_M = 0.54


def _add_kitti_odometry_camera_3(tmp_path, frames):
    """image_3 holds the images mirrored; P3 sits BASELINE_M to the right of camera 2."""
    seq_dir = tmp_path / "sequences" / "00"
    text = (seq_dir / "calib.txt").read_text().splitlines()
    P3 = np.hstack([KITTI_K, np.array([[-KITTI_K[0, 0] * BASELINE_M], [0.0], [0.0]])])
    text[3] = format_kv_line("P3", P3).rstrip("\n")
    (seq_dir / "calib.txt").write_text("\n".join(text) + "\n")
    (seq_dir / "image_3").mkdir()
    for i, f in enumerate(frames):
        write_image(seq_dir / "image_3" / f"{i:06d}.png", f.image[:, ::-1].copy())
    return seq_dir


def test_kitti_odometry_camera_choice(tmp_path, frames):
    write_kitti_odometry(tmp_path, "00", frames)
    seq_dir = _add_kitti_odometry_camera_3(tmp_path, frames)
    left, right = open_dataset(tmp_path), open_dataset(tmp_path, camera="3")
    assert left.camera == "2" and right.camera == "3"
    np.testing.assert_array_equal(left[0].image, frames[0].image)
    np.testing.assert_array_equal(right[0].image, frames[0].image[:, ::-1])
    # camera 3 sits BASELINE_M to the right (+x) of camera 2: its T_cam_lidar is shifted by -x
    shift = right.calibration.T_cam_lidar @ np.linalg.inv(left.calibration.T_cam_lidar)
    np.testing.assert_allclose(shift[:3, 3], [-BASELINE_M, 0, 0], atol=1e-9)
    for spelling in (3, "03", "image_3"):
        assert open_dataset(tmp_path, camera=spelling).camera == "3"
    with pytest.raises(
        DataError, match=r"no camera 1 \(image_1 not found\); available cameras: 2, 3"
    ) as info:
        open_dataset(tmp_path, camera=1)
    assert str(info.value).startswith(str(seq_dir))
    with pytest.raises(DataError, match="--camera: 'left' is not a KITTI camera index"):
        open_dataset(tmp_path, camera="left")
    # no image_2: two cameras left, so the user must pick
    shutil.rmtree(seq_dir / "image_2")
    (seq_dir / "image_0").mkdir()
    with pytest.raises(DataError, match="has no image_2 but cameras 0, 3; pick one with --camera"):
        open_dataset(tmp_path)


def test_kitti_raw_camera_choice(tmp_path, frames):
    date, c = _write_kitti_raw(tmp_path, frames)
    drive = date / "2011_09_26_drive_0001_sync"
    with pytest.raises(DataError, match=r"no camera 3 \(image_03 not found\); available cameras: 2"):
        open_dataset(date, camera=3)
    shutil.copytree(drive / "image_02", drive / "image_03")
    cam = (date / "calib_cam_to_cam.txt").read_text()
    P3 = np.hstack([KITTI_K, np.array([[-KITTI_K[0, 0] * BASELINE_M], [0.0], [0.0]])])
    (date / "calib_cam_to_cam.txt").write_text(cam + format_kv_line("P_rect_03", P3))
    left, right = open_dataset(date), open_dataset(date, camera="image_03")
    assert (left.camera, right.camera) == ("02", "03") and left.notes == right.notes == []
    shift = right.calibration.T_cam_lidar @ np.linalg.inv(left.calibration.T_cam_lidar)
    expected = np.linalg.solve(KITTI_K, P3[:, 3]) - np.linalg.solve(KITTI_K, c["P"][:, 3])
    np.testing.assert_allclose(shift[:3, 3], expected, atol=1e-9)
    np.testing.assert_allclose(shift[:3, :3], np.eye(3), atol=1e-9)
    assert left.fingerprint() != right.fingerprint()


def test_kitti_raw_with_one_grey_camera(tmp_path, frames):
    """As the real AMZ fixture: only image_00; the default falls back to it (noted), camera 2
    is refused."""
    date, _ = _write_kitti_raw(tmp_path, frames, camera=0)
    seq = open_dataset(date)
    assert seq.camera == "00" and seq.notes == ["image_02 absent; using the only camera, image_00"]
    assert open_dataset(date, camera=0).notes == []
    with pytest.raises(DataError, match="available cameras: 0"):
        open_dataset(date, camera=2)


def test_bag_camera_is_an_image_topic(tmp_path, frames):
    bag = write_bag(tmp_path / "rec", frames, second_image_topic="/right/image")
    with pytest.raises(DataError, match=r"found 2 image topics \(/camera/image, /right/image\); pick one"):
        open_dataset(bag)
    with open_dataset(bag, camera="/right/image") as right, open_dataset(bag, camera="/camera/image") as left:
        assert right.camera == "/right/image" and left.camera == "/camera/image"
        np.testing.assert_array_equal(right[1].image, frames[1].image[:, ::-1])
        np.testing.assert_array_equal(left[1].image, frames[1].image)
        assert left.fingerprint() != right.fingerprint()
    with pytest.raises(
        DataError, match=r"no image topic '/rear/image' \(available: /camera/image, /right/image\)"
    ):
        open_dataset(bag, camera="/rear/image")


def test_sequence_is_refused_where_a_layout_holds_one(tmp_path, frames):
    bag = write_bag(tmp_path / "rec", frames)
    with pytest.raises(DataError, match="a ROS bag holds one sequence; leave out --sequence"):
        open_dataset(bag, sequence="00")
    custom = write_custom(tmp_path / "custom", frames)
    with pytest.raises(DataError, match="a custom folder holds one sequence"):
        open_dataset(custom, sequence="00")
    with pytest.raises(DataError, match="a custom folder has one camera"):
        open_dataset(custom, camera="2")
    write_kitti_odometry(tmp_path / "odo", "04", frames)
    with pytest.raises(DataError, match="is sequence 04, not '05'"):
        open_dataset(tmp_path / "odo" / "sequences" / "04", sequence="05")
    assert len(open_dataset(tmp_path / "odo" / "sequences" / "04", sequence="04")) == 3
    date, _ = _write_kitti_raw(tmp_path / "raw", frames)
    drive = date / "2011_09_26_drive_0001_sync"
    with pytest.raises(DataError, match="is drive 2011_09_26_drive_0001_sync, not '0002'"):
        open_dataset(drive, sequence="0002")
    assert len(open_dataset(drive, sequence="0001")) == 3


def test_kitti_object_refuses_a_sequence(tmp_path, frames):
    for sub in ("calib", "image_2", "velodyne"):
        (tmp_path / sub).mkdir()
    body = "".join(format_kv_line(f"P{k}", np.hstack([KITTI_K, np.zeros((3, 1))])) for k in range(4))
    body += format_kv_line("R0_rect", np.eye(3)) + format_kv_line(
        "Tr_velo_to_cam", frames[0].calibration.T_cam_lidar[:3]
    )
    (tmp_path / "calib" / "000000.txt").write_text(body)
    write_image(tmp_path / "image_2" / "000000.png", frames[0].image)
    write_bin(tmp_path / "velodyne" / "000000.bin", frames[0].points)
    assert open_dataset(tmp_path).camera == "2"
    with pytest.raises(DataError, match="a KITTI object split holds one sequence"):
        open_dataset(tmp_path, sequence="00")
    with pytest.raises(DataError, match="available cameras: 2"):
        open_dataset(tmp_path, camera=3)


# ---------------------------------------------------------------- fingerprints


def test_fingerprint_follows_the_content_not_the_location(tmp_path, frames):
    write_kitti_odometry(tmp_path / "a", "00", frames)
    shutil.copytree(tmp_path / "a", tmp_path / "moved")
    fingerprint = open_dataset(tmp_path / "a").fingerprint()
    assert len(fingerprint) == 16 and open_dataset(tmp_path / "moved").fingerprint() == fingerprint
    # another dataset with the same frame count, times and calibration: other files
    write_kitti_odometry(tmp_path / "b", "00", make_frames(3, seed=1))
    assert open_dataset(tmp_path / "b").fingerprint() != fingerprint
    # one scan shorter (same names, same times, same calibration): its size tells
    scan = tmp_path / "moved" / "sequences" / "00" / "velodyne" / "000001.bin"
    write_bin(scan, frames[1].points[:-1])
    assert open_dataset(tmp_path / "moved").fingerprint() != fingerprint


def test_bag_fingerprint(tmp_path, frames):
    one, two = write_bag(tmp_path / "one", frames), write_bag(tmp_path / "two", make_frames(3, seed=5))
    shutil.copytree(one, tmp_path / "copy")
    prints = []
    for bag in (one, tmp_path / "copy", two):
        with open_dataset(bag) as seq:
            prints.append(seq.fingerprint())
    assert prints[0] == prints[1] != prints[2]
    with open_dataset(one) as seq, open_dataset(write_bag(tmp_path / "short", frames[:2])) as short:
        assert seq.fingerprint() != short.fingerprint()
