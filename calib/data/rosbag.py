"""ROS 1 (``.bag``) and ROS 2 (folder with ``metadata.yaml``) recordings, read with ``rosbags``.

Topics are given by option or found by message type (``sensor_msgs/Image`` or
``CompressedImage``, ``PointCloud2``, ``CameraInfo``; an ambiguous choice is an error that lists
the candidates). Each camera image is paired with the scan of nearest header time stamp; pairs
farther apart than ``max_gap`` seconds are dropped, and each scan is used at most once.

Intrinsics come from ``camera_info``: ``K`` and the distortion ``D`` (``plumb_bob``,
``rational_polynomial`` or ``equidistant``; images undistorted on load keeping ``K``), except for a
``*rect*`` image topic, whose ``P[:3, :3]`` is used as is.

Per-point times: Ouster's ``t`` (ns after the scan's start), Velodyne's ``time`` (s after the
stamp), or an absolute ``timestamp`` in s or ns (Hesai, RoboSense, Livox); times that fit one
sweep about the stamp in no unit are left out, with a note.

Transform: ROS TF messages hold ``T_parent_child`` (a child-frame point mapped into the parent).
``/tf_static`` is searched for a chain between the cloud's and the image's ``frame_id``;
``T_cam_lidar = T_root_cam⁻¹ · T_root_lidar``. The image ``frame_id`` must be the optical frame
(z forward, x right). Without such a chain the reference extrinsic is ``None`` unless given.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from scipy.spatial.transform import Rotation

from calib.data.io import validate_points
from calib.data.types import SAMPLE_BYTES, Calibration, Frame, Sequence, time_problems
from calib.errors import DataError

__all__ = ["BagSequence", "BagTopics", "is_bag", "write_bag"]

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
TF_TYPE = "tf2_msgs/msg/TFMessage"
# camera_info distortion models: OpenCV's cv2.undistort takes the first two, cv2.fisheye the others
PINHOLE_MODELS = ("plumb_bob", "rational_polynomial")
FISHEYE_MODELS = ("equidistant", "fisheye")
_POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def is_bag(path: Path) -> bool:
    return (path.is_file() and path.suffix == ".bag") or (path / "metadata.yaml").is_file()


@dataclass(frozen=True)
class BagTopics:
    """Topic names; ``None`` means find the topic by its message type."""

    image: str | None = None
    cloud: str | None = None
    camera_info: str | None = None


TOPIC_KEYS = {"image": "image", "cloud": "cloud", "info": "camera_info"}
"""``--camera KEY=TOPIC`` keys and the :class:`BagTopics` field each sets."""


def _stamp(msg: object) -> float:
    stamp = msg.header.stamp  # type: ignore[attr-defined]
    return stamp.sec + stamp.nanosec * 1e-9


def _field(msg: object, name: str) -> object:
    """ROS 1 spells CameraInfo's arrays in capitals (``K``), ROS 2 in lower case (``k``)."""
    return getattr(msg, name.lower(), None) if hasattr(msg, name.lower()) else getattr(msg, name)


def decode_image(msg: object, msgtype: str, where: str) -> np.ndarray:
    """``sensor_msgs/Image`` or ``CompressedImage`` -> ``(H, W, 3)`` uint8 RGB."""
    if msgtype.endswith("CompressedImage"):
        image = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_COLOR)  # type: ignore[attr-defined]
        if image is None:
            raise DataError(where, "compressed image does not decode")
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    enc = msg.encoding.lower()  # type: ignore[attr-defined]
    h, w, step = msg.height, msg.width, msg.step  # type: ignore[attr-defined]
    depth = {"mono16": 2, "16uc1": 2}.get(enc, 1)
    channels = {
        "rgb8": 3,
        "bgr8": 3,
        "rgba8": 4,
        "bgra8": 4,
        "mono8": 1,
        "8uc1": 1,
        "mono16": 1,
        "16uc1": 1,
    }.get(enc)
    if channels is None:
        raise DataError(where, f"unsupported image encoding {enc!r}")
    raw = np.asarray(msg.data, dtype=np.uint8).reshape(h, step)[:, : w * channels * depth]  # type: ignore[attr-defined]
    image = raw.view(np.uint16 if depth == 2 else np.uint8).reshape(h, w, channels)
    if depth == 2:
        image = (image >> 8).astype(np.uint8)
    if channels == 1:
        return np.repeat(image, 3, axis=2)
    if enc.startswith("bgr"):
        image = image[:, :, 2::-1]
    # a copy: the message's buffer is read only (torch warns on such arrays) and shared
    return np.array(image[:, :, :3], order="C")


