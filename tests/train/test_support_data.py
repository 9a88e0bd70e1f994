"""Training data (issue 19, defect 5): maps made from another dataset, or without a fingerprint, are
refused; the sequences' fingerprints go into every checkpoint (the data module's state)."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from calib.data import open_dataset
from calib.errors import DataError
from tests.calib.support.test_map_files import write_maps_folder
from train.support_data import SupportDataModule, load_source
from train.train_config import DataConfig, Source


@pytest.fixture(scope="module")
def sources(tiny_worlds, tmp_path_factory):
    """The tiny worlds with maps folders written for them (flat maps, with the fingerprint)."""
    _, worlds = tiny_worlds
    root = tmp_path_factory.mktemp("maps")
    out = []
    for world in worlds:
        with open_dataset(world["data"], sequence=world["sequence"]) as seq:
            maps = write_maps_folder(root / Path(world["data"]).name, seq)
        out.append({**world, "maps": str(maps)})
    return out


def test_maps_of_another_dataset_are_refused(sources):
    vineyard, urban = sources
    swapped = Source(**{**vineyard, "maps": urban["maps"]})
    with pytest.raises(DataError, match="was made from another dataset") as info:
        load_source(swapped, DataConfig(sources=sources))
    assert str(info.value).startswith(urban["maps"]) and "\n" not in str(info.value)


def test_maps_without_a_fingerprint_are_refused(sources, tmp_path):
    vineyard, _ = sources
    summary = Path(vineyard["maps"]) / "summary.json"
    stored = json.loads(summary.read_text())
    old = {k: v for k, v in stored.items() if k != "dataset_fingerprint"}
    try:
        summary.write_text(json.dumps(old))
        with pytest.raises(DataError, match="carries no dataset fingerprint"):
            load_source(Source(**vineyard), DataConfig(sources=sources))
    finally:
        summary.write_text(json.dumps(stored))


def test_frames_of_a_longer_focal_length_are_resampled_with_their_maps(sources):
    """Known answer: the tiny worlds render at 360.8 px; at a working focal length of half that,
    every image, target and weight is halved (2x2 pixel means), the weighted target keeping its
    mean; at their own focal length nothing is resampled."""
    vineyard, _ = sources
    full = load_source(Source(**vineyard), DataConfig(sources=sources))
    half = load_source(Source(**vineyard), DataConfig(sources=sources, working_focal_px=180.4))
    (n, H, W), (h, w) = full.target.shape, half.target.shape[1:]
    assert (h, w) == (H // 2, W // 2) and half.images.shape == (n, h, w, 3) and half.weight.shape == (n, h, w)
    with open_dataset(vineyard["data"], sequence=vineyard["sequence"]) as seq:
        assert np.array_equal(full.images[0], seq[0].image)
    assert np.array_equal(half.images[0], cv2.resize(full.images[0], (w, h), interpolation=cv2.INTER_AREA))
    assert np.allclose(half.weight[0], cv2.resize(full.weight[0], (w, h), interpolation=cv2.INTER_AREA))
    before = (full.target * full.weight).sum((1, 2)) / full.weight.sum((1, 2))
    after = (half.target * half.weight).sum((1, 2)) / half.weight.sum((1, 2))
    assert np.allclose(before, after, rtol=1e-4)


def test_the_data_module_state_names_each_sequence_and_its_fingerprint(sources):
    data = SupportDataModule(DataConfig(sources=sources, crop=(64, 96)))
    data.setup()
    state = data.state_dict()
    assert [s["split"] for s in state["sources"]] == ["train", "val"]
    for source, saved in zip(sources, state["sources"], strict=True):
        with open_dataset(source["data"], sequence=source["sequence"]) as seq:
            assert saved["dataset_fingerprint"] == seq.fingerprint()
        assert saved["maps"] == source["maps"] and saved["frames"] == 3
