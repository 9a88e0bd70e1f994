"""calib.data.rig: frames of several cameras placed in one rig from the extrinsics they carry."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from calib.data import open_dataset
from calib.data.real_fixtures import NUSCENES_CAMERAS, custom_from_nuscenes
from calib.data.rig import as_rig, unknown_reference
from calib.errors import DataError
from calib.geometry import perturb
from tests.conftest import make_frames


def test_each_camera_in_the_rig_keeps_its_own_extrinsic():
    """Known answer: three cameras with different extrinsics (the reference, or the data's initial
    one where there is none); in the rig the first camera's frame is the rig's, each camera's
    ``T_cam_rig · T_rig_lidar`` is its own ``T_cam_lidar``, and the rig's reference is the first's."""
    frames = make_frames(3)
    generator = torch.Generator().manual_seed(1)
    own = [perturb(frames[0].calibration.T_cam_lidar, 40.0, 30.0, generator) for _ in frames]
    frames = [
        replace(f, calibration=replace(f.calibration, T_cam_lidar=T))
        for f, T in zip(frames, own, strict=True)
    ]
    frames[2] = replace(
        frames[2], calibration=replace(frames[2].calibration, T_cam_lidar=None, initial_T_cam_lidar=own[2])
    )
    rig = as_rig(frames)
    np.testing.assert_allclose(rig[0].calibration.T_cam_rig, np.eye(4), atol=1e-12)
    for frame, T in zip(rig, own, strict=True):
        np.testing.assert_allclose(frame.calibration.camera_extrinsic(own[0]), T, atol=1e-12)
    np.testing.assert_allclose(unknown_reference(rig[1].calibration), own[0], atol=1e-12)
    assert unknown_reference(rig[2].calibration) is None  # a guess is not a reference


def test_a_camera_without_any_extrinsic_or_no_camera_is_refused():
    frames = make_frames(2)
    bare = replace(frames[1], name="cam_b", calibration=replace(frames[1].calibration, T_cam_lidar=None))
    with pytest.raises(DataError, match="cam_b.*no extrinsic"):
        as_rig([frames[0], bare])
    with pytest.raises(DataError, match="at least one"):
        as_rig([])


def test_the_nuscenes_cameras_form_one_rig(realdata, tmp_path):
    """The six nuScenes cameras of one sweep: one ``T_rig_lidar`` (CAM_FRONT's extrinsic) gives
    every camera its own reference."""
    frames = [open_dataset(custom_from_nuscenes(realdata, c, tmp_path / c))[0] for c in NUSCENES_CAMERAS]
    rig = as_rig(frames)
    T_rig_lidar = unknown_reference(rig[3].calibration)
    np.testing.assert_allclose(T_rig_lidar, frames[0].calibration.T_cam_lidar, atol=1e-9)
    for frame in rig:
        np.testing.assert_allclose(
            frame.calibration.camera_extrinsic(T_rig_lidar), frame.calibration.T_cam_lidar, atol=1e-9
        )
