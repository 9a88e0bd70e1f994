"""Readers: round trips through each writable layout, the KITTI transform conventions as the
devkit states them, and bad input."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from calib.data import detect_layout, open_dataset
from calib.data.custom import write_custom
from calib.data.io import (
    format_kv_line,
    lzf_decompress,
    read_label,
    read_pcd,
    read_scan,
    write_bin,
    write_image,
    write_pcd,
)
from calib.data.kitti_odometry import write_kitti_odometry
from calib.data.rosbag import BagTopics, write_bag
from calib.data.types import paired_timestamps
from calib.errors import DataError
from calib.geometry import perturb
from tests.conftest import KITTI_K, kitti_like_extrinsic, make_frames


def _assert_same_frames(seq, frames, image_exact=True):
    assert len(seq) == len(frames)
    for got, want in zip(seq, frames, strict=True):
        np.testing.assert_array_equal(got.points, want.points)
        if image_exact:
            np.testing.assert_array_equal(got.image, want.image)
        assert got.timestamp == pytest.approx(want.timestamp, abs=1e-6)
    np.testing.assert_allclose(seq.calibration.K, frames[0].K, atol=1e-9)
    np.testing.assert_allclose(seq.calibration.T_cam_lidar, frames[0].calibration.T_cam_lidar, atol=1e-9)


def test_kitti_odometry_round_trip(tmp_path, frames):
    poses = np.stack([perturb(np.eye(4), 100.0 * i, 5.0 * i) for i in range(len(frames))])
    write_kitti_odometry(tmp_path, "07", frames, poses_lidar=poses)
    assert detect_layout(tmp_path) == "kitti_odometry"
    seq = open_dataset(tmp_path, "07")
    _assert_same_frames(seq, frames)
    np.testing.assert_allclose(seq.poses, poses, atol=1e-9)
    f = seq[1]
    np.testing.assert_array_equal(f.labels, frames[1].labels)
    np.testing.assert_array_equal(f.image_labels, frames[1].image_labels)
    assert seq.problems == [] and seq.notes == []
    # the sequence folder itself opens too, and a root with one sequence needs no --sequence
    assert len(open_dataset(tmp_path / "sequences" / "07")) == len(frames)
    assert len(open_dataset(tmp_path)) == len(frames)


def test_kitti_odometry_camera_offset_from_P2(tmp_path, frames):
    """P2 = K [I | t] of the rectified camera 0: camera 2 sits at -t/fx along x."""
    seq_dir = write_kitti_odometry(tmp_path, "00", frames)
    text = (seq_dir / "calib.txt").read_text().splitlines()
    fx = KITTI_K[0, 0]
    P2 = np.hstack([KITTI_K, np.array([[fx * 0.06], [0.0], [0.0]])])
    text[2] = format_kv_line("P2", P2).rstrip("\n")
    (seq_dir / "calib.txt").write_text("\n".join(text) + "\n")
    seq = open_dataset(tmp_path, "00")
    X = np.array([3.0, 1.0, 0.5, 1.0])
    Tr = frames[0].calibration.T_cam_lidar
    devkit = P2 @ Tr @ X
    ours = seq.calibration.K @ (seq.calibration.T_cam_lidar @ X)[:3]
    np.testing.assert_allclose(ours[:2] / ours[2], devkit[:2] / devkit[2], atol=1e-9)


def test_custom_round_trip_with_distortion_undistorts(tmp_path, frames):
    write_custom(tmp_path, frames)
    assert detect_layout(tmp_path) == "custom"
    _assert_same_frames(open_dataset(tmp_path), frames)
    import yaml

    spec = yaml.safe_load((tmp_path / "calibration.yaml").read_text())
    spec["distortion"] = [-0.2, 0.05, 0.0, 0.0, 0.0]
    (tmp_path / "calibration.yaml").write_text(yaml.safe_dump(spec))
    img = open_dataset(tmp_path)[0].image
    assert img.shape == frames[0].image.shape and not np.array_equal(img, frames[0].image)


@pytest.mark.parametrize("ros_version", [1, 2])
@pytest.mark.parametrize("compressed", [False, True])
def test_bag_round_trip(tmp_path, frames, ros_version, compressed):
    rows, cols = np.mgrid[0:188, 0:624]
    smooth = np.stack([rows, cols // 3, (rows + cols) // 4], axis=2).astype(np.uint8)
    for f in frames:  # LiDAR stamps 20 ms after the camera's, still within the gap
        f.lidar_timestamp = f.timestamp + 0.02
        if compressed:  # JPEG keeps smooth images, not noise
            f.image = smooth
    path = tmp_path / ("rec.bag" if ros_version == 1 else "rec")
    write_bag(path, frames, ros_version=ros_version, compressed=compressed)
    assert detect_layout(path) == "rosbag"
    with open_dataset(path) as seq:
        _assert_same_frames(seq, frames, image_exact=not compressed)
        assert seq[0].lidar_timestamp == pytest.approx(frames[0].timestamp + 0.02)
        if compressed:  # JPEG: close, not equal
            assert np.abs(seq[0].image.astype(int) - frames[0].image).mean() < 2
    with pytest.raises(DataError, match="no image–scan pair within 10 ms"):
        open_dataset(path, max_gap=0.01)
    with pytest.raises(DataError, match="no image topic '/nope'"):
        open_dataset(path, topics=BagTopics(image="/nope"))


def _write_kitti_raw(root: Path, frames, camera=2, timestamps=True) -> tuple[Path, dict]:
    """A KITTI raw date folder with one drive, calibration values not the identity."""
    date = root / "2011_09_26"
    drive = date / "2011_09_26_drive_0001_sync"
    R_rect = perturb(np.eye(4), 0.0, 0.8)[:3, :3]
    T_velo = kitti_like_extrinsic()
    P = np.hstack([KITTI_K, np.array([[44.857], [0.216], [0.0027]])])
    lines = {
        "R_rect_00": R_rect,
        f"P_rect_0{camera}": P,
        f"S_rect_0{camera}": np.array([624.0, 188.0]),
    }
    date.mkdir(parents=True)
    (date / "calib_cam_to_cam.txt").write_text(
        "calib_time: 09-Jan-2012 13:57:47\n" + "".join(format_kv_line(k, m) for k, m in lines.items())
    )
    (date / "calib_velo_to_cam.txt").write_text(
        "calib_time: 15-Mar-2012 11:37:16\n"
        + format_kv_line("R", T_velo[:3, :3])
        + format_kv_line("T", T_velo[:3, 3])
    )
    img_dir, scan_dir = drive / f"image_0{camera}" / "data", drive / "velodyne_points" / "data"
    img_dir.mkdir(parents=True)
    scan_dir.mkdir(parents=True)
    for i, f in enumerate(frames):
        write_image(img_dir / f"{i:010d}.png", f.image)
        write_bin(scan_dir / f"{i:010d}.bin", f.points)
    if timestamps:
        (img_dir.parent / "timestamps.txt").write_text(
            "".join(f"2011-09-26 13:02:25.{100000000 * (i + 1):09d}\n" for i in range(len(frames)))
        )
    return date, {"P": P, "R_rect": R_rect, "T_velo": T_velo}


def _devkit_pixels(P, R_rect, Tr, X):
    R4 = np.eye(4)
    R4[:3, :3] = R_rect
    x = P @ R4 @ Tr @ X
    return x[:2] / x[2]


def test_kitti_raw_transform_matches_devkit_formula(tmp_path, frames):
    date, c = _write_kitti_raw(tmp_path, frames)
    assert detect_layout(date) == "kitti_raw"
    seq = open_dataset(date)
    X = np.array([8.0, -1.0, 0.3, 1.0])
    x = seq.calibration.K @ (seq.calibration.T_cam_lidar @ X)[:3]
    np.testing.assert_allclose(x[:2] / x[2], _devkit_pixels(c["P"], c["R_rect"], c["T_velo"], X), atol=1e-9)
    assert seq.calibration.image_size == (188, 624)
    np.testing.assert_allclose(np.diff(seq.timestamps), 0.1, atol=1e-6)
    np.testing.assert_array_equal(seq[2].points, frames[2].points)


def test_kitti_raw_without_timestamps_assumes_10hz(tmp_path, frames):
    date, _ = _write_kitti_raw(tmp_path, frames, timestamps=False)
    seq = open_dataset(date)
    assert any("10 Hz assumed" in n for n in seq.notes)
    np.testing.assert_allclose(seq.timestamps, [0.0, 0.1, 0.2])
    # from the file numbers: frames 0 and 2 of a drive, without 1, are 0.2 s apart
    for path in date.rglob("0000000001.*"):  # its image and its scan
        path.unlink()
    np.testing.assert_allclose(open_dataset(date).timestamps, [0.0, 0.2])


def test_stamps_assumed_from_order_where_names_are_not_numbers(tmp_path):
    notes = []
    images = [tmp_path / "b.png", tmp_path / "a7.png"]
    np.testing.assert_allclose(paired_timestamps(tmp_path / "none.txt", images, images, notes), [0.0, 0.1])
    assert notes == [f"{tmp_path / 'none.txt'}: no time stamps; 10 Hz assumed"]


def test_kitti_object_transform_matches_devkit_formula(tmp_path, frames):
    root = tmp_path / "training"
    for sub in ("calib", "image_2", "velodyne"):
        (root / sub).mkdir(parents=True)
    P2 = np.hstack([KITTI_K, np.array([[44.857], [0.216], [0.0027]])])
    R0 = perturb(np.eye(4), 0.0, 0.5)[:3, :3]
    Tr = kitti_like_extrinsic()
    for i, f in enumerate(frames):
        body = "".join(format_kv_line(f"P{k}", P2) for k in range(4))
        body += format_kv_line("R0_rect", R0) + format_kv_line("Tr_velo_to_cam", Tr[:3])
        (root / "calib" / f"{i:06d}.txt").write_text(body)
        write_image(root / "image_2" / f"{i:06d}.png", f.image)
        write_bin(root / "velodyne" / f"{i:06d}.bin", f.points)
    assert detect_layout(tmp_path) == "kitti_object"
    seq = open_dataset(tmp_path)
    X = np.array([8.0, -1.0, 0.3, 1.0])
    x = seq.calibration.K @ (seq.calibration.T_cam_lidar @ X)[:3]
    np.testing.assert_allclose(x[:2] / x[2], _devkit_pixels(P2, R0, Tr, X), atol=1e-9)
    assert len(seq) == 3


def test_pcd_binary_and_ascii_round_trip(tmp_path, frames):
    pts = frames[0].points
    write_pcd(tmp_path / "a.pcd", pts)
    np.testing.assert_array_equal(read_scan(tmp_path / "a.pcd"), pts)
    header = (
        "VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
        f"WIDTH {len(pts)}\nHEIGHT 1\nPOINTS {len(pts)}\nDATA ascii\n"
    )
    body = "".join(" ".join(f"{v:.9g}" for v in row) + "\n" for row in pts)
    (tmp_path / "b.pcd").write_text(header + body)
    np.testing.assert_allclose(read_pcd(tmp_path / "b.pcd"), pts, rtol=1e-6)


def test_lzf_known_answer():
    # literal "abc" (ctrl 2), then a back reference of length 6 at distance 3 (overlapping copy)
    data = bytes([2]) + b"abc" + bytes([(4 << 5) | 0, 2])
    assert lzf_decompress(data, 9) == b"abcabcabc"
    with pytest.raises(ValueError, match="header says"):
        lzf_decompress(data, 10)


def test_semantickitti_label_reading(tmp_path):
    raw = np.array([10 | (7 << 16), 40, 70 | (1 << 16)], dtype=np.uint32)
    raw.tofile(tmp_path / "x.label")
    np.testing.assert_array_equal(read_label(tmp_path / "x.label", 3), [10, 40, 70])
    with pytest.raises(DataError, match="3 labels for a scan of 4 points"):
        read_label(tmp_path / "x.label", 4)


# ---------------------------------------------------------------- bad input, every reader


def _kitti_odometry(tmp, frames):
    write_kitti_odometry(tmp, "00", frames)
    d = tmp / "sequences" / "00"
    return tmp, d / "velodyne", d / "image_2", d / "calib.txt"


def _custom(tmp, frames):
    write_custom(tmp, frames)
    return tmp, tmp / "lidar", tmp / "camera", tmp / "calibration.yaml"


def _kitti_raw(tmp, frames):
    date, _ = _write_kitti_raw(tmp, frames)
    drive = date / "2011_09_26_drive_0001_sync"
    return (
        date,
        drive / "velodyne_points" / "data",
        drive / "image_02" / "data",
        date / "calib_velo_to_cam.txt",
    )


def _bag(tmp, frames):
    return write_bag(tmp / "rec", frames), None, None, None


WRITERS = {"kitti_odometry": _kitti_odometry, "custom": _custom, "kitti_raw": _kitti_raw}


def _first(folder):
    return sorted(folder.iterdir())[0]


@pytest.fixture(params=list(WRITERS))
def layout(request, tmp_path, frames):
    return WRITERS[request.param](tmp_path, frames)


def _expect_error(root, match, path):
    with pytest.raises(DataError, match=match) as info:
        for _ in open_dataset(root):  # reading every frame surfaces per-file errors
            pass
    assert str(path) in str(info.value), f"message must name {path}: {info.value}"
    assert "\n" not in str(info.value)


def test_missing_scan_file_is_reported(layout):
    root, scans, _, _ = layout
    victim = _first(scans)
    victim.unlink()
    _expect_error(root, "images but", scans)


def test_empty_scan(layout):
    root, scans, _, _ = layout
    victim = _first(scans)
    victim.write_bytes(b"")
    _expect_error(root, "empty scan", victim)


def test_truncated_bin(layout):
    root, scans, _, _ = layout
    victim = _first(scans)
    victim.write_bytes(victim.read_bytes()[:-6])
    _expect_error(root, "truncated", victim)


def test_nan_points(layout):
    root, scans, _, _ = layout
    victim = _first(scans)
    pts = np.fromfile(victim, np.float32).reshape(-1, 4)
    pts[5, 1] = np.nan
    pts.tofile(victim)
    _expect_error(root, "1 of 500 points are NaN", victim)


def test_corrupt_png(layout):
    root, _, images, _ = layout
    victim = _first(images)
    victim.write_bytes(victim.read_bytes()[:200])
    _expect_error(root, "corrupt", victim)


def test_calibration_that_does_not_parse(layout):
    root, _, _, calib = layout
    calib.write_text("this is: not [ a calibration\n::\n")
    _expect_error(root, "is not 'key: values'|not valid YAML|not permitted", calib)


def test_custom_calibration_typo_fails_loudly(tmp_path, frames):
    write_custom(tmp_path, frames)
    text = (tmp_path / "calibration.yaml").read_text().replace("T_cam_lidar", "T_cam_lidr")
    (tmp_path / "calibration.yaml").write_text(text)
    with pytest.raises(DataError, match="T_cam_lidr: Extra inputs are not permitted"):
        open_dataset(tmp_path)


def test_bag_bad_input(tmp_path, frames):
    bag = write_bag(tmp_path / "rec", frames)
    with pytest.raises(DataError, match="not a readable ROS bag"):
        (bag / (bag.name + ".db3")).write_bytes(b"garbage")
        open_dataset(bag)


def test_unknown_layout_and_missing_folder(tmp_path):
    with pytest.raises(DataError, match="no such file or folder"):
        open_dataset(tmp_path / "nope")
    with pytest.raises(DataError, match="unknown data layout"):
        open_dataset(tmp_path)


def test_info_mode_collects_problems_instead_of_raising(tmp_path, frames):
    root, scans, _, _ = _kitti_odometry(tmp_path, frames)
    _first(scans).write_bytes(b"")
    seq = open_dataset(root, strict=False)
    assert any("empty scan file" in p for p in seq.problems)
    shutil.rmtree(scans)
    with pytest.raises(DataError, match="folder not found"):
        open_dataset(root, strict=False)


def test_kitti_odometry_reads_separate_lidar_stamps(tmp_path):
    frames = make_frames(3)
    for i, f in enumerate(frames):
        f.lidar_timestamp = f.timestamp - 0.02 + 0.001 * i
    write_kitti_odometry(tmp_path, "00", frames)
    with open_dataset(tmp_path, sequence="00") as seq:
        assert [seq[i].lidar_timestamp for i in range(3)] == pytest.approx(
            [f.lidar_timestamp for f in frames]
        )
    (tmp_path / "sequences" / "00" / "times_lidar.txt").write_text("1.0\n")
    with pytest.raises(DataError, match="holds 1 stamps for 3 frames"):
        open_dataset(tmp_path, sequence="00")
