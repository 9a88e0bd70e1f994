"""Issue 19, defects 7, 8 and 11 in the readers: intrinsics with fx = 0, images of different sizes,
NaN poses, NaN or decreasing time stamps, ragged calibration matrices, and the read-only arrays a
bag gave torch. Each ends in one line naming the file (or, for ``info``, in ``problems``)."""

import warnings

import numpy as np
import pytest
import torch
import yaml

from calib.data import open_dataset
from calib.data.custom import write_custom
from calib.data.io import format_kv_line, format_row, read_kv_file, write_image
from calib.data.kitti_odometry import write_kitti_odometry
from calib.data.rosbag import write_bag
from calib.errors import DataError
from calib.projection import project_scan
from tests.calib.data.test_readers import _write_kitti_raw
from tests.conftest import KITTI_K, make_frames


def _one_line(exc_info, path):
    message = str(exc_info.value)
    assert "\n" not in message and str(path) in message, message
    return message


# ---------------------------------------------------------------- fx = 0 (was a LinAlgError)


def _zero_fx(path, key):
    values = read_kv_file(path)
    lines = []
    for k, v in values.items():
        if isinstance(v, str):
            lines.append(f"{k}: {v}\n")
            continue
        if k == key:
            v = v.copy()
            v[0] = 0.0
        lines.append(format_kv_line(k, v))
    path.write_text("".join(lines))


def test_kitti_odometry_P2_with_fx_zero(tmp_path, frames):
    seq_dir = write_kitti_odometry(tmp_path, "00", frames)
    _zero_fx(seq_dir / "calib.txt", "P2")
    with pytest.raises(DataError, match="'P2' has invalid intrinsics: fx = 0") as info:
        open_dataset(tmp_path)
    _one_line(info, seq_dir / "calib.txt")


def test_kitti_raw_P_rect_with_fx_zero(tmp_path, frames):
    date, _ = _write_kitti_raw(tmp_path, frames)
    _zero_fx(date / "calib_cam_to_cam.txt", "P_rect_02")
    with pytest.raises(DataError, match="'P_rect_02' has invalid intrinsics: fx = 0") as info:
        open_dataset(date)
    _one_line(info, date / "calib_cam_to_cam.txt")


def test_kitti_object_P2_with_fx_zero(tmp_path, frames):
    for sub in ("calib", "image_2", "velodyne"):
        (tmp_path / sub).mkdir()
    P = np.hstack([KITTI_K, np.zeros((3, 1))])
    P[0, 0] = 0.0
    body = "".join(format_kv_line(f"P{k}", P) for k in range(4))
    body += format_kv_line("R0_rect", np.eye(3)) + format_kv_line("Tr_velo_to_cam", np.eye(4)[:3])
    (tmp_path / "calib" / "000000.txt").write_text(body)
    write_image(tmp_path / "image_2" / "000000.png", frames[0].image)
    frames[0].points.tofile(tmp_path / "velodyne" / "000000.bin")
    with pytest.raises(DataError, match="'P2' has invalid intrinsics") as info:
        open_dataset(tmp_path)
    _one_line(info, tmp_path / "calib" / "000000.txt")


def test_custom_calibration_with_fx_zero_and_ragged_K(tmp_path, frames):
    write_custom(tmp_path, frames)
    spec = yaml.safe_load((tmp_path / "calibration.yaml").read_text())
    spec["K"][0][0] = 0.0
    (tmp_path / "calibration.yaml").write_text(yaml.safe_dump(spec))
    with pytest.raises(DataError, match="need fx > 0 and fy > 0, got fx = 0, fy = 360") as info:
        open_dataset(tmp_path)
    _one_line(info, tmp_path / "calibration.yaml")
    spec["K"] = [[360.0, 0.0, 311.5], [0.0, 360.0], [0.0, 0.0, 1.0]]
    (tmp_path / "calibration.yaml").write_text(yaml.safe_dump(spec))
    with pytest.raises(DataError, match=r"K rows have different lengths \(3, 2, 3 numbers\)"):
        open_dataset(tmp_path)


def test_custom_extrinsic_that_is_a_reflection(tmp_path, frames):
    write_custom(tmp_path, frames)
    spec = yaml.safe_load((tmp_path / "calibration.yaml").read_text())
    spec["T_cam_lidar"][0] = [-v for v in spec["T_cam_lidar"][0][:3]] + [spec["T_cam_lidar"][0][3]]
    (tmp_path / "calibration.yaml").write_text(yaml.safe_dump(spec))
    with pytest.raises(DataError, match="T_cam_lidar is not a rigid 4x4 transform: rotation has det -1"):
        open_dataset(tmp_path)


# ---------------------------------------------------------------- images of different sizes


def _mixed_sizes():
    frames = make_frames(3)
    frames[2].image = frames[2].image[:150, :600].copy()
    frames[2].image_labels = frames[2].image_labels[:150, :600].copy()
    return frames


