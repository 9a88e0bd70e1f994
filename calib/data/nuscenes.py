"""nuScenes layout (the devkit's): a data root holding one ``v1.0-*`` folder of JSON tables
(``scene``, ``sample``, ``sample_data``, ``calibrated_sensor``, ``sensor``, ``ego_pose``) and the
``samples/`` they name; ``--data`` may also be the ``v1.0-*`` folder itself. ``--sequence`` picks a
scene (its name, ``scene-0061``, or token; the only scene where there is one), ``--camera`` a
camera channel (``CAM_FRONT`` by default). A frame is one key frame (sample): the camera's JPEG
and the ``LIDAR_TOP`` sweep of the same sample (``.pcd.bin``, float32 ``x, y, z, intensity,
ring``; stored in firing order, read in scan-line order by the ring, returns within
:data:`MIN_RANGE_M` of the sensor dropped).

Transforms: ``calibrated_sensor`` gives each sensor's pose on the car (``T_ego_sensor``,
quaternion ``w, x, y, z``), ``ego_pose`` the car's in the world at each sample_data's time
(``T_world_ego``). The reference extrinsic is the static ``T_cam_lidar = T_ego_cam⁻¹ ·
T_ego_lidar``. A camera exposes up to 50 ms away from the sweep's stamp (each when the LiDAR
faces it), and the sweep is motion-compensated to its stamp, so the reader moves the points to
the camera's time with the car's two poses, as the devkit projects (``T_lidar(t_cam)⁻¹ ·
T_lidar(t_lidar)``, ``T_lidar(t) = T_world_ego(t) · T_ego_lidar``): a frame is then a
synchronised pair under the static extrinsic, its scan stamped at the camera's time, and a rig of
the six cameras (:mod:`calib.data.rig`) places each camera by that extrinsic. The images are
stored undistorted (``camera_intrinsic`` is their ``K``). The tables are read whole (``v1.0-mini``
in a second; the full ``v1.0-trainval`` takes minutes and several GB).
"""

from __future__ import annotations

import functools
import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from calib.data.io import read_image, require_file, scanline_order, validate_points
from calib.data.types import Calibration, FileSequence, Frame, time_problems
from calib.errors import DataError

__all__ = ["DEFAULT_NUSCENES_CAMERA", "NuScenesSequence", "is_nuscenes", "pose_matrix", "read_nuscenes"]

DEFAULT_NUSCENES_CAMERA = "CAM_FRONT"
MIN_RANGE_M = 1.0
"""Returns nearer than this are dropped, as the devkit's ``remove_close`` does: a sweep stores its
lasers' missing returns at the sensor, moved with the car by the motion compensation (a quarter
of the sample's 34688 returns lie within 1 m, one position shared by several lasers, 0.45 m from
the sensor at 9.3 m/s), and the car's own roof."""
LIDAR_CHANNEL = "LIDAR_TOP"
TABLES = ("scene", "sample", "sample_data", "calibrated_sensor", "sensor", "ego_pose")


def _versions(path: Path) -> list[Path]:
    """The table folders at ``path``: itself where it holds ``sample_data.json``, else its
    ``v1.0-*`` folders that do."""
    if (path / "sample_data.json").is_file():
        return [path]
    return sorted(p for p in path.glob("v1.0-*") if (p / "sample_data.json").is_file())


def is_nuscenes(path: Path) -> bool:
    return path.is_dir() and bool(_versions(path))


def pose_matrix(record: dict, where: str | Path) -> np.ndarray:
    """``(4, 4)`` from a table record's ``translation`` (m) and ``rotation`` (unit quaternion
    ``w, x, y, z``, as nuScenes stores it)."""
    try:
        t = np.asarray(record["translation"], np.float64).reshape(3)
        w, x, y, z = np.asarray(record["rotation"], np.float64).reshape(4)
    except (KeyError, ValueError, TypeError):
        raise DataError(
            where, f"record {record.get('token', '?')!r} has no 3-vector translation and w, x, y, z rotation"
        ) from None
    norm = np.sqrt(w * w + x * x + y * y + z * z)
    if not np.isfinite(norm) or abs(norm - 1.0) > 1e-3 or not np.isfinite(t).all():
        raise DataError(
            where,
            f"record {record.get('token', '?')!r}: rotation is not a unit quaternion "
            f"or translation not finite ({[w, x, y, z]}, {t.tolist()})",
        )
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()  # scipy's order: scalar last
    T[:3, 3] = t
    return T


def _table(folder: Path, name: str) -> list[dict]:
    path = folder / f"{name}.json"
    require_file(path)
    try:
        records = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(path, f"does not parse as JSON ({exc})") from None
    if not isinstance(records, list) or not all(isinstance(r, dict) and "token" in r for r in records):
        raise DataError(path, "is not a list of records with a 'token'")
    return records


