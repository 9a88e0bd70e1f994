import json

import numpy as np
import pytest
from rich.console import Console

from calib.data import open_dataset
from calib.data.types import Sequence
from calib.errors import ConfigError, DataError
from calib.init.lidar_odometry import SequenceMotions
from calib.pipeline import Calibrator
from calib.refine.passes import CalibrateConfig, load_calibrate_config
from calib.results import CalibrationResult
from calib.support.support_maps import load_maps_config
from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config
from supportnet.cli.cmd_calibrate import parse_init, run_calibrate
from supportnet.cli.cmd_maps import run_maps
from supportnet.runtime.support_sources import parse_supports

STILL = {"wind": {"amplitude_m": 0.0}, "timing": {"camera_offset_s": 0.0}}
FAST = CalibrateConfig(frames=3, passes=2, sampling={"per_frame": 1500})


@pytest.fixture(scope="module")
def still_vineyard(tmp_path_factory):
    root = tmp_path_factory.mktemp("vineyard")
    write_sequence(Synthesizer(load_synth_config("vineyard", small=True, **STILL), 6, seed=5), root, "00")
    return root


def test_calibrate_undoes_a_perturbation_with_uniform_and_offline_support(still_vineyard, tmp_path):
    """EdgeMatcher residuals on 3 still frames take 10 cm / 2° to 0.3 cm / 0.09° (uniform) and
    1.6 cm / 0.23° (SGIS on maps of 6 frames); the assertion is the recovery, not the ranking."""
    maps = run_maps(still_vineyard, "00", tmp_path / "maps", load_maps_config())
    result = run_calibrate(
        still_vineyard, "00", f"uniform,offline:{maps}", "perturb:10,2", tmp_path / "cal", FAST, runs=1
    )
    for name, r in result["results"].items():
        for run in r["runs"]:
            assert run["initial_error"]["translation_cm"] == pytest.approx(10.0)
            assert run["error"]["translation_cm"] < 2.5 and run["error"]["rotation_deg"] < 0.4, name
    uniform, offline = result["results"].values()
    # paired: the same initial draws for both supports
    assert [r["initial_T_cam_lidar"] for r in uniform["runs"]] == [
        r["initial_T_cam_lidar"] for r in offline["runs"]
    ]
    assert result["paired_vs_uniform"][f"offline:{maps}"]["runs"] == 1
    stored = json.loads((tmp_path / "cal" / "result.json").read_text())
    for key in ("T_cam_lidar", "initial_T_cam_lidar", "reference_T_cam_lidar", "error", "initial_error"):
        assert key in stored
    assert stored["schema_version"] == 2 and stored["frames"] == 3 and len(stored["frame_indices"]) == 3
    assert isinstance(stored["weak_directions"], list)
    # a straight row at one speed cannot tell the time offset from a translation: held, and said so
    assert stored["time_offset_s"] == 0.0 and stored["time_offset_std_s"] is None
    assert stored["time_offset_note"].startswith("held at 0 s: the frames' motion varies too little")
    assert stored["time_offset_reference_s"] == pytest.approx(0.0, abs=1e-9)
    assert np.asarray(stored["covariance"]).shape == (6, 6)
    assert stored["support"] == "uniform" and stored["summary"]["translation_cm"]["mean"] < 2.5
    assert "| uniform |" in (tmp_path / "cal" / "summary.md").read_text()
    assert len(list((tmp_path / "cal").glob("overlay_*.png"))) == 2
    assert len(list((tmp_path / "cal").glob("support_*.png"))) == 1


def test_the_runs_calibrate_the_sequence_and_share_its_odometry(still_vineyard, tmp_path, monkeypatch):
    """The Calibrator gets the whole sequence (its own frame selection, and the scans around each
    used frame for the moving-point test), one SequenceMotions for every run and support, and
    the progress bar hears of each stage as it ends."""
    calls = []
    calibrate = Calibrator.calibrate

    def recording(self, seq, T_init, seed=0, motions=None, on_stage=None):
        calls.append((seq, motions))
        stages = []
        result = calibrate(
            self,
            seq,
            T_init,
            seed=seed,
            motions=motions,
            on_stage=lambda *a: stages.append(a) or on_stage(*a),
        )
        assert [stage for stage, _ in stages] == list(result.stage_seconds)  # the progress bar's
        return result

    monkeypatch.setattr(Calibrator, "calibrate", recording)
    config = FAST.model_copy(update={"passes": 1})
    result = run_calibrate(still_vineyard, "00", "uniform", "perturb:2,0.5", tmp_path / "cal", config, runs=2)
    assert len(calls) == 2
    assert all(isinstance(seq, Sequence) and len(seq) == 6 for seq, _ in calls)
    assert isinstance(calls[0][1], SequenceMotions) and calls[1][1] is calls[0][1]
    assert all(0 <= i < 6 for run in result["results"]["uniform"]["runs"] for i in run["frame_indices"])


