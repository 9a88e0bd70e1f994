"""The CLI contract: `info` on every layout, one-line errors with exit code 2, no traceback."""

import os
import subprocess
import sys
import time

import pytest

from calib.data.custom import write_custom
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
    code = "import sys; import supportnet.cli; print('torch' in sys.modules)"
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
