"""Maps folders read back safely (issue 19, defects 5 and 7): a maps folder made from another
dataset, or without a fingerprint, is refused in one line naming both; a corrupt, truncated or
incomplete npz is a DataError, not a zipfile/zlib/KeyError traceback."""

import json

import numpy as np
import pytest

from calib.data import open_dataset
from calib.data.kitti_odometry import write_kitti_odometry
from calib.errors import DataError
from calib.support.map_files import (
    FINGERPRINT_KEY,
    check_maps_fingerprint,
    dataset_identity,
    load_frame_maps,
    load_npz,
    load_sequence_maps,
)
from tests.conftest import make_frames


def write_maps_folder(folder, seq, fingerprint=True):
    """A maps folder as `supportnet maps` writes it (flat maps), for ``seq``."""
    (folder / "frames").mkdir(parents=True)
    H, W = seq[0].image_size
    maps = {"raw": np.ones((H, W), np.float32), "coverage": np.ones((H, W), np.float32)}
    for i in range(len(seq)):
        np.savez_compressed(folder / "frames" / f"{i:06d}.npz", **maps)
    np.savez_compressed(folder / "sequence.npz", support=np.ones((H, W), np.float32), **maps)
    summary = {"data": "somewhere", "sequence": "00", "frames": len(seq)}
    if fingerprint:
        summary.update(dataset_identity(seq))
    (folder / "summary.json").write_text(json.dumps(summary))
    return folder


@pytest.fixture
def two_datasets(tmp_path):
    write_kitti_odometry(tmp_path / "a", "00", make_frames(3, seed=0))
    write_kitti_odometry(tmp_path / "b", "00", make_frames(3, seed=1))
    return open_dataset(tmp_path / "a"), open_dataset(tmp_path / "b")


def test_maps_of_the_same_dataset_pass(tmp_path, two_datasets):
    a, _ = two_datasets
    maps = write_maps_folder(tmp_path / "maps", a)
    check_maps_fingerprint(maps, a)
    assert json.loads((maps / "summary.json").read_text())[FINGERPRINT_KEY] == a.fingerprint()
    assert load_sequence_maps(maps)["support"].shape == (188, 624)
    assert set(load_frame_maps(maps, 2)) == {"raw", "coverage"}


def test_maps_of_another_dataset_are_refused_naming_both(tmp_path, two_datasets):
    a, b = two_datasets
    maps = write_maps_folder(tmp_path / "maps", a)
    with pytest.raises(DataError) as info:
        check_maps_fingerprint(maps, b)
    message = str(info.value)
    assert message == (
        f"{maps}: was made from another dataset ({a.name}, fingerprint {a.fingerprint()}) than "
        f"{b.name} (fingerprint {b.fingerprint()}); make maps of this dataset with `supportnet maps`"
    )


def test_old_maps_without_a_fingerprint_are_refused(tmp_path, two_datasets):
    a, _ = two_datasets
    maps = write_maps_folder(tmp_path / "maps", a, fingerprint=False)
    with pytest.raises(
        DataError, match="carries no dataset fingerprint .* remake the maps with `supportnet maps`"
    ):
        check_maps_fingerprint(maps, a)
    (maps / "summary.json").unlink()
    with pytest.raises(DataError, match="has no summary.json: not a finished `supportnet maps` folder"):
        check_maps_fingerprint(maps, a)
    (maps / "summary.json").write_text("{broken")
    with pytest.raises(DataError, match="summary.json: does not parse"):
        check_maps_fingerprint(maps, a)
    with pytest.raises(DataError, match="maps folder not found"):
        check_maps_fingerprint(tmp_path / "nope", a)


def _npz(tmp_path, **arrays):
    path = tmp_path / "m.npz"
    np.savez_compressed(path, **arrays)
    return path


@pytest.mark.parametrize(
    "damage, match",
    [
        (lambda raw: raw[: len(raw) // 2], "is not a readable maps file"),  # truncated zip
        (lambda raw: b"not a zip at all" * 10, "is not a readable maps file"),
        (lambda raw: b"", "is not a readable maps file"),
        # flip bytes inside the compressed member: a bad CRC or a zlib error
        (
            lambda raw: raw[:60] + bytes(b ^ 0xFF for b in raw[60:200]) + raw[200:],
            "is not a readable maps file",
        ),
    ],
)
def test_corrupt_npz_is_one_line(tmp_path, damage, match):
    path = _npz(tmp_path, raw=np.random.default_rng(0).random((40, 60)), coverage=np.ones((40, 60)))
    path.write_bytes(damage(path.read_bytes()))
    with pytest.raises(DataError, match=match) as info:
        load_npz(path, ("raw", "coverage"))
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


def test_incomplete_or_bad_arrays(tmp_path):
    path = _npz(tmp_path, raw=np.ones((4, 5)))
    with pytest.raises(DataError, match=r"has no coverage array \(has: raw\)"):
        load_npz(path, ("raw", "coverage"))
    path = _npz(tmp_path, raw=np.full((4, 5), np.nan), coverage=np.ones((4, 5)))
    with pytest.raises(DataError, match="'raw' holds NaN"):
        load_npz(path, ("raw", "coverage"))
    path = _npz(tmp_path, raw=np.ones(5), coverage=np.ones(5))
    with pytest.raises(DataError, match="'raw' is not a 2-D map"):
        load_npz(path, ("raw", "coverage"))
    path = _npz(tmp_path, raw=np.ones((4, 5)), coverage=np.ones((5, 4)))
    with pytest.raises(DataError, match="arrays have different shapes"):
        load_npz(path, ("raw", "coverage"))
    path = tmp_path / "p.npz"
    np.savez(path, raw=np.array([{"a": 1}], dtype=object))
    with pytest.raises(DataError, match="is not a readable maps file"):
        load_npz(path, ("raw",))
    with pytest.raises(DataError, match="missing: the maps do not cover frame 7"):
        load_frame_maps(tmp_path, 7)