def decode_cloud(msg: object, where: str) -> tuple[np.ndarray, np.ndarray | None]:
    """``PointCloud2`` -> ``(N, 4)`` float32 points and per-point times in seconds after the
    header stamp (or ``None``; see :func:`point_times`).

    NaN rows of a cloud with ``is_dense = false`` are no-returns and are dropped. Rows may be
    padded (``row_step`` beyond ``width · point_step``); a field of ``count`` > 1 is read by its
    first value.
    """
    fields = {f.name: f for f in msg.fields}  # type: ignore[attr-defined]
    if not {"x", "y", "z"} <= set(fields):
        raise DataError(where, f"PointCloud2 has no x, y, z fields (has {', '.join(fields)})")
    order = ">" if msg.is_bigendian else "<"  # type: ignore[attr-defined]
    names = [n for n in fields if fields[n].datatype in _POINTFIELD_DTYPES]
    height, width = int(msg.height), int(msg.width)  # type: ignore[attr-defined]
    step, row_step = int(msg.point_step), int(msg.row_step)  # type: ignore[attr-defined]
    end = max(fields[n].offset + np.dtype(_POINTFIELD_DTYPES[fields[n].datatype]).itemsize for n in names)
    if step < end:
        raise DataError(where, f"PointCloud2 point_step {step} is shorter than its fields ({end} bytes)")
    row_step = row_step or width * step  # some writers leave it 0
    data = np.asarray(msg.data, dtype=np.uint8)  # type: ignore[attr-defined]
    if row_step < width * step or data.size < (height - 1) * row_step + width * step:
        raise DataError(
            where,
            f"PointCloud2 holds {data.size} bytes for {height} x {width} points of {step} bytes "
            f"(row_step {row_step})",
        )
    dtype = np.dtype(
        {
            "names": names,
            "formats": [order + _POINTFIELD_DTYPES[fields[n].datatype] for n in names],
            "offsets": [fields[n].offset for n in names],
            "itemsize": step,
        }
    )
    rows = [data[r * row_step : r * row_step + width * step] for r in range(height)]
    cloud = np.frombuffer(np.concatenate(rows).tobytes(), dtype=dtype)
    n = len(cloud)
    intensity = next((f for f in ("intensity", "reflectivity", "i") if f in names), None)
    columns = [cloud["x"], cloud["y"], cloud["z"], cloud[intensity] if intensity else np.zeros(n)]
    points = np.stack([c.astype(np.float64) for c in columns], axis=1)
    times = point_times(cloud, names, _stamp(msg))
    dense = bool(msg.is_dense)  # type: ignore[attr-defined]
    finite = np.isfinite(points).all(axis=1)
    if times is not None and not dense:
        times = times[finite]
    return validate_points(points, Path(where), drop_nonfinite=not dense), times


# Time fields drivers write, as the seconds one unit is: Ouster ``t`` (uint32 ns after the scan's
# start), Velodyne ``time`` (float s after the stamp); ``timestamp`` is absolute, in seconds
# (Hesai, RoboSense) or nanoseconds (Livox's PointXYZRTLT), told apart by its size.
_RELATIVE_TIMES = {"t": 1e-9, "time": 1.0}
TIME_FIELDS = (*_RELATIVE_TIMES, "timestamp")
_ABSOLUTE_SCALES = (1.0, 1e-3, 1e-6, 1e-9)  # s, ms, µs, ns
SWEEP_LIMIT_S = 1.0  # per-point times farther from the stamp are not one sweep's