def read_nuscenes_bin(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A nuScenes ``.pcd.bin`` sweep (float32 ``x, y, z, intensity, ring`` per point) ->
    ``(N, 4)`` float32 points and ``(N,)`` int64 rings."""
    require_file(path)
    size = path.stat().st_size
    if size % 20:
        raise DataError(path, f"truncated: {size} bytes is not a multiple of 20 (5 float32 per point)")
    raw = np.fromfile(path, dtype=np.float32).reshape(-1, 5)
    return validate_points(np.ascontiguousarray(raw[:, :4]), path), raw[:, 4].astype(np.int64)


class NuScenesSequence(FileSequence):
    """One camera's key frames of one nuScenes scene (see the module docstring).

    Attributes (beyond :class:`FileSequence`'s):
        lidar_poses: ``(len, 4, 4)`` ``T_world_lidar`` at each sweep's stamp.
        camera_poses: ``(len, 4, 4)`` ``T_world_lidar`` at each image's time (the LiDAR where the
            car had taken it when the camera exposed); ``poses`` are these in the first one's frame.
        sweep_timestamps: ``(len,)`` each sweep's own stamp in seconds (``timestamps`` are the
            camera's, and the points are moved to them).
    """

    scan_row_bytes = 20

    def __init__(
        self,
        *args: object,
        lidar_poses: np.ndarray,
        camera_poses: np.ndarray,
        sweep_timestamps: np.ndarray,
        **kwargs: object,
    ) -> None:
        super().__init__(*args, **kwargs)
        self.lidar_poses, self.camera_poses = lidar_poses, camera_poses
        self.sweep_timestamps = sweep_timestamps

    def _fingerprint_parts(self) -> Iterator[str]:
        yield from super()._fingerprint_parts()
        yield np.ascontiguousarray(self.sweep_timestamps, np.float64).tobytes().hex()

    def frame(self, i: int) -> Frame:
        image = read_image(self.image_paths[i])
        self._check_image_size(i, image, self.image_paths[i])
        points, ring = read_nuscenes_bin(self.scan_paths[i])
        near = np.linalg.norm(points[:, :3], axis=1) < MIN_RANGE_M
        points, ring = points[~near], ring[~near]
        # the LiDAR's motion from the sweep's stamp to the camera's exposure (the devkit's chain);
        # then scan-line order by the ring and the azimuth about the centre the points now have
        T_then_now = np.linalg.inv(self.camera_poses[i]) @ self.lidar_poses[i]
        moved = points.copy()
        moved[:, :3] = (points[:, :3].astype(np.float64) @ T_then_now[:3, :3].T + T_then_now[:3, 3]).astype(
            np.float32
        )
        moved = moved[scanline_order(moved[:, :3], ring)]
        return Frame(
            image=image,
            points=moved,
            calibration=self.calibration,
            index=i,
            name=self.image_paths[i].stem,
            timestamp=float(self.timestamps[i]),
        )


@dataclass(frozen=True)
class _Index:
    """A table folder's records: scenes in order, the others by token, and every key frame's
    ``sample_data`` by its sample and channel."""

    scenes: list[dict]
    sensors: dict[str, dict]
    calibrated: dict[str, dict]
    ego: dict[str, dict]
    samples: dict[str, dict]
    key_frames: dict[tuple[str, str], dict]


def _index(tables: Path) -> _Index:
    """The folder's :class:`_Index`, parsed once while its files stay as they are (a rig's
    cameras open one dataset once each: v1.0-trainval's tables take minutes to parse)."""
    stamps = []
    for name in TABLES:
        path = tables / f"{name}.json"
        stamps.append((path.stat().st_mtime_ns, path.stat().st_size) if path.is_file() else None)
    return _parsed_index(tables, tuple(stamps))


@functools.lru_cache(maxsize=1)
def _parsed_index(tables: Path, _stamps: tuple) -> _Index:
    sensors = {r["token"]: r for r in _table(tables, "sensor")}
    calibrated = {r["token"]: r for r in _table(tables, "calibrated_sensor")}

    def channel(record: dict) -> str:
        return sensors.get(
            calibrated.get(record.get("calibrated_sensor_token"), {}).get("sensor_token"), {}
        ).get("channel", "")

    key_frames = {
        (record.get("sample_token"), channel(record)): record
        for record in _table(tables, "sample_data")
        if record.get("is_key_frame")
    }
    return _Index(
        scenes=_table(tables, "scene"),
        sensors=sensors,
        calibrated=calibrated,
        ego={r["token"]: r for r in _table(tables, "ego_pose")},
        samples={r["token"]: r for r in _table(tables, "sample")},
        key_frames=key_frames,
    )


def _scene(scenes: list[dict], sequence: str | None, where: Path) -> dict:
    if sequence is None and len(scenes) == 1:
        return scenes[0]
    chosen = [s for s in scenes if sequence is not None and sequence in (s.get("name"), s["token"])]
    if chosen:
        return chosen[0]
    listed = ", ".join(s.get("name", s["token"]) for s in scenes[:12])
    listed += f" and {len(scenes) - 12} more" if len(scenes) > 12 else ""
    if sequence is None:
        raise DataError(where, f"holds {len(scenes)} scenes ({listed}); pick one with --sequence")
    raise DataError(where, f"no scene {sequence!r} (have: {listed})")


def read_nuscenes(
    path: Path, sequence: str | None = None, camera: int | str | None = None
) -> NuScenesSequence:
    """Read one camera of one nuScenes scene (see the module docstring).

    Args:
        path: the data root (holding one ``v1.0-*`` table folder and ``samples/``) or the table
            folder itself.
        sequence: the scene's name or token (``None``: the only scene).
        camera: a camera channel (``None``: ``CAM_FRONT``); one the data lacks is refused with
            the list of those it has.
    """
    path = Path(path)
    versions = _versions(path)
    if len(versions) != 1:
        raise DataError(
            path, f"holds table folders {', '.join(v.name for v in versions)}; point --data at one of them"
        )
    tables = versions[0]
    root = tables if (tables / "samples").is_dir() else tables.parent
    index = _index(tables)
    sensors, calibrated, ego, samples = index.sensors, index.calibrated, index.ego, index.samples
    scene = _scene(index.scenes, sequence, tables / "scene.json")
    cameras = sorted({s["channel"] for s in sensors.values() if s.get("modality") == "camera"})
    name = str(camera) if camera is not None else DEFAULT_NUSCENES_CAMERA
    if name not in cameras:
        raise DataError(tables, f"no camera {name!r}; available cameras: {', '.join(cameras) or 'none'}")

    order, token = [], scene.get("first_sample_token", "")
    while token and token in samples and len(order) <= len(samples):
        order.append(token)
        token = samples[token].get("next", "")
    problems: list[str] = []
    pairs = []
    for sample in order:
        image, sweep = index.key_frames.get((sample, name)), index.key_frames.get((sample, LIDAR_CHANNEL))
        if image is None or sweep is None:
            problems.append(
                f"{tables / 'sample_data.json'}: sample {sample} of {scene.get('name')} "
                f"has no key frame of {name if image is None else LIDAR_CHANNEL}"
            )
            continue
        pairs.append((image, sweep))
    if not pairs:
        raise DataError(
            tables, f"scene {scene.get('name')!r} has no key frame of both {name} and {LIDAR_CHANNEL}"
        )

    where = tables / "calibrated_sensor.json"
    used = {(c["calibrated_sensor_token"], s["calibrated_sensor_token"]) for c, s in pairs}
    if len(used) > 1:
        problems.append(
            f"{where}: scene {scene.get('name')!r} holds {len(used)} calibrations of {name} "
            f"and {LIDAR_CHANNEL}; a sequence has one extrinsic"
        )
    cam_record = calibrated[pairs[0][0]["calibrated_sensor_token"]]
    T_ego_cam = pose_matrix(cam_record, where)
    T_ego_lidar = pose_matrix(calibrated[pairs[0][1]["calibrated_sensor_token"]], where)

    def world(record: dict, T_ego_sensor: np.ndarray) -> np.ndarray:
        pose = ego.get(record.get("ego_pose_token"))
        if pose is None:
            raise DataError(tables / "ego_pose.json", f"has no ego pose {record.get('ego_pose_token')!r}")
        return pose_matrix(pose, tables / "ego_pose.json") @ T_ego_sensor

    K = np.asarray(cam_record.get("camera_intrinsic") or np.zeros((0,)), np.float64)
    if K.shape != (3, 3):
        raise DataError(where, f"{name}'s camera_intrinsic is not a 3x3 matrix")
    size = (pairs[0][0].get("height"), pairs[0][0].get("width"))
    calibration = Calibration(
        K=K,
        T_cam_lidar=np.linalg.inv(T_ego_cam) @ T_ego_lidar,
        image_size=(int(size[0]), int(size[1])) if all(isinstance(v, int) and v > 0 for v in size) else None,
        source=str(where),
    )
    camera_times = np.array([c["timestamp"] for c, _ in pairs], np.float64) * 1e-6
    sweep_times = np.array([s["timestamp"] for _, s in pairs], np.float64) * 1e-6
    problems += time_problems(camera_times, tables / "sample_data.json")
    lead_ms = 1e3 * (camera_times - sweep_times)
    notes = [
        f"{name} exposes {np.median(lead_ms):+.1f} ms from the sweep's stamp (median; "
        f"{lead_ms.min():+.1f} to {lead_ms.max():+.1f}): the points are moved to the camera's time "
        "with the car's poses, as the devkit projects; the reference is the static calibrated_sensor "
        "extrinsic"
    ]
    camera_poses = np.stack([world(c, T_ego_lidar) for c, _ in pairs])
    return NuScenesSequence(
        name=str(scene.get("name", scene["token"])),
        layout="nuscenes",
        image_paths=[root / c["filename"] for c, _ in pairs],
        scan_paths=[root / s["filename"] for _, s in pairs],
        calibration=calibration,
        timestamps=camera_times,
        notes=notes,
        problems=problems,
        camera=name,
        poses=np.linalg.inv(camera_poses[0]) @ camera_poses,
        lidar_poses=np.stack([world(s, T_ego_lidar) for _, s in pairs]),
        camera_poses=camera_poses,
        sweep_timestamps=sweep_times,
    )
