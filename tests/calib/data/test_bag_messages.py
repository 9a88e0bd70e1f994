"""ROS messages as drivers write them (PointCloud2 layouts and time fields, camera_info models,
topics of several cameras, bags without TF) and scans in the formats PCL and ros_numpy write."""

from dataclasses import replace

import cv2
import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from calib.data import open_dataset
from calib.data.io import lzf_decompress, read_pcd, read_pcd_fields, read_scan
from calib.data.kitti_odometry import write_kitti_odometry
from calib.data.rosbag import decode_cloud, write_bag
from calib.errors import DataError
from tests.conftest import make_frames

STORE = get_typestore(Stores.ROS2_HUMBLE)
TYPES = STORE.types
STAMP = 1_700_000_000.25  # an epoch stamp, as a real driver writes it


def _cloud_message(
    columns: dict[str, tuple[int, np.ndarray]],
    height: int = 1,
    row_pad: int = 0,
    is_dense: bool = True,
    cut: int = 0,
):
    """A PointCloud2 of the named columns ``{name: (PointField datatype, values)}``, packed in
    order, each row padded by ``row_pad`` bytes, the data ``cut`` bytes short."""
    dtypes = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
    names = list(columns)
    offsets = np.cumsum([0] + [np.dtype(dtypes[columns[n][0]]).itemsize for n in names])
    step = int(offsets[-1])
    n = len(next(iter(columns.values()))[1])
    width = n // height
    packed = np.zeros(
        n,
        np.dtype(
            {
                "names": names,
                "formats": [dtypes[columns[k][0]] for k in names],
                "offsets": offsets[:-1].tolist(),
                "itemsize": step,
            }
        ),
    )
    for name in names:
        packed[name] = columns[name][1]
    rows = packed.tobytes()
    data = b"".join(rows[r * width * step : (r + 1) * width * step] + bytes(row_pad) for r in range(height))
    fields = [
        TYPES["sensor_msgs/msg/PointField"](name=k, offset=int(o), datatype=columns[k][0], count=1)
        for k, o in zip(names, offsets[:-1], strict=True)
    ]
    stamp = TYPES["builtin_interfaces/msg/Time"](sec=int(STAMP), nanosec=int(round(STAMP % 1 * 1e9)))
    return TYPES["sensor_msgs/msg/PointCloud2"](
        header=TYPES["std_msgs/msg/Header"](stamp=stamp, frame_id="lidar"),
        height=height,
        width=width,
        fields=fields,
        is_bigendian=False,
        point_step=step,
        row_step=width * step + row_pad,
        data=np.frombuffer(data[: len(data) - cut], np.uint8),
        is_dense=is_dense,
    )


XYZ = np.array([[1.0, 2.0, 3.0], [2.0, 2.0, 2.0], [4.0, -1.0, 0.5], [7.0, 0.0, -1.0]])


def _xyz(extra: dict | None = None) -> dict:
    return {"x": (7, XYZ[:, 0]), "y": (7, XYZ[:, 1]), "z": (7, XYZ[:, 2]), **(extra or {})}


def test_cloud_rows_padded_by_row_step_read_each_row():
    # two rows of two points, each row followed by 8 bytes of padding: the second row's points
    # must be read from row_step, not from width * point_step
    points, _ = decode_cloud(
        _cloud_message(_xyz({"intensity": (7, np.arange(4.0))}), height=2, row_pad=8), "m"
    )
    np.testing.assert_array_equal(points[:, :3], XYZ)
    np.testing.assert_array_equal(points[:, 3], [0, 1, 2, 3])


def test_cloud_too_short_or_point_step_too_small_is_one_line():
    with pytest.raises(DataError, match="holds 44 bytes for 1 x 4 points of 12 bytes"):
        decode_cloud(_cloud_message(_xyz(), cut=4), "m")
    with pytest.raises(DataError, match="point_step 8 is shorter than its fields"):
        decode_cloud(replace(_cloud_message(_xyz()), point_step=8), "m")


@pytest.mark.parametrize(
    ("field", "datatype", "values"),
    [
        ("t", 6, np.array([0, 25_000_000, 50_000_000, 99_000_000])),  # Ouster: uint32 ns
        ("time", 7, np.array([0.0, 0.025, 0.05, 0.099])),  # Velodyne: float s after the stamp
        ("timestamp", 8, STAMP + np.array([0.0, 0.025, 0.05, 0.099])),  # Hesai: absolute s
        ("timestamp", 8, (STAMP + np.array([0.0, 0.025, 0.05, 0.099])) * 1e9),  # Livox: absolute ns
    ],
)
def test_per_point_times_in_each_drivers_unit(field, datatype, values):
    _, times = decode_cloud(_cloud_message(_xyz({field: (datatype, values)})), "m")
    np.testing.assert_allclose(times, [0.0, 0.025, 0.05, 0.099], atol=2e-6)


