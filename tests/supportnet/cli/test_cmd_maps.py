import numpy as np
import pytest

from calib.errors import DataError, SupportnetError
from calib.match.edge_matcher import EdgeMatcherConfig
from calib.support.support_maps import load_maps_config
from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config
from supportnet.cli.cmd_maps import run_maps
from supportnet.runtime.matcher_factory import build_matcher


@pytest.fixture(scope="module")
def vineyard(tmp_path_factory):
    root = tmp_path_factory.mktemp("vineyard")
    write_sequence(Synthesizer(load_synth_config("vineyard", small=True), 3, seed=4), root, "00")
    return root


def test_maps_writes_frames_and_sequence_and_refuses_to_overwrite(vineyard, tmp_path):
    out = run_maps(vineyard, "00", tmp_path / "maps", load_maps_config(sigma_px=5.0))
    frames = sorted((out / "frames").glob("*.npz"))
    assert len(frames) == 3 and len(list((out / "previews").glob("*.png"))) == 3
    frame = np.load(frames[0])
    assert (
        frame["support"].shape == (188, 624) and 0 <= frame["support"].min() and frame["support"].max() == 1
    )
    assert frame["agreement"].max() <= 1 and (frame["agreement"][frame["coverage"] < 0.5] == 0).all()
    sequence = np.load(out / "sequence.npz")
    summed = sum(np.load(f)["raw"].astype(np.float64) for f in frames)
    np.testing.assert_allclose(sequence["raw"], summed, rtol=1e-5, atol=1e-4)
    assert "sigma_px: 5.0" in (out / "config.yaml").read_text()
    with pytest.raises(DataError, match="already exists"):
        run_maps(vineyard, "00", out, load_maps_config())


def test_an_interrupted_run_resumes_from_its_frames(vineyard, tmp_path):
    config = load_maps_config()
    first = run_maps(vineyard, "00", tmp_path / "maps", config)
    partial = tmp_path / "again.partial"
    first.rename(partial)  # as if interrupted after every frame was written
    (partial / "sequence.npz").unlink()
    marker = np.load(partial / "frames" / "000001.npz")
    np.savez(partial / "frames" / "000001.npz", **{k: marker[k] * 0 for k in marker.files})
    out = run_maps(vineyard, "00", tmp_path / "again", config, resume=True)
    # the stored (zeroed) frame was reused, not recomputed
    assert not np.load(out / "frames" / "000001.npz")["raw"].any()
    assert not partial.exists()
    with pytest.raises(DataError, match="another config"):
        (tmp_path / "x.partial").mkdir()
        (tmp_path / "x.partial" / "config.yaml").write_text("old")
        run_maps(vineyard, "00", tmp_path / "x", config, resume=True)


def test_the_shipped_flow_matcher_plugs_into_maps(vineyard, tmp_path):
    out = run_maps(vineyard, "00", tmp_path / "maps", load_maps_config(matcher="flow"))
    support = np.load(out / "sequence.npz")["support"]
    assert support.shape == (188, 624) and support.max() > 0


def test_an_unknown_matcher_is_a_clear_error(vineyard, tmp_path):
    with pytest.raises(SupportnetError, match="unknown matcher"):
        build_matcher("sift", EdgeMatcherConfig())
