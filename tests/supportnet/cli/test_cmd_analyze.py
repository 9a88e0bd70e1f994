import csv
import json

import numpy as np
import pytest

from calib.errors import DataError
from calib.support.support_maps import load_maps_config
from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config
from supportnet.cli.cmd_analyze import run_analyze
from supportnet.cli.cmd_maps import run_maps


@pytest.fixture(scope="module")
def vineyard(tmp_path_factory):
    """The default vineyard: the camera fires 20 ms after the LiDAR while the robot drives at
    1.2 m/s, so under the reference the near rows (leaves, posts, trunks at 2–3 m) appear a
    couple of pixels off and far buildings much less (parallax ∝ 1 / depth)."""
    root = tmp_path_factory.mktemp("vineyard")
    write_sequence(Synthesizer(load_synth_config("vineyard", small=True), 4, seed=4), root, "00")
    return root


def test_analyze_ranks_classes_and_writes_csv_json_and_charts(vineyard, tmp_path):
    maps = run_maps(vineyard, "00", tmp_path / "maps", load_maps_config())
    result = run_analyze(vineyard, ["00"], tmp_path / "report", load_maps_config(), maps=maps)
    by_name = {row["name"]: row for row in result["classes"]["all"]}
    assert by_name["vegetation"]["median_norm"] > 1.5 * by_name["building"]["median_norm"]
    assert by_name["vegetation"]["median_depth_m"] < by_name["building"]["median_depth_m"]
    assert result["ranking_by_median_norm"].index("building") < result["ranking_by_median_norm"].index(
        "vegetation"
    )
    assert all(0 <= row["mean_support"] <= 1 for row in result["classes"]["all"])
    report = tmp_path / "report"
    assert json.loads((report / "classes.json").read_text())["frames"] == 4
    rows = list(csv.DictReader(open(report / "classes.csv")))
    assert {r["sequence"] for r in rows} == {"all", "00"} and len(rows) == 2 * len(result["classes"]["00"])
    assert (report / "residuals_by_class.png").stat().st_size > 10_000
    assert (report / "config.yaml").is_file()
    with pytest.raises(DataError, match="already exists"):
        run_analyze(vineyard, ["00"], report, load_maps_config())


def test_analyze_by_excess_green_when_asked(vineyard, tmp_path):
    result = run_analyze(vineyard, None, tmp_path / "r", load_maps_config(), classes="exg", stride=2)
    assert result["frames"] == 2 and result["class_source"] == {"00": "exg"}
    assert {row["name"] for row in result["classes"]["all"]} == {"foliage", "background"}


def test_analyze_errors_are_clear(vineyard, tmp_path):
    with pytest.raises(DataError, match="no support maps for sequence 00"):
        run_analyze(vineyard, ["00"], tmp_path / "r", load_maps_config(), maps=tmp_path)
    with pytest.raises(DataError, match="--stride"):
        run_analyze(vineyard, ["00"], tmp_path / "r", load_maps_config(), stride=0)
    assert not (tmp_path / "r").exists()
    np.testing.assert_equal(sorted(p.name for p in tmp_path.iterdir()), [])
