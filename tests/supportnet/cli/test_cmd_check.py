"""``supportnet check`` through the installed console script: exit code 0 for the reference of a
small synthetic world, 1 (with every output written) for the same 2° off, 2 with one line for
bad input; strict ``check.json``; refuses to overwrite; reads a ``result.json`` too."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from calib.data import open_dataset
from calib.geometry import perturb
from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config

SUPPORTNET = Path(sys.executable).parent / "supportnet"
STILL = {"wind": {"amplitude_m": 0.0}, "timing": {"camera_offset_s": 0.0}}


def run_cli(*args):
    env = dict(os.environ, COLUMNS="200")
    return subprocess.run(
        [str(SUPPORTNET), "check", *map(str, args)], capture_output=True, text=True, env=env, timeout=300
    )


def strict_json(path: Path) -> dict:
    def refuse(constant: str) -> None:
        raise ValueError(f"not strict JSON: {constant}")

    return json.loads(path.read_text(), parse_constant=refuse)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("urban")
    write_sequence(Synthesizer(load_synth_config("urban", small=True, **STILL), 2, seed=5), root, "00")
    with open_dataset(root, sequence="00") as seq:
        T = seq.calibration.T_cam_lidar
    files = tmp_path_factory.mktemp("extrinsics")
    np.savetxt(files / "reference.txt", T)  # 16 numbers
    off = perturb(T, 5.0, 2.0, torch.Generator().manual_seed(1))
    np.savetxt(files / "off.txt", off[:3])  # 12 numbers
    (files / "result.json").write_text(json.dumps({"T_cam_lidar": off.tolist()}))
    (files / "short.txt").write_text("1 0 0 0 0 1 0")
    return root, files


def test_reference_exits_0_with_its_outputs(world, tmp_path):
    data, files = world
    result = run_cli(
        "--data", data, "--sequence", "00", "--extrinsic", files / "reference.txt", "--out", tmp_path / "o"
    )
    assert result.returncode == 0, result.stderr
    out = tmp_path / "o"
    stored = strict_json(out / "check.json")
    assert stored["verdict"] == "good" and stored["exit_code"] == 0 and stored["schema_version"] == 1
    assert stored["frame_indices"] == [0, 1] and len(stored["frames"]) == 2
    assert {"rotation_deg", "translation_cm"} <= set(stored["detectable_error"])
    for name in ("check.md", "overlay.png", "config.yaml"):
        assert (out / name).is_file(), name
    assert "# supportnet check: good" in (out / "check.md").read_text()
    assert "good:" in result.stderr


def test_two_degrees_off_exits_1_after_writing_everything(world, tmp_path):
    data, files = world
    for name in ("off.txt", "result.json"):
        out = tmp_path / name
        result = run_cli("--data", data, "--sequence", "00", "--extrinsic", files / name, "--out", out)
        assert result.returncode == 1, result.stderr
        stored = strict_json(out / "check.json")
        assert stored["verdict"] == "bad" and stored["exit_code"] == 1
        assert stored["suggested_correction"]["rotation_deg"] > 1.0
        assert stored["reference"]["suggested_error"]["rotation_deg"] < 0.7
        assert (out / "overlay.png").is_file() and (out / "check.md").is_file()


def test_an_extrinsic_that_sees_nothing_is_a_miscalibration_exit_1(world, tmp_path):
    """The identity (a URDF's default) or a translation in millimetres puts no point into the
    image: `bad` with exit code 1 and check.json saying why, not bad input."""
    data, files = world
    T = np.loadtxt(files / "reference.txt")
    T[:3, 3] *= 1000.0
    np.savetxt(tmp_path / "mm.txt", T)
    np.savetxt(tmp_path / "identity.txt", np.eye(4))
    for name, says in (("identity.txt", "puts 0.00%"), ("mm.txt", "m long: given in millimetres?")):
        out = tmp_path / f"out_{name}"
        result = run_cli("--data", data, "--sequence", "00", "--extrinsic", tmp_path / name, "--out", out)
        assert result.returncode == 1, result.stderr
        stored = strict_json(out / "check.json")
        assert stored["verdict"] == "bad" and stored["exit_code"] == 1 and says in stored["reasons"][0]
        assert "bad: the extrinsic puts" in result.stderr and "Traceback" not in result.stderr
        assert (out / "check.md").read_text().startswith("# supportnet check: bad")
        assert not (out / "overlay.png").exists()


def test_bad_input_is_one_line_and_exit_2(world, tmp_path):
    data, files = world
    result = run_cli(
        "--data", data, "--sequence", "00", "--extrinsic", files / "short.txt", "--out", tmp_path / "o"
    )
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "short.txt" in lines[0] and "holds 7 numbers" in lines[0]
    assert "Traceback" not in result.stderr and not (tmp_path / "o").exists()
    missing = run_cli(
        "--data", tmp_path / "nothing", "--extrinsic", files / "reference.txt", "--out", tmp_path / "o"
    )
    assert missing.returncode == 2 and len(missing.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
    frames = run_cli(
        "--data", data, "--extrinsic", files / "reference.txt", "--out", tmp_path / "o", "--frames", "0"
    )
    assert frames.returncode == 2 and "--frames" in frames.stderr


def test_refuses_to_overwrite_without_the_flag(world, tmp_path):
    data, files = world
    out = tmp_path / "o"
    out.mkdir()
    (out / "mine.txt").write_text("not supportnet's")
    args = ("--data", data, "--sequence", "00", "--extrinsic", files / "reference.txt", "--out", out)
    result = run_cli(*args)
    assert result.returncode == 2 and (out / "mine.txt").is_file()
    assert run_cli(*args, "--overwrite").returncode == 2  # not supportnet's: never replaced
    (out / "mine.txt").unlink()
    out.rmdir()
    assert run_cli(*args).returncode == 0
    assert run_cli(*args).returncode == 2  # exists now
    assert run_cli(*args, "--overwrite").returncode == 0


def test_a_result_calibrated_on_other_data_is_noted(world, tmp_path):
    """A ``result.json`` of ``calibrate`` on another dataset or sequence gets a note naming both;
    one of the same data, none."""
    from rich.console import Console

    from supportnet.cli.cmd_check import run_check

    data, _ = world
    with open_dataset(data, sequence="00") as seq:
        T = seq.calibration.T_cam_lidar
    for name, written, noted in (
        ("same", {"data": str(data), "sequence": "00", "camera": None}, False),
        ("other", {"data": str(tmp_path / "elsewhere"), "sequence": "00", "camera": None}, True),
        ("sequence", {"data": str(data), "sequence": "07", "camera": None}, True),
    ):
        (tmp_path / f"{name}.json").write_text(json.dumps({"T_cam_lidar": T.tolist(), **written}))
        console = Console(record=True, width=300)
        run_check(data, "00", tmp_path / f"{name}.json", tmp_path / f"out_{name}", console=console)
        text = console.export_text()
        assert ("was calibrated on" in text) == noted, name
        if noted:
            assert f"this check reads `{data.resolve()}` sequence 00" in text


@pytest.mark.realdata
def test_a_verdict_not_good_on_weak_data_says_a_right_extrinsic_can_read_so_too():
    """Data that shows errors only from 1.85° / 19.9 cm (nuScenes' back camera alone) cannot tell
    a right extrinsic from a 1° one; a bad or suspect verdict there says so, a good one or one on
    data that shows 0.5° / 10 cm does not (that is check_line's own note)."""
    from supportnet.cli.cmd_check import weak_data_note

    def check(verdict: str, deg: float | None, cm: float | None) -> dict:
        return {"verdict": verdict, "detectable_error": {"rotation_deg": deg, "translation_cm": cm}}

    assert "--rig-camera" in weak_data_note(check("bad", 1.85, 19.9))
    assert weak_data_note(check("suspect", 0.5, 30.0)) is not None
    assert weak_data_note(check("suspect", None, 10.0)) is not None
    assert weak_data_note(check("bad", 0.5, 10.0)) is None
    assert weak_data_note(check("good", 1.85, 19.9)) is None


def test_check_a_rig_of_the_six_nuscenes_cameras(realdata, tmp_path):
    """``--rig``: CAM_FRONT's reference checked with the five other cameras of the sweep is good
    (alone, the front camera's is not: README), and check.json names the rig's datasets; the same
    with the sweep read through the nuScenes reader and ``--rig-camera`` naming its channels."""
    from calib.data.real_fixtures import NUSCENES_CAMERAS, custom_from_nuscenes, nuscenes_from_mmdet
    from supportnet.cli.cmd_check import run_check

    folders = [custom_from_nuscenes(realdata, c, tmp_path / c) for c in NUSCENES_CAMERAS]
    np.savetxt(tmp_path / "front.txt", open_dataset(folders[0]).calibration.T_cam_lidar)
    out = run_check(folders[0], None, tmp_path / "front.txt", tmp_path / "chk", rig=folders[1:])
    assert out["verdict"] == "good" and out["exit_code"] == 0
    assert [entry["data"] for entry in out["rig"]] == [str(f) for f in folders[1:]] and len(
        out["frames"]
    ) == 6
    assert "its rig's 5 other camera(s)" in (tmp_path / "chk" / "check.md").read_text()

    devkit = nuscenes_from_mmdet(realdata, tmp_path / "nuscenes")
    np.savetxt(tmp_path / "static.txt", open_dataset(devkit, camera="CAM_FRONT").calibration.T_cam_lidar)
    out = run_check(
        devkit,
        None,
        tmp_path / "static.txt",
        tmp_path / "dev",
        camera="CAM_FRONT",
        rig_camera=NUSCENES_CAMERAS[1:],
    )
    assert out["verdict"] == "good" and len(out["frames"]) == 6
    assert out["rig"] == [{"data": str(devkit), "camera": c} for c in NUSCENES_CAMERAS[1:]]
