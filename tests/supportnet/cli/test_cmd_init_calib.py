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
    # a ground robot turning on gentle terrain: the vertical offset is reported as weak, and the
    # degeneracy tests find the rotation determined all the same (their numbers are in the report)
    assert any(w["kind"] == "translation" for w in result["weak"])
    assert result["degeneracy"]["determined"] and result["degeneracy"]["axis_spread"] < 0.05
    out = tmp_path / "out"
    stored = json.loads((out / "result.json").read_text())
    assert np.allclose(stored["T_cam_lidar"], result["T_cam_lidar"])
    for name in ("lidar.kitti", "lidar.tum", "camera.kitti", "camera.tum", "trajectories.png", "config.yaml"):
        assert (out / name).is_file(), name
    assert len((out / "lidar.kitti").read_text().splitlines()) == 120
    assert len((out / "camera.tum").read_text().split("\n")[0].split()) == 8
    assert parse_init(f"file:{out / 'result.json'}")[0] == "file"


def test_a_refusal_from_the_degeneracy_tests_is_one_line_and_leaves_nothing(tmp_path, monkeypatch, capsys):
    """What `supportnet init-calib` prints when Stage 1 refuses a rotation the motion left free (the
    refusal itself is tested in tests/calib/init): one line naming the test, exit code 2."""
    from calib.data.kitti_odometry import write_kitti_odometry
    from calib.init.degeneracy import check_motion, diagnose
    from calib.init.hand_eye import HandEyeConfig, hand_eye
    from supportnet.cli import cmd_init_calib
    from tests.calib.init.test_degeneracy import _arc
    from tests.calib.init.test_hand_eye import _extrinsic, _motions, _unit
    from tests.conftest import make_frames
    from tests.supportnet.cli.test_output_dir import cli, one_line

    A, B = _motions(_arc(12, 3.0, np.random.default_rng(1)), _extrinsic())
    diagnostics = diagnose(_unit(A), B, hand_eye(_unit(A), B, HandEyeConfig()), HandEyeConfig())

    def refuse(seq, *args, **kwargs):
        check_motion(diagnostics, load_stage1_config().degeneracy, seq.name)

    monkeypatch.setattr(cmd_init_calib, "initial_calibration", refuse)
    write_kitti_odometry(tmp_path / "data", "00", make_frames(3))
    code, err = cli(
        capsys, "init-calib", "--data", tmp_path / "data", "--sequence", "00", "--out", tmp_path / "out"
    )
    line = one_line(err)
    assert code == 2 and line.startswith("supportnet: error: ") and "Stage 1 refuses the rotation" in line
    assert "rotation about LiDAR +z undetermined: std unbounded > 1.3° (max_rotation_std_deg" in line
    assert not (tmp_path / "out").exists()
