"""Data model and readers. :func:`open_dataset` detects the layout of a path and reads it."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from calib.data.custom import is_custom, read_custom
from calib.data.kitti_object import is_kitti_object, read_kitti_object
from calib.data.kitti_odometry import is_kitti_odometry, read_kitti_odometry
from calib.data.kitti_raw import is_kitti_raw, read_kitti_raw
from calib.data.nuscenes import is_nuscenes, read_nuscenes
from calib.data.rosbag import TOPIC_KEYS, BagSequence, BagTopics, is_bag
from calib.data.types import Calibration, Frame, Sequence, refuse_sequence
from calib.errors import DataError

__all__ = ["LAYOUTS", "Calibration", "Frame", "Sequence", "detect_layout", "open_dataset"]

LAYOUTS = ("rosbag", "kitti_odometry", "kitti_raw", "kitti_object", "nuscenes", "custom")
_DETECTORS = {
    "rosbag": is_bag,
    "kitti_odometry": is_kitti_odometry,
    "kitti_raw": is_kitti_raw,
    "kitti_object": is_kitti_object,
    "nuscenes": is_nuscenes,
    "custom": is_custom,
}
_EXPECTED = (
    "a KITTI odometry root (sequences/NN) or sequence folder, a KITTI raw drive or date folder, "
    "a KITTI object split (calib/, image_2/, velodyne/), a nuScenes root (v1.0-*/ tables, samples/), "
    "a custom folder (camera/, lidar/, calibration.yaml), or a ROS bag (.bag file or ROS 2 folder)"
)


def detect_layout(path: Path) -> str:
    """Name of the layout at ``path`` (one of :data:`LAYOUTS`)."""
    path = Path(path)
    if not path.exists():
        raise DataError(path, "no such file or folder")
    for name, detect in _DETECTORS.items():
        if detect(path):
            return name
    raise DataError(path, f"unknown data layout; expected {_EXPECTED}")


def bag_choice(path: Path, camera: str, topics: BagTopics, max_gap: float) -> tuple[BagTopics, float]:
    """A bag's ``--camera``: its image topic, or ``key=value`` pairs of
    :data:`~calib.data.rosbag.TOPIC_KEYS` and ``max_gap_ms`` (the largest camera–LiDAR stamp
    difference of a pair)."""
    if "=" not in camera:
        return replace(topics, image=camera), max_gap
    keys = ", ".join([*TOPIC_KEYS, "max_gap_ms"])
    for part in camera.split(","):
        key, sep, value = (s.strip() for s in part.partition("="))
        if not sep or not value:
            raise DataError(path, f"--camera {camera!r}: {part!r} is not KEY=VALUE ({keys})")
        if key == "max_gap_ms":
            try:
                max_gap = float(value) / 1000
            except ValueError:
                max_gap = -1.0
            if not 0 < max_gap <= 10:
                raise DataError(path, f"--camera max_gap_ms={value}: give milliseconds in (0, 10000]")
        elif key in TOPIC_KEYS:
            topics = replace(topics, **{TOPIC_KEYS[key]: value})
        else:
            raise DataError(path, f"--camera {camera!r}: unknown key {key!r} ({keys})")
    return topics, max_gap


def open_dataset(
    path: Path | str,
    sequence: str | None = None,
    camera: int | str | None = None,
    *,
    strict: bool = True,
    topics: BagTopics = BagTopics(),
    max_gap: float = 0.05,
) -> Sequence:
    """Open any supported layout as a :class:`Sequence`.

    Args:
        path: dataset folder or bag.
        sequence: which sequence (KITTI odometry), drive (KITTI raw) or scene (nuScenes: name or
            token) where the path holds several. Layouts holding one sequence (KITTI object,
            custom, a bag) refuse it.
        camera: which camera where the layout has several: a KITTI index (``2``, ``"2"``,
            ``"image_02"``), a bag's image topic (``"/cam_left/image_raw"``; or its topics as
            ``"image=/cam/image_raw,cloud=/os1/points,info=/cam/camera_info,max_gap_ms=20"``,
            any of them) or a nuScenes channel
            (``"CAM_BACK"``). ``None``: the layout's default (KITTI camera 2, or the only one
            present; a bag's only image topic; nuScenes' ``CAM_FRONT``). One that is not there
            is refused with a line listing those that are. The custom layout has one camera and
            refuses it.
        strict: raise on the first listed problem (unpaired files, empty or truncated scans,
            NaN or non-increasing time stamps, NaN poses); ``info`` passes ``False`` to report
            them all instead.
        topics, max_gap: ROS bag topic choice and pairing tolerance in seconds (``camera``
            overrides ``topics.image``).
    """
    path = Path(path)
    layout = detect_layout(path)
    if layout == "rosbag":
        refuse_sequence(path, sequence, "a ROS bag")
        if camera is not None:
            topics, max_gap = bag_choice(path, str(camera), topics, max_gap)
        seq: Sequence = BagSequence(path, topics=topics, max_gap=max_gap)
    elif layout == "kitti_odometry":
        seq = read_kitti_odometry(path, sequence, camera=camera)
    elif layout == "kitti_raw":
        seq = read_kitti_raw(path, sequence, camera=camera)
    elif layout == "nuscenes":
        seq = read_nuscenes(path, sequence, camera=camera)
    elif layout == "kitti_object":
        refuse_sequence(path, sequence, "a KITTI object split")
        seq = read_kitti_object(path, camera=camera)
    else:
        refuse_sequence(path, sequence, "a custom folder")
        if camera is not None:
            raise DataError(
                path, f"a custom folder has one camera (camera/); leave out --camera (got {camera!r})"
            )
        seq = read_custom(path)
    if strict and seq.problems:
        seq.close()
        path_part, _, problem = seq.problems[0].partition(": ")
        raise DataError(path_part, problem)
    if len(seq) == 0:
        seq.close()
        raise DataError(path, "holds no image–scan pairs")
    return seq
