"""Training data (issue 19, defect 5): maps made from another dataset, or without a fingerprint, are
refused; the sequences' fingerprints go into every checkpoint (the data module's state)."""

import json
from pathlib import Path

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


def test_the_data_module_state_names_each_sequence_and_its_fingerprint(sources):
    data = SupportDataModule(DataConfig(sources=sources, crop=(64, 96)))
    data.setup()
    state = data.state_dict()
    assert [s["split"] for s in state["sources"]] == ["train", "val"]
    for source, saved in zip(sources, state["sources"], strict=True):
        with open_dataset(source["data"], sequence=source["sequence"]) as seq:
            assert saved["dataset_fingerprint"] == seq.fingerprint()
        assert saved["maps"] == source["maps"] and saved["frames"] == 3