def point_times(cloud: np.ndarray, names: list[str], stamp_s: float) -> np.ndarray | None:
    """Per-point times of a structured cloud, in seconds after the stamp ``stamp_s``, or ``None``
    where it has no time field or its times do not fit one sweep about the stamp (an unknown
    unit: better no times than wrong ones, which would deskew the scan by metres)."""
    for name, scale in _RELATIVE_TIMES.items():
        if name in names:
            times = cloud[name].astype(np.float64) * scale
            break
    else:
        if "timestamp" not in names:
            return None
        raw = cloud["timestamp"].astype(np.float64)
        middle = float(np.median(raw)) if len(raw) else 0.0
        # the unit that puts the sweep's middle nearest the stamp
        scale = min(_ABSOLUTE_SCALES, key=lambda s: abs(middle * s - stamp_s))
        times = raw * scale - stamp_s
    finite = times[np.isfinite(times)]
    if finite.size and np.abs(finite).max() > SWEEP_LIMIT_S:
        return None
    return times


def _tf_tree(reader: AnyReader) -> dict[str, tuple[str, np.ndarray]]:
    """``child -> (parent, T_parent_child)`` from every ``/tf_static`` message."""
    tree: dict[str, tuple[str, np.ndarray]] = {}
    connections = [c for c in reader.connections if c.msgtype == TF_TYPE and c.topic == "/tf_static"]
    if not connections:  # rosbags reads an empty list as every connection
        return tree
    for connection, _, raw in reader.messages(connections=connections):
        for tf in reader.deserialize(raw, connection.msgtype).transforms:
            q, t = tf.transform.rotation, tf.transform.translation
            T = np.eye(4)
            T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
            T[:3, 3] = (t.x, t.y, t.z)
            tree[tf.child_frame_id.lstrip("/")] = (tf.header.frame_id.lstrip("/"), T)
    return tree


def _chain(tree: dict[str, tuple[str, np.ndarray]], frame: str) -> dict[str, np.ndarray]:
    """``ancestor -> T_ancestor_frame`` for every ancestor of ``frame`` (itself included)."""
    chain, T = {frame: np.eye(4)}, np.eye(4)
    while frame in tree and len(chain) <= len(tree):
        frame, T_parent_child = tree[frame]
        T = T_parent_child @ T
        chain[frame] = T
    return chain


def lookup_T_cam_lidar(tree: dict, camera_frame: str, lidar_frame: str) -> np.ndarray | None:
    cam, lidar = _chain(tree, camera_frame), _chain(tree, lidar_frame)
    common = next((f for f in cam if f in lidar), None)
    return None if common is None else np.linalg.inv(cam[common]) @ lidar[common]