@pytest.mark.parametrize("layout", ["kitti_odometry", "custom", "bag"])
def test_images_of_different_sizes_are_refused_when_read(tmp_path, layout):
    frames = _mixed_sizes()
    if layout == "kitti_odometry":
        write_kitti_odometry(tmp_path, "00", frames)
        root, odd = tmp_path, tmp_path / "sequences" / "00" / "image_2" / "000002.png"
    elif layout == "custom":
        root = write_custom(tmp_path, frames)
        odd = tmp_path / "camera" / "000002.png"
    else:
        root = odd = write_bag(tmp_path / "rec", frames)
    with open_dataset(root) as seq:
        seq[0], seq[1]
        with pytest.raises(DataError, match="image is 600x150 but frame 0's is 624x188") as info:
            seq[2]
    _one_line(info, odd)


# ---------------------------------------------------------------- NaN poses and time stamps


def test_nan_pose_is_a_problem(tmp_path, frames):
    poses = np.tile(np.eye(4), (3, 1, 1))
    write_kitti_odometry(tmp_path, "00", frames, poses_lidar=poses)
    path = tmp_path / "poses" / "00.txt"
    rows = path.read_text().splitlines()
    rows[1] = rows[1].replace(rows[1].split()[3], "nan", 1)
    path.write_text("\n".join(rows) + "\n")
    seq = open_dataset(tmp_path, strict=False)
    assert seq.poses is None
    assert seq.problems == [f"{path}: 1 pose(s) hold NaN or infinite values (first on line 2)"]
    with pytest.raises(DataError, match="pose\\(s\\) hold NaN"):
        open_dataset(tmp_path)


def test_non_rigid_pose_is_a_problem(tmp_path, frames):
    poses = np.tile(np.eye(4), (3, 1, 1))
    write_kitti_odometry(tmp_path, "00", frames, poses_lidar=poses)
    path = tmp_path / "poses" / "00.txt"
    rows = path.read_text().splitlines()
    rows[2] = format_row(2 * np.eye(4)[:3]).strip()
    path.write_text("\n".join(rows) + "\n")
    seq = open_dataset(tmp_path, strict=False)
    assert "pose on line 3 is not a rigid transform" in seq.problems[0]


@pytest.mark.parametrize(
    "stamps, match",
    [
        ("0.0\nnan\n0.2\n", "1 time stamp\\(s\\) NaN or infinite \\(first at frame 1\\)"),
        ("0.0\n0.2\n0.1\n", "time stamps do not increase: frame 2 at 0.1 s follows 0.2 s"),
        ("0.0\n0.0\n0.1\n", "time stamps do not increase: frame 1 at 0 s follows 0 s"),
    ],
)
@pytest.mark.parametrize("layout", ["kitti_odometry", "custom"])
def test_bad_time_stamps_are_problems(tmp_path, frames, stamps, match, layout):
    if layout == "kitti_odometry":
        write_kitti_odometry(tmp_path, "00", frames)
        times = tmp_path / "sequences" / "00" / "times.txt"
    else:
        write_custom(tmp_path, frames)
        times = tmp_path / "timestamps.txt"
    times.write_text(stamps)
    seq = open_dataset(tmp_path, strict=False)
    assert len(seq.problems) == 1 and seq.problems[0].startswith(f"{times}: ")
    with pytest.raises(DataError, match=match) as info:
        open_dataset(tmp_path)
    _one_line(info, times)


def test_bad_lidar_stamps_and_kitti_raw_stamps(tmp_path, frames):
    write_kitti_odometry(tmp_path / "odo", "00", frames)
    (tmp_path / "odo" / "sequences" / "00" / "times_lidar.txt").write_text("0.0\ninf\n0.2\n")
    with pytest.raises(DataError, match="LiDAR time stamp\\(s\\) NaN or infinite"):
        open_dataset(tmp_path / "odo")
    date, _ = _write_kitti_raw(tmp_path / "raw", frames)
    stamps = date / "2011_09_26_drive_0001_sync" / "image_02" / "timestamps.txt"
    lines = stamps.read_text().splitlines()
    stamps.write_text("\n".join([lines[1], lines[0], lines[2]]) + "\n")
    with pytest.raises(DataError, match="time stamps do not increase: frame 1"):
        open_dataset(date)


# ---------------------------------------------------------------- bags and torch (defect 11)


def test_bag_frames_are_writable_and_torch_does_not_warn(tmp_path, frames):
    bag = write_bag(tmp_path / "rec", frames)
    with open_dataset(bag) as seq, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frame = seq[0]
        assert frame.image.flags.writeable and frame.K.flags.writeable
        torch.from_numpy(frame.image)
        torch.as_tensor(frame.K)
        project_scan(frame.points, frame.calibration.T_cam_lidar, frame.K, frame.image_size)
    assert [str(w.message) for w in caught] == []