def test_init_from_a_file(still_vineyard, tmp_path):
    with open_dataset(still_vineyard, sequence="00") as seq:
        T = seq.calibration.T_cam_lidar
    (tmp_path / "T.txt").write_text(" ".join(map(str, T.ravel())))
    kind, value = parse_init(f"file:{tmp_path / 'T.txt'}")
    assert kind == "file" and np.allclose(value, T)
    (tmp_path / "result.json").write_text(json.dumps({"T_cam_lidar": T[:3].tolist()}))
    assert np.allclose(parse_init(f"file:{tmp_path / 'result.json'}")[1], T)


def test_parse_errors_are_one_line(tmp_path):
    config = load_calibrate_config()
    for text in ("perturb:10", "perturb:1.2.3,2", "perturb:nan,1", "perturb:-1,2", "perturb:inf,2"):
        with pytest.raises(DataError, match="perturb takes CM,DEG"):
            parse_init(text)
    with pytest.raises(DataError, match="out of range"):
        parse_init("perturb:10,200")
    with pytest.raises(DataError, match=r"expected 12 \(3x4 \[R \| t\]\) or 16"):
        (tmp_path / "bad.txt").write_text("1 2 3")
        parse_init(f"file:{tmp_path / 'bad.txt'}")
    assert parse_init("stage1") == ("stage1", None)
    with pytest.raises(DataError, match="is not perturb:CM,DEG, file:PATH or stage1"):
        parse_init("stage1:x")
    with pytest.raises(DataError, match="supportnet maps"):
        parse_supports(f"offline:{tmp_path}", config.support_map)
    with pytest.raises(DataError, match="distinct"):
        parse_supports("uniform,uniform", config.support_map)
    with pytest.raises(DataError, match="not uniform"):
        parse_supports("uniformm", config.support_map)


def test_offline_maps_of_another_dataset_or_corrupt_are_refused(still_vineyard, tmp_path):
    other = tmp_path / "other"
    write_sequence(Synthesizer(load_synth_config("vineyard", small=True, **STILL), 3, seed=6), other, "00")
    maps = run_maps(other, "00", tmp_path / "maps_other", load_maps_config())
    with pytest.raises(DataError, match="another dataset"):
        run_calibrate(still_vineyard, "00", f"offline:{maps}", "perturb:10,2", tmp_path / "cal", FAST)
    assert not (tmp_path / "cal").exists()
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "sequence.npz").write_bytes(b"not a zip file")
    with pytest.raises(DataError, match="not a readable maps file"):
        parse_supports(f"offline:{broken}")


def test_the_answer_is_checked_and_a_wrong_one_is_flagged(still_vineyard, tmp_path, monkeypatch):
    """The converged answer checks good; an answer left 3° / 20 cm off (a calibrator that returns
    its start, as a run stuck in a wrong minimum would) is flagged on the console and in
    result.json; ``check=False`` leaves it out."""
    good = run_calibrate(still_vineyard, "00", "uniform", "perturb:10,2", tmp_path / "good", FAST)
    assert good["check"]["verdict"] == "good"
    assert (
        "Check of the answer (uniform, run 1; no ground truth): good"
        in (tmp_path / "good" / "summary.md").read_text()
    )

    def stuck(self, frames, T_init, **kwargs):
        T_init = np.asarray(T_init)
        return CalibrationResult(
            T_init, T_init, frames[0].calibration.T_cam_lidar, np.eye(6) * 1e-6, "uniform", [0, 1, 2], 0, 0.0
        )

    monkeypatch.setattr(Calibrator, "calibrate", stuck)
    console = Console(record=True, width=200)
    wrong = run_calibrate(
        still_vineyard, "00", "uniform", "perturb:20,3", tmp_path / "wrong", FAST, console=console
    )
    assert wrong["error"]["rotation_deg"] == pytest.approx(3.0)
    assert wrong["check"]["verdict"] == "bad"
    assert wrong["check"]["suggested_correction"]["rotation_deg"] > 1.0
    assert "This answer is likely wrong" in " ".join(console.export_text().split())  # wrapped at 200
    assert json.loads((tmp_path / "wrong" / "result.json").read_text())["check"]["verdict"] == "bad"
    unchecked = run_calibrate(
        still_vineyard, "00", "uniform", "perturb:20,3", tmp_path / "unchecked", FAST, check=False
    )
    assert unchecked["check"] is None


