"""Issue 19, defects 2, 3 and 7: every numeric option and config value is range-checked, and a bad
one ends in one line on stderr, exit code 2, no traceback, before any work (the real entry point)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from calib.errors import ConfigError
from supportnet.cli.cmd_synth import parse_drift, run_synth

SUPPORTNET = Path(sys.executable).parent / "supportnet"
TINY = """world: vineyard
camera: {width: 64, height: 24, fx: 37.0, fy: 37.0, cx: 31.5, cy: 11.5}
lidar: {beams: 8, azimuth_step_deg: 2.0}
"""


def run(*args, cwd):
    return subprocess.run(
        [str(SUPPORTNET), *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=dict(os.environ, COLUMNS="200"),
        timeout=300,
    )


def one_line_error(result, *fragments):
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("supportnet: error: "), result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


SYNTH = ["synth", "--world", "vineyard", "--out", "out", "--frames", "1"]
CALIBRATE = ["calibrate", "--data", "data", "--out", "out"]
RANGE_ERRORS = [
    (SYNTH + ["--seed", "-1"], ["--seed: must be an integer from 0 to 2^32 - 1", "got -1"]),
    (SYNTH + ["--seed", str(2**32)], ["--seed: must be an integer from 0 to 2^32 - 1", "got 4294967296"]),
    (SYNTH + ["--drift", "nan,1"], ["--drift: sizes must be 0 to 100 cm and 0 to 45°", "'nan,1'"]),
    (SYNTH + ["--workers", "0"], ["--workers: must be from 1 to 256, got 0"]),
    (
        ["synth", "--world", "urban", "--out", "out", "--frames", "0"],
        ["--frames: must be from 1 to 100000, got 0"],
    ),
    (CALIBRATE + ["--seed", "-1"], ["--seed: must be an integer from 0 to 2^32 - 1", "got -1"]),
    (CALIBRATE + ["--seed", str(2**32)], ["--seed: ", "got 4294967296"]),
    (CALIBRATE + ["--runs", "0"], ["--runs: must be from 1 to 1000, got 0"]),
    (["demo", "--frames", "0"], ["--frames: must be from 1 to 10000, got 0"]),
    (["demo", "--runs", "0"], ["--runs: must be from 1 to 1000, got 0"]),
    (
        ["maps", "--data", "data", "--out", "out", "--sigma", "inf"],
        ["--sigma: must be from 2 to 100, got inf"],
    ),
    (["maps", "--data", "data", "--out", "out", "--sigma", "nan"], ["--sigma: ", "got nan"]),
    (["analyze", "--data", "data", "--out", "out", "--stride", "0"], ["--stride: must be from 1 to 100000"]),
]


@pytest.mark.parametrize(("args", "fragments"), RANGE_ERRORS, ids=[" ".join(a[0][-2:]) for a in RANGE_ERRORS])
def test_out_of_range_options_end_in_one_line(tmp_path, args, fragments):
    one_line_error(run(*args, cwd=tmp_path), *fragments)
    assert not list(tmp_path.iterdir())  # refused before any work


def test_export_names_the_opsets_torch_supports(tmp_path):
    (tmp_path / "model.ckpt").write_bytes(b"not read")
    result = run("export", "--ckpt", "model.ckpt", "--out", "model.onnx", "--opset", "99", cwd=tmp_path)
    one_line_error(result, "--opset: must be from 17 to 20", "got 99")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.ckpt"]


@pytest.mark.parametrize(
    ("text", "fragments"),
    [
        (b"support:\n  sigma_px: .inf\n", ["maps.yaml: support.sigma_px: Input should be a finite number"]),
        (b"matcher: edge\n# caf\xe9\n", ["maps.yaml: not UTF-8 text"]),
    ],
    ids=["inf", "latin-1"],
)
def test_a_bad_config_file_ends_in_one_line(tmp_path, text, fragments):
    (tmp_path / "maps.yaml").write_bytes(text)
    result = run("maps", "--data", "data", "--out", "out", "--config", "maps.yaml", cwd=tmp_path)
    one_line_error(result, *fragments)


def test_seed_256_makes_a_world(tmp_path):
    """It crashed with an OverflowError (``seed + index`` with a uint8 material index); 2³² − 1 is
    tested in-process (tests/calib/synth/test_seeded_textures.py)."""
    seed = 256
    (tmp_path / "tiny.yaml").write_text(TINY)
    result = run(*SYNTH, "--seed", seed, "--config", "tiny.yaml", "--workers", "1", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    assert json.loads((tmp_path / "out" / "sequences" / "00" / "meta.json").read_text())["seed"] == seed


# In-process (each entry-point run above starts torch): the rest of what the synth command refuses


@pytest.mark.parametrize("text", ["nan,1", "1,inf", "-1,0", "1e9,1", "5,46", "1", "a,b"])
def test_parse_drift_refuses_what_is_not_a_drift(text):
    with pytest.raises(ConfigError) as info:
        parse_drift(text)
    assert str(info.value).startswith("--drift: ") and "\n" not in str(info.value)


def test_parse_drift_takes_sizes_up_to_the_bound():
    assert parse_drift("0,0") == (0.0, 0.0) and parse_drift("100,45") == (100.0, 45.0)
    assert parse_drift(None) == (0.0, 0.0)


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        ({"frames": 0}, "--frames: must be from 1 to 100000, got 0"),
        ({"frames": 100_001}, "--frames: must be from 1 to 100000, got 100001"),
        ({"seed": -1}, "--seed: must be an integer from 0 to 2^32 - 1 = 4294967295, got -1"),
        ({"seed": 2**32}, "--seed: must be an integer from 0 to 2^32 - 1 = 4294967295, got 4294967296"),
        ({"workers": 0}, "--workers: must be from 1 to 256, got 0"),
        ({"camera_offset_ms": 2000.0}, "--camera-offset-ms: must be from -1000 to 1000, got 2000.0"),
    ],
)
def test_run_synth_refuses_before_any_work(tmp_path, arguments, message):
    with pytest.raises(ConfigError) as info:
        run_synth(**{"world": "urban", "frames": 1, "seed": 0, "out": tmp_path / "out", **arguments})
    assert str(info.value) == message
    assert not (tmp_path / "out").exists()


def test_time_offset_option_parses_its_three_forms_and_refuses_others():
    from calib.refine.passes import TimeOffsetConfig
    from supportnet.cli.options import time_offset_setting

    base = TimeOffsetConfig()
    assert time_offset_setting("estimate", base).mode == "estimate"
    fixed = time_offset_setting("fixed:-20", base)
    assert (fixed.mode, fixed.initial_s) == ("fixed", -0.02)
    for bad in ("fixed:nan", "fixed:2000", "fixed:", "sometimes"):
        with pytest.raises(ConfigError, match="--time-offset"):
            time_offset_setting(bad, base)


def test_time_offset_option_on_the_command_line_is_refused_with_one_line(tmp_path):
    done = run(
        "calibrate", "--data", tmp_path, "--out", tmp_path / "o", "--time-offset", "sometimes", cwd=tmp_path
    )
    assert done.returncode == 2 and "--time-offset" in done.stderr and "Traceback" not in done.stderr


def test_synth_writes_the_camera_offset_and_motion_distortion_it_is_given(tmp_path):
    seq = run_synth(
        "vineyard",
        3,
        0,
        tmp_path,
        small=True,
        workers=1,
        camera_offset_ms=-12.5,
        motion_distortion=True,
        clock_drift_ms=10.0,
    )
    meta = json.loads((seq / "meta.json").read_text())
    assert meta["camera_offset_s"] == -0.0125 and meta["timing"]["motion_distortion"] is True
    assert meta["camera_offsets_s"] == pytest.approx([-0.0125, -0.0075, -0.0025])  # the clock drifts 10 ms
    assert len(list((seq / "point_times").glob("*.bin"))) == 3
