"""Output that goes to a log file or a pipe is not cut at rich's default of 80 columns."""

import os
import subprocess
import sys

from calib.data.kitti_odometry import write_kitti_odometry
from supportnet.cli.console import LOG_WIDTH, make_console
from tests.conftest import make_frames


def test_a_table_row_is_not_cut_when_stdout_is_a_pipe(tmp_path):
    data = tmp_path / ("a_long_dataset_folder_name_" * 2)
    write_kitti_odometry(data, "03", make_frames(2))
    env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}
    result = subprocess.run(
        [sys.executable, "-m", "supportnet", "info", str(data)],
        capture_output=True,  # stdout is a pipe: no terminal says how wide to be
        text=True,
        env=env,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    (row,) = [line for line in result.stdout.splitlines() if line.startswith("data")]
    assert len(row.rstrip()) > 80
    assert str(data) in row and row.rstrip().endswith("(layout: kitti_odometry)"), row


def test_width_follows_columns_or_a_wide_default(monkeypatch):
    monkeypatch.delenv("COLUMNS", raising=False)
    assert make_console().width == LOG_WIDTH  # pytest captures stderr: not a terminal
    monkeypatch.setenv("COLUMNS", "123")
    assert make_console().width == 123