def test_a_good_check_on_frames_that_show_only_large_errors_says_it_cannot_confirm():
    """A check of data that shows errors only from 2° / 20 cm up (one nuScenes sweep) still says
    good, and the line adds that it cannot confirm the extrinsic more finely; data that shows
    0.72° / 10 cm (four KITTI frames) gets no such line, nor does a bad verdict."""
    from supportnet.cli.cmd_calibrate import _check_line

    def check(verdict: str, deg: float | None, cm: float | None) -> dict:
        return {
            "verdict": verdict,
            "suggested_correction": {"rotation_deg": 0.46, "translation_cm": 2.6},
            "significance": {"joint": 0.6},
            "peak_share": 0.0,
            "peak_shell_deg": 1.0,
            "detectable_error": {"rotation_deg": deg, "translation_cm": cm},
        }

    unconfirmed = "cannot confirm the extrinsic more finely"
    assert unconfirmed in _check_line(check("good", 2.0, 20.0), True)
    assert unconfirmed in _check_line(check("good", 0.72, 28.6), True)
    assert unconfirmed in _check_line(check("good", None, 10.0), True)
    assert unconfirmed not in _check_line(check("good", 0.72, 10.0), True)
    bad = _check_line(check("bad", 2.0, 20.0), True)
    assert "likely wrong" in bad and unconfirmed not in bad and "--init stage1" in bad
    after_stage1 = _check_line(check("bad", 2.0, 20.0), False)  # after Stage 1, or a rig's
    assert "likely wrong" in after_stage1 and "--init stage1" not in after_stage1


def test_a_rig_of_the_six_nuscenes_cameras_is_calibrated_together(realdata, tmp_path):
    """``--rig-camera``: the one nuScenes sweep (through the nuScenes reader) seen by its six
    cameras, from 25 cm / 5° off CAM_FRONT's reference (each camera as far off: the rig moves them
    together), ends within 10 cm / 0.6° of it (one camera alone ends 17-52 cm off, README), and
    result.json's rig gives every camera its own extrinsic, as near its own reference."""
    from calib.data.real_fixtures import NUSCENES_CAMERAS, nuscenes_from_mmdet
    from calib.geometry import calibration_error

    root = nuscenes_from_mmdet(realdata, tmp_path / "nuscenes")
    config = load_calibrate_config()
    out = run_calibrate(
        root, None, "uniform", "perturb:25,5", tmp_path / "cal", config, camera="CAM_FRONT",
        rig_camera=NUSCENES_CAMERAS[1:],
    )  # fmt: skip
    assert out["initial_error"]["translation_cm"] == pytest.approx(25.0)
    assert out["error"]["translation_cm"] < 10.0 and out["error"]["rotation_deg"] < 0.6
    assert [entry["camera"] for entry in out["rig"]] == list(NUSCENES_CAMERAS)
    for entry in out["rig"]:
        reference = open_dataset(root, camera=entry["camera"]).calibration.T_cam_lidar
        error = calibration_error(np.array(entry["T_cam_lidar"]), reference)
        assert error.translation_cm == pytest.approx(out["error"]["translation_cm"], abs=1e-6)
    summary = (tmp_path / "cal" / "summary.md").read_text()
    assert "A rig of 6 cameras" in summary and "the answer is CAM_FRONT's extrinsic" in summary
    assert "Check of the answer on the rig's 6 cameras" in summary
    assert "a rig's cameras" in out["time_offset_note"]
    assert len(list((tmp_path / "cal").glob("overlay_uniform*.png"))) == 6  # one per camera
    assert (tmp_path / "cal" / "overlay_uniform_5_CAM_FRONT_LEFT.png").is_file()
    with pytest.raises(ConfigError, match="--rig.*stage1 takes one camera"):
        run_calibrate(
            root,
            None,
            "uniform",
            "stage1",
            tmp_path / "s1",
            config,
            camera="CAM_FRONT",
            rig_camera=["CAM_BACK"],
        )


