"""Conventions on real data: with the reference calibration, LiDAR occluding contours land on
image edges, measurably more than under the same calibration rotated by 1°."""

import numpy as np
import pytest

from calib.data import open_dataset
from calib.data.io import read_label, read_scan
from calib.data.real_fixtures import AMZ_DRIVE, real_scenes
from calib.errors import DataError
from calib.features import contour_check

pytestmark = pytest.mark.realdata


@pytest.fixture(scope="module")
def checks(realdata, tmp_path_factory):
    scenes = real_scenes(realdata, tmp_path_factory.mktemp("realdata"))
    return {name: contour_check(frame, ring) for name, frame, ring in scenes}


def test_every_real_scene_prefers_the_reference(checks):
    assert len(checks) == 6
    for name, check in checks.items():
        assert check["contour_points"] > 200, name
        assert check["ratio"] > 1.05, f"{name}: {check}"


@pytest.mark.parametrize(("prefix", "margin"), [("kitti", 1.3), ("pjlab", 1.15)])
def test_pooled_margin_per_rig(checks, prefix, margin):
    picked = [c for n, c in checks.items() if n.startswith(prefix)]
    reference = np.mean([c["reference"] for c in picked])
    perturbed = np.mean([c["perturbed_mean"] for c in picked])
    assert reference > margin * perturbed


def test_amz_raw_drive_reads_with_its_fallbacks(realdata):
    seq = open_dataset(realdata / AMZ_DRIVE)
    assert len(seq) == 2
    assert any("image_00" in n for n in seq.notes) and any("10 Hz assumed" in n for n in seq.notes)
    frame = seq[0]
    assert frame.image.shape == (370, 1224, 3) and frame.points.shape[1] == 4
    # the rectified camera-0 projection P_rect_00 · R_rect_00 · [R T]: camera 0 has no offset
    assert frame.K[0, 0] == pytest.approx(707.0493)


def test_semantickitti_fixture_labels(realdata):
    base = realdata / "mmdet3d_demo/tests/data/semantickitti/sequences/00"
    points = read_scan(base / "velodyne/000000.bin")
    labels = read_label(base / "labels/000000.label", len(points))
    assert labels.shape == (50,) and labels.dtype == np.uint16
    assert set(np.unique(labels)) <= set(range(260))


def test_amz_raw_drive_camera_choice(realdata):
    """The AMZ drive has only image_00: --camera 0 reads it without a note, --camera 2 is refused
    with the list of cameras present (issue 19, defect 10)."""
    seq = open_dataset(realdata / AMZ_DRIVE, camera="0")
    assert seq.camera == "00" and not any("absent; using the only camera" in n for n in seq.notes)
    with pytest.raises(DataError, match=r"no camera 2 \(image_02 not found\); available cameras: 0"):
        open_dataset(realdata / AMZ_DRIVE, camera=2)
    # the two AMZ folders share a calibration and layout, not their frames
    more = open_dataset(realdata / AMZ_DRIVE.replace("amz_kitti_raw_0928", "amz_kitti_raw_0928_more"))
    assert more.fingerprint() != seq.fingerprint()