def test_per_point_times_of_no_known_unit_are_left_out():
    # relative times in a field that should be absolute: in no unit one sweep about the stamp
    _, times = decode_cloud(_cloud_message(_xyz({"timestamp": (8, np.array([0.0, 0.03, 0.06, 0.09]))})), "m")
    assert times is None


def _pcd(tmp_path, header: str, body: bytes | str) -> object:
    path = tmp_path / "s.pcd"
    raw = header.encode() + (body.encode() if isinstance(body, str) else body)
    path.write_bytes(raw)
    return path


def test_pcd_binary_with_pcl_padding_fields(tmp_path):
    # PCL pads PointXYZI to 32 bytes with fields named "_"
    n = len(XYZ)
    dtype = np.dtype(
        [("x", "f4"), ("y", "f4"), ("z", "f4"), ("_a", "u1", (4,)), ("intensity", "f4"), ("_b", "u1", (12,))]
    )
    cloud = np.zeros(n, dtype)
    cloud["x"], cloud["y"], cloud["z"], cloud["intensity"] = *XYZ.T, np.arange(n) + 0.5
    header = (
        f"VERSION 0.7\nFIELDS x y z _ intensity _\nSIZE 4 4 4 1 4 1\nTYPE F F F U F U\n"
        f"COUNT 1 1 1 4 1 12\nWIDTH {n}\nHEIGHT 1\nPOINTS {n}\nDATA binary\n"
    )
    points = read_pcd(_pcd(tmp_path, header, cloud.tobytes()))
    np.testing.assert_array_equal(points[:, :3], XYZ)
    np.testing.assert_array_equal(points[:, 3], np.arange(n) + 0.5)


def test_pcd_ascii_field_of_several_values_spans_its_columns(tmp_path):
    header = (
        "VERSION 0.7\nFIELDS x y z normal intensity\nSIZE 4 4 4 4 4\nTYPE F F F F F\n"
        "COUNT 1 1 1 3 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n"
    )
    path = _pcd(tmp_path, header, "1 2 3 0 0 1 77\n4 5 6 1 0 0 88\n")
    np.testing.assert_array_equal(read_pcd(path), [[1, 2, 3, 77], [4, 5, 6, 88]])
    np.testing.assert_array_equal(read_pcd_fields(path)[0]["normal"], [[0, 0, 1], [1, 0, 0]])
    short = _pcd(tmp_path, header, "1 2 3 0 0 1\n4 5 6 1 0 0\n")
    with pytest.raises(DataError, match="6 columns for fields of 7 values"):
        read_pcd(short)


def test_lzf_data_cut_inside_a_back_reference_is_a_value_error():
    data = bytes([2]) + b"abc" + bytes([(7 << 5) | 0])  # a long back reference missing its bytes
    with pytest.raises(ValueError, match="end inside a back reference"):
        lzf_decompress(data, 20)
    with pytest.raises(ValueError, match="end inside a back reference"):
        lzf_decompress(bytes([2]) + b"abc" + bytes([(4 << 5) | 0]), 9)


def test_structured_npy_scan_read_by_field_names(tmp_path):
    cloud = np.zeros(len(XYZ), [("intensity", "f4"), ("x", "f4"), ("y", "f4"), ("z", "f4"), ("ring", "u2")])
    cloud["x"], cloud["y"], cloud["z"], cloud["intensity"] = *XYZ.T, 9.0
    np.save(tmp_path / "s.npy", cloud)
    np.testing.assert_array_equal(read_scan(tmp_path / "s.npy"), np.column_stack([XYZ, np.full(4, 9.0)]))
    np.save(tmp_path / "bad.npy", np.zeros(3, [("a", "f4"), ("b", "f4")]))
    with pytest.raises(DataError, match="without x, y, z fields"):
        read_scan(tmp_path / "bad.npy")


def test_bag_without_tf_static_opens_without_reference(tmp_path):
    frames = make_frames(2)
    for f in frames:
        f.calibration = replace(f.calibration, T_cam_lidar=None)
    write_bag(tmp_path / "rec", frames)
    with open_dataset(tmp_path / "rec") as seq:
        assert seq.calibration.T_cam_lidar is None
        assert any("no /tf_static chain" in n for n in seq.notes)
        np.testing.assert_array_equal(seq[1].points, frames[1].points)