def test_a_rigs_cameras_need_as_many_frames(still_vineyard, realdata, tmp_path):
    from calib.data.real_fixtures import custom_from_nuscenes

    one = custom_from_nuscenes(realdata, "CAM_FRONT", tmp_path / "front")
    with pytest.raises(DataError, match="pair their frames by position and need as many"):
        run_calibrate(
            one,
            None,
            "uniform",
            "perturb:10,2",
            tmp_path / "cal",
            FAST,
            rig=[still_vineyard / "sequences" / "00"],
        )


def test_a_rig_uses_every_cameras_frame_of_enough_scans(still_vineyard, tmp_path):
    """A rig of one camera twice (the same dataset as --data and --rig): frames = 3 becomes two
    scans of both cameras, all four frames used, the perturbation undone as for one camera; the
    overlays of both cameras written."""
    sequence = still_vineyard / "sequences" / "00"
    out = run_calibrate(sequence, None, "uniform", "perturb:10,2", tmp_path / "cal", FAST, rig=[sequence])
    assert out["frames"] == 4 and out["config"]["frames"] == 4
    assert out["frame_indices"] == [0, 5]  # the scans' positions in --data, both cameras' frames of each
    assert out["error"]["translation_cm"] < 2.5 and out["error"]["rotation_deg"] < 0.4
    np.testing.assert_allclose(out["rig"][0]["T_cam_lidar"], out["rig"][1]["T_cam_lidar"], atol=1e-12)
    assert {p.name for p in (tmp_path / "cal").glob("overlay_*.png")} == {
        "overlay_uniform.png",
        "overlay_uniform_1_00.png",
    }
    # --rig-camera: the same camera named again in --data's own dataset, the same answer
    named = run_calibrate(
        sequence, None, "uniform", "perturb:10,2", tmp_path / "named", FAST, rig_camera=["2"]
    )
    np.testing.assert_allclose(named["T_cam_lidar"], out["T_cam_lidar"], atol=1e-12)
    assert [entry["camera"] for entry in named["rig"]] == [None, "2"]
    assert (tmp_path / "named" / "overlay_uniform_1_2.png").is_file()


@pytest.mark.parametrize(("mode", "expected_s"), [("fixed", 0.012), ("estimate", 0.037)])
def test_stage1_seeds_the_time_offset_only_where_it_is_estimated(
    still_vineyard, tmp_path, monkeypatch, mode, expected_s
):
    """`--init stage1 --time-offset fixed:12` holds 12 ms: Stage 1's 37 ms seeds only an
    estimated δt (it replaced the user's held value before)."""
    from types import SimpleNamespace

    import supportnet.cli.cmd_calibrate as cmd_calibrate

    with open_dataset(still_vineyard, sequence="00") as seq:
        T = seq.calibration.T_cam_lidar
    stage1 = SimpleNamespace(T_cam_lidar=T, time_offset_s=0.037, calibration=SimpleNamespace(weak=[]))
    monkeypatch.setattr(cmd_calibrate, "initial_calibration", lambda *a, **k: stage1)
    held = []

    def recording(self, seq, T_init, seed=0, motions=None, on_stage=None):
        held.append((self.config.time_offset.mode, self.config.time_offset.initial_s))
        raise KeyboardInterrupt  # what it was given is all this test asks

    monkeypatch.setattr(Calibrator, "calibrate", recording)
    timing = FAST.time_offset.model_copy(update={"mode": mode, "initial_s": 0.012})
    config = FAST.model_copy(update={"time_offset": timing})
    with pytest.raises(KeyboardInterrupt):
        run_calibrate(still_vineyard, "00", "uniform", "stage1", tmp_path / "cal", config, check=False)
    assert held == [(mode, expected_s)]
