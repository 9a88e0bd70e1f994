"""The nuScenes reader (devkit layout): tables, transforms, the points moved to the camera's time."""

import json

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from calib.data import detect_layout, open_dataset
from calib.data.nuscenes import _parsed_index, pose_matrix
from calib.data.real_fixtures import NUSCENES, NUSCENES_CAMERAS, custom_from_nuscenes, nuscenes_from_mmdet
from calib.errors import DataError

SPEED = 10.0  # m/s along the car's x
LEAD_S = -0.030  # the camera exposes 30 ms before the sweep's stamp


def _quaternion_z(angle: float) -> list[float]:
    return [np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)]


def write_devkit(root, samples=3, scenes=("scene-0001",), drop=None):
    """A small devkit layout: a car driving at ``SPEED`` along x, a LiDAR 1.8 m up turned 90° about
    z (its y forward, as LIDAR_TOP), one camera ``CAM_FRONT`` looking forward, exposing
    ``LEAD_S`` from each sweep's stamp. Each sweep: a ring of points, 5 float32 columns."""
    tables = {k: [] for k in ("scene", "sample", "sample_data", "calibrated_sensor", "sensor", "ego_pose")}
    tables["sensor"] += [
        {"token": "s_lidar", "channel": "LIDAR_TOP", "modality": "lidar"},
        {"token": "s_cam", "channel": "CAM_FRONT", "modality": "camera"},
        {"token": "s_back", "channel": "CAM_BACK", "modality": "camera"},
    ]
    K = [[500.0, 0.0, 80.0], [0.0, 500.0, 60.0], [0.0, 0.0, 1.0]]
    # camera: z forward (car x), x right (car −y), y down (car −z)
    R_ego_cam = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    w = np.sqrt(1 + np.trace(R_ego_cam)) / 2
    q_cam = [
        w,
        (R_ego_cam[2, 1] - R_ego_cam[1, 2]) / (4 * w),
        (R_ego_cam[0, 2] - R_ego_cam[2, 0]) / (4 * w),
        (R_ego_cam[1, 0] - R_ego_cam[0, 1]) / (4 * w),
    ]
    tables["calibrated_sensor"] += [
        {"token": "c_lidar", "sensor_token": "s_lidar", "translation": [0.9, 0.0, 1.8],
         "rotation": _quaternion_z(-np.pi / 2), "camera_intrinsic": []},
        {"token": "c_cam", "sensor_token": "s_cam", "translation": [1.7, 0.0, 1.5], "rotation": q_cam,
         "camera_intrinsic": K},
    ]  # fmt: skip
    rng = np.random.default_rng(0)
    for s, scene in enumerate(scenes):
        tokens = [f"{scene}_{i}" for i in range(samples)]
        tables["scene"].append(
            {
                "token": f"tok_{scene}",
                "name": scene,
                "first_sample_token": tokens[0],
                "last_sample_token": tokens[-1],
            }
        )
        for i, token in enumerate(tokens):
            t_lidar = 1_000_000 * (s * 100 + 1) + 500_000 * i  # µs, key frames at 2 Hz
            t_cam = t_lidar + round(LEAD_S * 1e6)
            tables["sample"].append(
                {"token": token, "timestamp": t_lidar, "scene_token": f"tok_{scene}",
                 "prev": tokens[i - 1] if i else "", "next": tokens[i + 1] if i + 1 < samples else ""}
            )  # fmt: skip
            for kind, stamp, channel, calib in (
                ("l", t_lidar, "LIDAR_TOP", "c_lidar"),
                ("c", t_cam, "CAM_FRONT", "c_cam"),
            ):
                if drop == (i, channel):
                    continue
                name = f"samples/{channel}/{token}.{'pcd.bin' if kind == 'l' else 'jpg'}"
                tables["ego_pose"].append(
                    {"token": f"e_{kind}_{token}", "timestamp": stamp, "rotation": [1.0, 0, 0, 0],
                     "translation": [SPEED * stamp * 1e-6, 2.0, 0.0]}
                )  # fmt: skip
                tables["sample_data"].append(
                    {"token": f"d_{kind}_{token}", "sample_token": token,
                     "ego_pose_token": f"e_{kind}_{token}", "calibrated_sensor_token": calib,
                     "timestamp": stamp, "is_key_frame": True,
                     "height": 120, "width": 160, "filename": name, "prev": "", "next": ""}
                )  # fmt: skip
                (root / name).parent.mkdir(parents=True, exist_ok=True)
                if kind == "l":
                    n = 64
                    ring = np.repeat(np.arange(4), n // 4)
                    azimuth = rng.uniform(-np.pi, np.pi, n)
                    scan = np.column_stack(
                        [
                            10 * np.cos(azimuth),
                            10 * np.sin(azimuth),
                            ring * 0.1 - 1.0,
                            rng.uniform(0, 100, n),
                            ring,
                        ]
                    ).astype(np.float32)
                    scan[::16, :3] = [0.0, 0.45, 0.0]  # missing returns: at the sensor, moved with the car
                    scan.tofile(root / name)
                else:
                    cv2.imwrite(str(root / name), np.full((120, 160, 3), 90 + 10 * i, np.uint8))
    (root / "v1.0-mini").mkdir(parents=True, exist_ok=True)
    for name, records in tables.items():
        (root / "v1.0-mini" / f"{name}.json").write_text(json.dumps(records))
    return root


def test_quaternion_known_answers():
    T = pose_matrix({"translation": [1, 2, 3], "rotation": _quaternion_z(np.pi / 2)}, "t")
    np.testing.assert_allclose(T[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [1, 2, 3])
    with pytest.raises(DataError, match="not a unit quaternion"):
        pose_matrix({"token": "x", "translation": [0, 0, 0], "rotation": [2, 0, 0, 0]}, "t")
    with pytest.raises(DataError, match="w, x, y, z rotation"):
        pose_matrix({"token": "x", "translation": [0, 0]}, "t")


def test_points_move_to_the_cameras_time_and_the_reference_is_static(tmp_path):
    """Known answer: a car at 10 m/s, the camera 30 ms before the sweep: in the LiDAR frame at the
    camera's time every point lies 30 cm further ahead (the LiDAR's y), and the reference is
    ``T_ego_cam⁻¹ · T_ego_lidar``."""
    root = write_devkit(tmp_path / "nus")
    assert detect_layout(root) == "nuscenes" and detect_layout(root / "v1.0-mini") == "nuscenes"
    seq = open_dataset(root)
    assert (seq.layout, seq.name, seq.camera, len(seq)) == ("nuscenes", "scene-0001", "CAM_FRONT", 3)
    assert any("-30.0 ms" in note for note in seq.notes)
    raw = np.fromfile(root / "samples/LIDAR_TOP/scene-0001_1.pcd.bin", np.float32).reshape(-1, 5)
    raw = raw[np.linalg.norm(raw[:, :3], axis=1) > 1.0]  # the missing returns dropped
    frame = seq[1]
    assert frame.timestamp == pytest.approx(1.5 + LEAD_S) and frame.lidar_timestamp is None
    assert frame.points.shape == (60, 4) and frame.image.shape == (120, 160, 3)
    # scan-line order about the centre the points now have: by ring, then azimuth
    moved = raw[:, :3] + np.array([0.0, -SPEED * LEAD_S, 0.0], np.float32)
    order = np.lexsort((np.arctan2(moved[:, 1], moved[:, 0]), raw[:, 4]))  # ring, then azimuth
    np.testing.assert_allclose(frame.points[:, :3], moved[order], atol=1e-5)
    np.testing.assert_array_equal(frame.points[:, 3], raw[order, 3])
    # static reference: a LiDAR point 10 m ahead (its y) and 0.3 m below the camera centre
    T = seq.calibration.T_cam_lidar
    p_cam = T[:3, :3] @ np.array([0.0, 10.0, 0.0]) + T[:3, 3]
    np.testing.assert_allclose(p_cam, [0.0, -0.3, 10.0 - 0.8], atol=1e-12)
    np.testing.assert_allclose(
        seq.poses[:, :3, 3], [[0, 0, 0], [0, SPEED * 0.5, 0], [0, SPEED * 1.0, 0]], atol=1e-9
    )


def test_scenes_cameras_and_broken_data_are_named(tmp_path):
    root = write_devkit(tmp_path / "two", scenes=("scene-0001", "scene-0002"))
    with pytest.raises(
        DataError, match=r"holds 2 scenes \(scene-0001, scene-0002\); pick one with --sequence"
    ):
        open_dataset(root)
    assert len(open_dataset(root, sequence="scene-0002")) == 3
    parsed = _parsed_index.cache_info().misses
    assert len(open_dataset(root, sequence="scene-0001")) == 3  # the tables parsed once for both
    assert _parsed_index.cache_info().misses == parsed
    assert len(open_dataset(root, sequence="tok_scene-0002")) == 3
    with pytest.raises(DataError, match="no scene 'scene-9'"):
        open_dataset(root, sequence="scene-9")
    with pytest.raises(DataError, match="no camera 'CAM_LEFT'; available cameras: CAM_BACK, CAM_FRONT"):
        open_dataset(root, sequence="scene-0001", camera="CAM_LEFT")
    with pytest.raises(DataError, match="no key frame of both CAM_BACK and LIDAR_TOP"):
        open_dataset(root, sequence="scene-0001", camera="CAM_BACK")

    gap = write_devkit(tmp_path / "gap", drop=(1, "CAM_FRONT"))
    with pytest.raises(DataError, match="has no key frame of CAM_FRONT"):
        open_dataset(gap)
    assert len(open_dataset(gap, strict=False)) == 2

    cut = tmp_path / "gap" / "samples/LIDAR_TOP/scene-0001_2.pcd.bin"
    cut.write_bytes(cut.read_bytes()[:-4])
    seq = open_dataset(gap, strict=False)
    assert any("not a multiple of 20" in p for p in seq.problems)
    with pytest.raises(DataError, match="not a multiple of 20"):
        seq[1]

    (tmp_path / "gap" / "v1.0-mini" / "ego_pose.json").write_text("[{")
    with pytest.raises(DataError, match="ego_pose.json: does not parse as JSON"):
        open_dataset(gap)
    (tmp_path / "gap" / "v1.0-trainval").mkdir()
    (tmp_path / "gap" / "v1.0-trainval" / "sample_data.json").write_text("[]")
    with pytest.raises(DataError, match="holds table folders v1.0-mini, v1.0-trainval; point --data at one"):
        open_dataset(gap)


@pytest.mark.realdata
def test_the_real_sample_projects_as_the_devkit(realdata, tmp_path):
    """Known answer on the real nuScenes sample: every camera's frame under the static extrinsic
    puts every point where the pickle's ``lidar2cam`` (the devkit's chain, the car's motion to the
    camera's exposure folded in) puts the sweep as stored, image and ``K`` the same; the 8029
    returns within 1 m of the sensor (missing returns, one position for several lasers) dropped."""
    root = nuscenes_from_mmdet(realdata, tmp_path / "nus")
    for camera in NUSCENES_CAMERAS:
        seq = open_dataset(root, camera=camera)
        frame, stored = seq[0], open_dataset(custom_from_nuscenes(realdata, camera, tmp_path / camera))[0]
        assert frame.name == stored_name(realdata, camera)
        ours = (
            frame.points[:, :3] @ seq.calibration.T_cam_lidar[:3, :3].T + seq.calibration.T_cam_lidar[:3, 3]
        )
        T = stored.calibration.T_cam_lidar
        kept = stored.points[np.linalg.norm(stored.points[:, :3], axis=1) >= 1.0]  # missing returns out
        assert len(kept) == len(frame.points) == 34688 - 8029
        theirs = kept[:, :3] @ T[:3, :3].T + T[:3, 3]
        # the same points in another order (scan lines about the LiDAR at the camera's time)
        distance, match = cKDTree(theirs).query(ours)
        assert distance.max() < 2e-5 and len(np.unique(match)) == len(ours)
        np.testing.assert_array_equal(frame.image, stored.image)
        np.testing.assert_allclose(frame.K, stored.K)


def stored_name(realdata, camera):
    return next((realdata / NUSCENES).glob(f"*__{camera}__*.jpg")).name.removesuffix(".jpg")
