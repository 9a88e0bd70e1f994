import pytest

from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config


@pytest.fixture(scope="session")
def tiny_worlds(tmp_path_factory):
    """Two 3-frame sequences of different worlds as training sources: one to train on, one held out."""
    root = tmp_path_factory.mktemp("tiny")
    sources = []
    for world, sequence, split in (("vineyard", "00", "train"), ("urban", "01", "val")):
        write_sequence(Synthesizer(load_synth_config(world, small=True), 3, seed=1), root / world, sequence)
        sources.append({"data": str(root / world), "sequence": sequence, "split": split})
    return root, sources
