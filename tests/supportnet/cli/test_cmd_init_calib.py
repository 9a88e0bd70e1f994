import json

import numpy as np
import pytest

from calib.errors import NumericalError
from calib.init.motion_init import load_stage1_config
from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config
from supportnet.cli.cmd_calibrate import parse_init
from supportnet.cli.cmd_init_calib import run_init_calib


def _vineyard(root, frames, start_before_turn_m):
    config = load_synth_config("vineyard", small=True, drive={"start_before_turn_m": start_before_turn_m})
    write_sequence(Synthesizer(config, frames, seed=2), root, "00")
    return root


def test_a_straight_row_is_refused_with_what_is_unobservable(tmp_path):
    data = _vineyard(tmp_path / "straight", 25, 30.0)  # 2.5 s down the middle of a row
    with pytest.raises(NumericalError, match="translation of T_cam_lidar is unobservable"):
        run_init_calib(data, "00", tmp_path / "out", load_stage1_config())
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_headland_turn_gives_an_initial_extrinsic_and_its_report(tmp_path):
    data = _vineyard(tmp_path / "turn", 120, 1.0)
    result = run_init_calib(data, "00", tmp_path / "out", load_stage1_config())
    assert result["error"]["rotation_deg"] < 1.0
    # the translation is the prior (zero by default), the hand-eye solve's own is reported beside it
    assert result["translation_source"] == "prior"
    assert np.allclose(np.array(result["T_cam_lidar"])[:3, 3], 0.0)
    assert result["hand_eye_error"]["rotation_deg"] == pytest.approx(result["error"]["rotation_deg"])
    # a ground robot turning on gentle terrain: the vertical offset is reported as weak
    assert any(w["kind"] == "translation" for w in result["weak"])
    out = tmp_path / "out"
    stored = json.loads((out / "result.json").read_text())
    assert np.allclose(stored["T_cam_lidar"], result["T_cam_lidar"])
    for name in ("lidar.kitti", "lidar.tum", "camera.kitti", "camera.tum", "trajectories.png", "config.yaml"):
        assert (out / name).is_file(), name
    assert len((out / "lidar.kitti").read_text().splitlines()) == 120
    assert len((out / "camera.tum").read_text().split("\n")[0].split()) == 8
    assert parse_init(f"file:{out / 'result.json'}")[0] == "file"