def test_bag_of_two_compressed_cameras_finds_each_cameras_info_and_topics_by_key(tmp_path):
    frames = make_frames(2)
    write_bag(
        tmp_path / "rec",
        frames,
        compressed=True,
        image_topic="/cam_front/image_raw/compressed",
        info_topic="/cam_front/camera_info",
        second_image_topic="/cam_rear/image_raw/compressed",
        second_info_topic="/cam_rear/camera_info",
    )
    with open_dataset(tmp_path / "rec", camera="/cam_rear/image_raw/compressed") as seq:
        assert "camera_info /cam_rear/camera_info" in seq.notes[0]
    spec = (
        "image=/cam_front/image_raw/compressed,cloud=/lidar/points,info=/cam_front/camera_info,max_gap_ms=5"
    )
    with open_dataset(tmp_path / "rec", camera=spec) as seq:
        assert "camera_info /cam_front/camera_info" in seq.notes[0] and "within 5 ms" in seq.notes[0]
    for bad, message in (
        ("image=/cam_rear/image_raw/compressed,cloud=/nope", "no point cloud topic '/nope'"),
        ("cloud=/lidar/points", "found 2 image topics .*; pick one with --camera TOPIC"),
        ("lidar=/lidar/points", "unknown key 'lidar'"),
        ("image", "no image topic 'image' \\(available: /cam_front"),
        ("max_gap_ms=0", "give milliseconds"),
        ("image=/cam_front/image_raw/compressed,cloud", "is not KEY=VALUE"),
    ):
        with pytest.raises(DataError, match=message):
            open_dataset(tmp_path / "rec", camera=bad).close()


def test_fisheye_camera_info_undistorted_with_the_fisheye_model(tmp_path):
    frames = make_frames(1)
    D = np.array([0.1, -0.05, 0.01, 0.0])
    write_bag(tmp_path / "fish", frames, distortion=("equidistant", D))
    with open_dataset(tmp_path / "fish") as seq:
        assert seq.calibration.distortion is None  # not OpenCV's pinhole coefficients
        assert any("equidistant (fisheye) images undistorted" in n for n in seq.notes)
        got = seq[0].image
    K = frames[0].K
    np.testing.assert_array_equal(
        got, cv2.fisheye.undistortImage(frames[0].image, K, D.reshape(4, 1), Knew=K)
    )
    assert np.abs(got.astype(int) - frames[0].image).mean() > 5  # it did undistort
    write_bag(tmp_path / "mei", frames, distortion=("mei", np.r_[D, 0.0]))
    with pytest.raises(DataError, match="distortion model 'mei' is not one this reader undistorts"):
        open_dataset(tmp_path / "mei")


def test_kitti_odometry_stamps_written_to_the_nanosecond(tmp_path):
    frames = make_frames(2)
    for i, f in enumerate(frames):
        f.timestamp = 1317384506.123456789 + 0.1 * i
    write_kitti_odometry(tmp_path, "00", frames)
    with open_dataset(tmp_path, sequence="00") as seq:
        np.testing.assert_allclose(seq.timestamps, [f.timestamp for f in frames], atol=1e-6)


def test_kitti_raw_drive_with_frames_left_out_reads_stamps_by_number(tmp_path):
    from tests.calib.data.test_readers import _write_kitti_raw

    frames = make_frames(3)
    date, _ = _write_kitti_raw(tmp_path, frames)
    for path in date.rglob("0000000001.*"):  # frame 1's image and scan; timestamps.txt keeps 3 lines
        path.unlink()
    with open_dataset(date) as seq:
        np.testing.assert_allclose(np.diff(seq.timestamps), [0.2], atol=1e-6)  # epoch seconds
        assert any("2 of 3 frames present" in n for n in seq.notes)


def test_a_ros2_bag_whose_metadata_does_not_parse_is_one_line(tmp_path):
    write_bag(tmp_path / "rec", make_frames(1))
    (tmp_path / "rec" / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: [9\n  x: 1\n")
    with pytest.raises(DataError, match="not a readable ROS bag") as caught:
        open_dataset(tmp_path / "rec")
    assert "\n" not in str(caught.value)


def test_bag_stamps_before_zero_round_trip(tmp_path):
    """A camera offset below zero puts frame 0's exposure before t = 0: sec -1, nanosec 0.96e9."""
    frames = make_frames(2)
    for i, f in enumerate(frames):
        f.timestamp, f.lidar_timestamp = -0.04 + 0.1 * i, 0.1 * i
    write_bag(tmp_path / "rec", frames)
    with open_dataset(tmp_path / "rec") as seq:
        np.testing.assert_allclose(seq.timestamps, [-0.04, 0.06], atol=1e-9)
        assert seq[0].lidar_timestamp == pytest.approx(0.0, abs=1e-9)