class BagSequence(Sequence):
    """Image–scan pairs of a ROS 1 or ROS 2 recording (see the module docstring).

    Args:
        path: a ``.bag`` file or a ROS 2 bag folder.
        topics: topic names, or ``None`` fields to find them by message type.
        max_gap: largest camera–LiDAR stamp difference of a pair, seconds.
        T_cam_lidar: reference extrinsic overriding ``/tf_static``.
    """

    layout = "rosbag"

    def __init__(
        self,
        path: Path,
        topics: BagTopics = BagTopics(),
        max_gap: float = 0.05,
        T_cam_lidar: np.ndarray | None = None,
    ):
        self.path = Path(path)
        self.name = self.path.stem
        self.notes, self.problems = [], []
        self.reader = None
        try:
            self.reader = AnyReader([self.path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            self.reader.open()
        except Exception as exc:  # rosbags raises several unrelated types for unreadable bags
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]  # YAML errors span lines
            raise DataError(self.path, f"not a readable ROS bag ({first})") from None
        try:
            self._index(topics, max_gap, T_cam_lidar)
        except BaseException:
            self.close()  # a refused bag leaves no open handle behind
            raise

    def _index(self, topics: BagTopics, max_gap: float, T_cam_lidar: np.ndarray | None) -> None:
        """Pick the topics, pair the stamps, read the calibration."""
        self._image = self._pick(topics.image, IMAGE_TYPES, "image", "image")
        self._cloud = self._pick(topics.cloud, (CLOUD_TYPE,), "point cloud", "cloud")
        info_conn = self._pick(
            topics.camera_info, (INFO_TYPE,), "camera_info", "info", near=self._image.topic
        )
        info = self._first(info_conn)
        self.camera = self._image.topic
        image_stamps = self._stamps(self._image)
        cloud_stamps = self._stamps(self._cloud)
        self._counts = {self._image.topic: len(image_stamps), self._cloud.topic: len(cloud_stamps)}
        self._pairs = self._pair(image_stamps, cloud_stamps, max_gap)
        if not self._pairs:
            raise DataError(self.path, f"no image–scan pair within {max_gap * 1000:g} ms")
        self.notes.append(
            f"topics: image {self._image.topic}, cloud {self._cloud.topic}, camera_info "
            f"{info_conn.topic}; {len(self._pairs)} pairs of {len(image_stamps)} images within "
            f"{max_gap * 1000:g} ms"
        )
        self.timestamps = np.array([image_stamps[i][0] for i, _ in self._pairs])
        self._lidar_times = np.array([cloud_stamps[j][0] for _, j in self._pairs])
        self.lidar_timestamps = self._lidar_times
        self._image_times_ns = [image_stamps[i][1] for i, _ in self._pairs]
        self._cloud_times_ns = [cloud_stamps[j][1] for _, j in self._pairs]
        for times, connection in ((self.timestamps, self._image), (self._lidar_times, self._cloud)):
            self.problems += time_problems(times, f"{self.path} [{connection.topic}]", "header stamp")
        first_cloud = self._first(self._cloud)
        time_fields = [f.name for f in first_cloud.fields if f.name in TIME_FIELDS]
        if time_fields and decode_cloud(first_cloud, f"{self.path} [{self._cloud.topic}]")[1] is None:
            self.notes.append(
                f"the cloud's per-point times ({time_fields[0]}) do not fit one sweep about its stamp "
                f"in any unit: read without them (not deskewed)"
            )
        if T_cam_lidar is None:
            T_cam_lidar = lookup_T_cam_lidar(
                _tf_tree(self.reader),
                info.header.frame_id.lstrip("/"),
                first_cloud.header.frame_id.lstrip("/"),
            )
            if T_cam_lidar is None:
                self.notes.append(
                    "no /tf_static chain from the LiDAR to the camera frame: no reference extrinsic"
                )
        self.calibration = self._calibration(info, T_cam_lidar)

    def _pick(self, topic: str | None, msgtypes: tuple[str, ...], what: str, key: str, near: str = ""):
        """The connection of ``topic``, else the only one of ``msgtypes`` (``near``: the one nearest
        that topic's namespace); ``what`` names it in errors, ``key`` its ``--camera`` key."""
        connections = [c for c in self.reader.connections if c.msgtype in msgtypes]
        if topic is not None:
            chosen = [c for c in connections if c.topic == topic]
            if not chosen:
                have = ", ".join(sorted({c.topic for c in connections})) or "none"
                raise DataError(self.path, f"no {what} topic {topic!r} (available: {have})")
            return chosen[0]
        topics = sorted({c.topic for c in connections})
        namespace = near
        while near and len(topics) > 1 and namespace:  # the camera_info nearest the image topic
            namespace = namespace.rsplit("/", 1)[0]  # /cam/image_raw/compressed -> /cam/image_raw -> /cam
            beside = [t for t in topics if t.startswith(namespace + "/")]
            if len(beside) == 1:
                topics = beside
        if len(topics) != 1:
            pick = f"; pick one with --camera {'' if key == 'image' else key + '='}TOPIC" if topics else ""
            found = ", ".join(topics) or "none"
            raise DataError(self.path, f"found {len(topics)} {what} topics ({found}){pick}")
        return next(c for c in connections if c.topic == topics[0])

    def _first(self, connection):
        for _, _, raw in self.reader.messages(connections=[connection]):
            return self.reader.deserialize(raw, connection.msgtype)
        raise DataError(self.path, f"topic {connection.topic} has no messages")

    def _stamps(self, connection) -> list[tuple[float, int]]:
        """(header stamp in seconds, bag time in ns) of every message on a topic."""
        return [
            (_stamp(self.reader.deserialize(raw, connection.msgtype)), bag_ns)
            for _, bag_ns, raw in self.reader.messages(connections=[connection])
        ]

    @staticmethod
    def _pair(images: list, clouds: list, max_gap: float) -> list[tuple[int, int]]:
        if not images or not clouds:
            return []
        cloud_t = np.array([c[0] for c in clouds])
        best: dict[int, tuple[float, int]] = {}
        for i, (t, _) in enumerate(images):
            j = int(np.argmin(np.abs(cloud_t - t)))
            gap = abs(cloud_t[j] - t)
            if gap <= max_gap and (j not in best or gap < best[j][0]):
                best[j] = (gap, i)
        return sorted((i, j) for j, (_, i) in best.items())

    def _calibration(self, info: object, T_cam_lidar: np.ndarray | None) -> Calibration:
        # copies (np.array): the message's arrays are read only, and torch warns on those
        K = np.array(_field(info, "K"), dtype=np.float64).reshape(3, 3)
        D = np.array(_field(info, "D"), dtype=np.float64)
        model = str(getattr(info, "distortion_model", "") or "plumb_bob").lower()
        if "rect" in self._image.topic:
            K = np.array(np.asarray(_field(info, "P"), dtype=np.float64).reshape(3, 4)[:, :3])
            D = np.zeros(0)
        elif np.any(D) and model not in PINHOLE_MODELS + FISHEYE_MODELS:
            raise DataError(
                self.path,
                f"camera_info distortion model {model!r} is not one this reader undistorts "
                f"({', '.join(PINHOLE_MODELS + FISHEYE_MODELS)}); give rectified images (a *rect* topic)",
            )
        self._fisheye = None
        if np.any(D) and model in FISHEYE_MODELS:
            # OpenCV's fisheye model is ROS's equidistant (k1..k4); Calibration.distortion holds
            # pinhole coefficients only, so the images are undistorted here and it stays None
            self._fisheye = D[:4].reshape(4, 1)
            self.notes.append(f"{model} (fisheye) images undistorted on load to the pinhole K")
            D = np.zeros(0)
        return Calibration(
            K=K,
            T_cam_lidar=T_cam_lidar,
            image_size=(int(info.height), int(info.width)) if info.height else None,  # type: ignore[attr-defined]
            distortion=D if D.size and np.any(D) else None,
            source=f"{self.path} (camera_info, /tf_static)",
        )

    def _message(self, connection, bag_ns: int):
        for _, _, raw in self.reader.messages(connections=[connection], start=bag_ns, stop=bag_ns + 1):
            return self.reader.deserialize(raw, connection.msgtype)
        raise DataError(self.path, f"message at {bag_ns} ns on {connection.topic} vanished")

    def __len__(self) -> int:
        return len(self._pairs)

    def _fingerprint_parts(self):
        """The recording's file names and sizes, the topics read, their message counts, and the
        head of the first, middle and last paired image and cloud messages."""
        files = [self.path] if self.path.is_file() else sorted(p for p in self.path.iterdir() if p.is_file())
        for file in files:
            yield f"{file.name}:{file.stat().st_size}"
        for topic, count in sorted(self._counts.items()):
            yield f"{topic}:{count}"
        n = len(self)
        topics = ((self._image, self._image_times_ns), (self._cloud, self._cloud_times_ns))
        for i in sorted({0, n // 2, n - 1} if n else set()):
            for connection, stamps in topics:
                start = stamps[i]
                for _, _, raw in self.reader.messages(connections=[connection], start=start, stop=start + 1):
                    yield hashlib.sha256(bytes(raw[:SAMPLE_BYTES])).hexdigest()[:16]
                    break

    def frame(self, i: int) -> Frame:
        where = f"{self.path} [{self._image.topic} #{i}]"
        image = decode_image(self._message(self._image, self._image_times_ns[i]), self._image.msgtype, where)
        self._check_image_size(i, image, where)
        if self.calibration.distortion is not None:
            image = cv2.undistort(image, self.calibration.K, self.calibration.distortion)
        elif self._fisheye is not None:
            K = self.calibration.K
            image = cv2.fisheye.undistortImage(image, K, self._fisheye, Knew=K)
        points, times = decode_cloud(
            self._message(self._cloud, self._cloud_times_ns[i]), f"{self.path} [{self._cloud.topic} #{i}]"
        )
        return Frame(
            image=image,
            points=points,
            calibration=self.calibration,
            index=i,
            name=f"{self.timestamps[i]:.6f}",
            timestamp=float(self.timestamps[i]),
            lidar_timestamp=float(self._lidar_times[i]),
            point_times=times,
        )

    def close(self) -> None:
        if getattr(self, "reader", None) is not None and self.reader.stack is not None:
            self.reader.close()


_TF_MSG = "geometry_msgs/TransformStamped[] transforms\n"


def write_bag(
    path: Path,
    frames: list[Frame],
    ros_version: int = 2,
    compressed: bool = False,
    camera_frame: str = "camera_optical",
    lidar_frame: str = "lidar",
    image_topic: str | None = None,
    cloud_topic: str = "/lidar/points",
    second_image_topic: str | None = None,
    info_topic: str = "/camera/camera_info",
    second_info_topic: str | None = None,
    distortion: tuple[str, np.ndarray] | None = None,
) -> Path:
    """Write frames as a ROS bag: image (raw ``rgb8`` or JPEG), ``camera_info``, ``PointCloud2``
    (x y z intensity float32) and ``/tf_static`` holding ``T_lidar_cam`` (parent LiDAR, child
    camera) when the frames carry a reference extrinsic.

    Args:
        path: ``.bag`` file (``ros_version=1``) or bag folder (``ros_version=2``); must not exist.
        second_image_topic: also write each image mirrored left–right on this topic, with a
            ``camera_info`` beside it (a rig with two cameras, to pick one with ``camera``).
        info_topic, second_info_topic: the two cameras' ``camera_info`` topics (the second's
            default: beside its image topic).
        distortion: ``(distortion_model, D)`` for ``camera_info`` (default: ``plumb_bob``,
            zeros); the images are written as they are.
    """
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2

    path = Path(path)
    store = get_typestore(Stores.ROS1_NOETIC if ros_version == 1 else Stores.ROS2_HUMBLE)
    if TF_TYPE not in store.types:
        store.register(get_types_from_msg(_TF_MSG, TF_TYPE))
    types = store.types
    serialize = store.serialize_ros1 if ros_version == 1 else store.serialize_cdr
    image_type = IMAGE_TYPES[1] if compressed else IMAGE_TYPES[0]
    image_topic = image_topic or ("/camera/image/compressed" if compressed else "/camera/image")
    writer = Writer1(path) if ros_version == 1 else Writer2(path, version=9)
    model, D = distortion or ("plumb_bob", np.zeros(5))

    def header(t: float, frame_id: str):
        ns = int(round(t * 1e9))  # floor division: a stamp before 0 keeps nanosec in [0, 1e9)
        stamp = types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        extra = {"seq": 0} if ros_version == 1 else {}
        return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id, **extra)

    def case(name: str) -> str:
        return name.upper() if ros_version == 1 else name.lower()

    with writer:
        conns = {
            "image": writer.add_connection(image_topic, image_type, typestore=store),
            "info": writer.add_connection(info_topic, INFO_TYPE, typestore=store),
            "cloud": writer.add_connection(cloud_topic, CLOUD_TYPE, typestore=store),
        }
        if second_image_topic:
            info2 = second_info_topic or second_image_topic.rsplit("/", 1)[0] + "/camera_info"
            conns["image2"] = writer.add_connection(second_image_topic, image_type, typestore=store)
            conns["info2"] = writer.add_connection(info2, INFO_TYPE, typestore=store)
        calibration = frames[0].calibration
        t0 = frames[0].timestamp or 0.0
        if calibration.T_cam_lidar is not None:
            T_lidar_cam = np.linalg.inv(calibration.T_cam_lidar)
            x, y, z, w = Rotation.from_matrix(T_lidar_cam[:3, :3]).as_quat()
            tf = types["geometry_msgs/msg/TransformStamped"](
                header=header(t0, lidar_frame),
                child_frame_id=camera_frame,
                transform=types["geometry_msgs/msg/Transform"](
                    translation=types["geometry_msgs/msg/Vector3"](*T_lidar_cam[:3, 3]),
                    rotation=types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
                ),
            )
            conn = writer.add_connection("/tf_static", TF_TYPE, typestore=store)
            writer.write(conn, int(t0 * 1e9), serialize(types[TF_TYPE](transforms=[tf]), TF_TYPE))
        Field = types["sensor_msgs/msg/PointField"]
        fields = [
            Field(name=n, offset=4 * k, datatype=7, count=1) for k, n in enumerate("x y z intensity".split())
        ]
        for i, frame in enumerate(frames):
            t = frame.timestamp if frame.timestamp is not None else t0 + i / 10.0
            t_lidar = frame.lidar_timestamp if frame.lidar_timestamp is not None else t
            H, W = frame.image_size

            def image_message(image: np.ndarray, t: float = t, H: int = H, W: int = W):
                if compressed:
                    ok, jpg = cv2.imencode(".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
                    data = np.frombuffer(jpg.tobytes(), np.uint8)
                    return types[image_type](header=header(t, camera_frame), format="jpeg", data=data)
                return types[image_type](
                    header=header(t, camera_frame),
                    height=H,
                    width=W,
                    encoding="rgb8",
                    is_bigendian=0,
                    step=3 * W,
                    data=np.ascontiguousarray(image).reshape(-1).copy(),
                )

            image_msg = image_message(frame.image)
            info = types[INFO_TYPE](
                header=header(t, camera_frame),
                height=H,
                width=W,
                distortion_model=model,
                **{
                    case("D"): np.asarray(D, np.float64),
                    case("K"): calibration.K.reshape(-1),
                    case("R"): np.eye(3).reshape(-1),
                    case("P"): np.hstack([calibration.K, np.zeros((3, 1))]).reshape(-1),
                },
                binning_x=0,
                binning_y=0,
                roi=types["sensor_msgs/msg/RegionOfInterest"](
                    x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
                ),
            )
            pts = np.ascontiguousarray(frame.points[:, :4], dtype=np.float32)
            cloud = types[CLOUD_TYPE](
                header=header(t_lidar, lidar_frame),
                height=1,
                width=len(pts),
                fields=fields,
                is_bigendian=False,
                point_step=16,
                row_step=16 * len(pts),
                data=np.frombuffer(pts.tobytes(), np.uint8),
                is_dense=True,
            )
            writer.write(conns["image"], int(t * 1e9), serialize(image_msg, image_type))
            writer.write(conns["info"], int(t * 1e9), serialize(info, INFO_TYPE))
            writer.write(conns["cloud"], int(t_lidar * 1e9), serialize(cloud, CLOUD_TYPE))
            if "image2" in conns:
                mirrored = image_message(frame.image[:, ::-1])
                writer.write(conns["image2"], int(t * 1e9), serialize(mirrored, image_type))
                writer.write(conns["info2"], int(t * 1e9), serialize(info, INFO_TYPE))
    return path
