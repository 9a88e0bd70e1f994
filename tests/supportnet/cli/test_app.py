"""The CLI contract: `info` on every layout, one-line errors with exit code 2, no traceback."""

import os
import subprocess
import sys
import time

import pytest

from calib.data.custom import write_custom
from calib.data.io import read_image
from calib.data.kitti_odometry import write_kitti_odometry
from tests.conftest import make_frames


def run_cli(*args, cwd=None):
    env = dict(os.environ, COLUMNS="200")
    return subprocess.run(
        [sys.executable, "-m", "supportnet", *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
        timeout=120,
    )


def test_help_is_fast_and_lists_commands():
    start = time.perf_counter()
    result = run_cli("--help")
    assert result.returncode == 0
    assert "info" in result.stdout and "demo" in result.stdout
    assert time.perf_counter() - start < 10  # lazy imports; generous bound for a loaded CI box


def test_help_does_not_import_torch():
    code = "import sys; import supportnet.cli.app; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.stdout.strip() == "False"


def test_info_on_kitti_odometry(tmp_path):
    write_kitti_odometry(tmp_path, "03", make_frames())
    result = run_cli("info", tmp_path)
    assert result.returncode == 0, result.stderr
    for expected in (
        "(layout: kitti_odometry)",
        "frames",
        "624 x 188",
        "fx 360.000",
        "T_cam_lidar",
        "0.200 s",
        "10 car",
        "70 vegetation",
        "image labels  yes",
        "no problems found",
    ):
        assert expected in result.stdout, expected


def test_info_lists_problems_then_exits_2(tmp_path):
    write_custom(tmp_path, make_frames())
    (tmp_path / "lidar" / "000001.bin").write_bytes(b"")
    (tmp_path / "lidar" / "000002.bin").unlink()
    result = run_cli("info", tmp_path)
    assert result.returncode == 2
    assert "2 problem(s)" in result.stdout and "empty scan file" in result.stdout
    assert "3 images but" in result.stderr and len(result.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("case", ["missing", "layout", "corrupt_png", "bad_calib"])
def test_user_mistakes_give_one_line_and_exit_2(tmp_path, case):
    data = tmp_path / "data"
    if case != "missing":
        data.mkdir()
    if case in ("corrupt_png", "bad_calib"):
        write_custom(data, make_frames())
    if case == "corrupt_png":
        (data / "camera" / "000000.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    if case == "bad_calib":
        (data / "calibration.yaml").write_text("K: [[1, 2], [3]]\nfx: 3\n")
    result = run_cli("info", data)
    assert result.returncode == 2, result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert str(data) in lines[0] and "Traceback" not in result.stderr


def test_demo_refuses_to_overwrite(tmp_path):
    (tmp_path / "out").mkdir()
    result = run_cli("demo", "--out", tmp_path / "out")
    assert result.returncode == 2
    assert "already exists; pass --overwrite" in result.stderr


def test_synth_writes_a_sequence_info_reads_and_refuses_to_overwrite(tmp_path):
    config = tmp_path / "tiny.yaml"
    config.write_text(
        "world: urban\ncamera: {width: 160, height: 48, fx: 92.5, fy: 92.5, cx: 78.0, cy: 22.0}\n"
        "lidar: {beams: 16, azimuth_step_deg: 1.0}\n"
    )
    args = (
        "synth",
        "--world",
        "urban",
        "--frames",
        "2",
        "--seed",
        "3",
        "--out",
        tmp_path / "data",
        "--sequence",
        "07",
        "--config",
        config,
    )
    result = run_cli(*args)
    assert result.returncode == 0, result.stderr
    seq = tmp_path / "data" / "sequences" / "07"
    names = {p.name for p in seq.iterdir()}
    assert {"calib.txt", "times.txt", "meta.json", "classes.json", "config.yaml"} <= names
    assert len(list((seq / "image_labels").iterdir())) == 2
    assert (tmp_path / "data" / "poses" / "07.txt").is_file()
    info = run_cli("info", tmp_path / "data", "--sequence", "07")
    assert info.returncode == 0 and "road" in info.stdout, info.stdout
    again = run_cli(*args)
    assert again.returncode == 2 and "already exists" in again.stderr and "Traceback" not in again.stderr
    assert [p.name for p in (tmp_path / "data").iterdir() if p.name.startswith(".")] == []


def test_synth_small_writes_the_small_camera(tmp_path):
    out = tmp_path / "data"
    result = run_cli(
        "synth", "--world", "vineyard", "--frames", "1", "--out", out, "--small", "--workers", "1"
    )
    assert result.returncode == 0, result.stderr
    seq = out / "sequences" / "00"
    assert read_image(seq / "image_2" / "000000.png").shape == (188, 624, 3)
    assert "width: 624" in (seq / "config.yaml").read_text()


def test_synth_config_typo_is_one_line_error(tmp_path):
    config = tmp_path / "typo.yaml"
    config.write_text("world: vineyard\ntiming: {camera_ofset_s: 0.1}\n")
    out = tmp_path / "d"
    result = run_cli("synth", "--world", "vineyard", "--frames", "1", "--out", out, "--config", config)
    assert result.returncode == 2
    assert "timing.camera_ofset_s" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "d" / "sequences").exists()


@pytest.mark.parametrize(
    "command",
    [
        ["info"],
        ["maps", "--out", "{out}"],
        ["predict", "--out", "{out}"],
        ["analyze", "--out", "{out}"],
        ["init-calib", "--out", "{out}"],
        ["calibrate", "--out", "{out}"],
        ["calibrate", "--online", "--out", "{out}"],
    ],
)
def test_every_command_that_opens_a_dataset_takes_camera(tmp_path, command):
    """Issue 19, defect 10: `--camera` reaches the reader everywhere (an absent one is refused
    with the list of cameras present, before anything is written)."""
    write_kitti_odometry(tmp_path / "data", "00", make_frames())
    args = [a.replace("{out}", str(tmp_path / "out")) for a in command]
    data = [tmp_path / "data"] if command == ["info"] else ["--data", tmp_path / "data"]
    result = run_cli(*args[:1], *data, *args[1:], "--camera", "5")
    assert result.returncode == 2, result.stderr
    assert "no camera 5 (image_5 not found); available cameras: 2" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("extra", [["--online"], ["--time-offset", "estimate"]])
def test_a_rig_refuses_what_takes_one_camera_in_one_line(tmp_path, extra):
    write_custom(tmp_path / "a", make_frames())
    write_custom(tmp_path / "b", make_frames())
    result = run_cli(
        "calibrate", "--data", tmp_path / "a", "--rig", tmp_path / "b", "--out", tmp_path / "o", *extra
    )
    assert result.returncode == 2 and "--rig" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and not (tmp_path / "o").exists()
