"""Issue 19, defect 7: a config that is not UTF-8 text, or holds ``.inf``/``.nan``, ends in one
ConfigError line naming the file and the key, not a traceback."""

import pytest

from calib.errors import ConfigError, DataError
from calib.init.motion_init import load_stage1_config
from calib.refine.passes import load_calibrate_config
from calib.support.support_maps import load_maps_config
from calib.synth.synth_config import load_synth_config
from calib.yaml_io import read_yaml


def refused(path, *fragments) -> str:
    """The one-line message of the ConfigError raised while reading ``path``."""
    message = str(pytest.raises(ConfigError, read_yaml, path).value)
    assert "\n" not in message and message.startswith(f"{path}: ")
    for fragment in fragments:
        assert fragment in message, message
    return message


@pytest.mark.parametrize(
    "raw",
    [
        b"matcher: edge\n# caf\xe9 (Latin-1)\n",
        b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00",
        b"\xff\xfes\x00i\x00",  # UTF-16
        b"a: 1\n\x00\x00\x00\x00",  # valid UTF-8, but binary
    ],
    ids=["latin-1", "png", "utf-16", "nul"],
)
def test_a_file_that_is_not_utf8_text_is_refused_in_one_line(tmp_path, raw):
    path = tmp_path / "config.yaml"
    path.write_bytes(raw)
    refused(path, "not UTF-8 text")


def test_a_byte_order_mark_is_fine(tmp_path):
    path = tmp_path / "config.yaml"
    path.write_bytes(b"\xef\xbb\xbfmatcher: edge\n")
    assert read_yaml(path) == {"matcher": "edge"}


def test_missing_unparsable_and_non_mapping_files_are_config_errors(tmp_path):
    refused(tmp_path / "absent.yaml", "file not found")
    refused(tmp_path, "is a folder, not a YAML file")
    (tmp_path / "bad.yaml").write_text("a: [1, 2\n")
    refused(tmp_path / "bad.yaml", "not valid YAML")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    refused(tmp_path / "list.yaml", "expected a mapping")
    assert issubclass(ConfigError, DataError)  # callers catching DataError still catch these


@pytest.mark.parametrize(
    ("load", "text", "key"),
    [
        (
            load_maps_config,
            "support:\n  sigma_px: .inf\n",
            "support.sigma_px: Input should be a finite number (got inf)",
        ),
        (
            load_maps_config,
            "support:\n  sigma_px: .nan\n",
            "support.sigma_px: Input should be a finite number (got nan)",
        ),
        (
            load_maps_config,
            "support:\n  sigma_px: 1000\n",
            "support.sigma_px: Input should be less than or equal to 100",
        ),
        (load_maps_config, "edge:\n  depth_edge_px: [0.2, 0.04]\n", "the full edge must exceed the start"),
        (
            load_calibrate_config,
            "refine:\n  loss_scale_px: -.inf\n",
            "refine.loss_scale_px: Input should be a finite",
        ),
        (
            load_calibrate_config,
            "online:\n  initial_std: [.inf, 1]\n",
            "online.initial_std.0: Input should be a finite",
        ),
        (
            load_calibrate_config,
            "online:\n  process_std: [1, -1]\n",
            "online.process_std.1: Input should be greater",
        ),
        (
            load_stage1_config,
            "translation_prior_m: [0, .nan, 0]\n",
            "translation_prior_m.1: Input should be a finite",
        ),
        (
            load_stage1_config,
            "hand_eye:\n  loss_scale: .inf\n",
            "hand_eye.loss_scale: Input should be a finite",
        ),
    ],
)
def test_non_finite_and_out_of_range_values_name_their_key(tmp_path, load, text, key):
    path = tmp_path / "config.yaml"
    path.write_text(text)
    message = str(pytest.raises(ConfigError, load, path).value)
    assert message.startswith(f"{path}: ") and key in message and "\n" not in message


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("world: urban\ntiming:\n  rate_hz: .inf\n", "timing.rate_hz: Input should be a finite number"),
        (
            "world: urban\nlidar:\n  azimuth_step_deg: 1.0e-9\n",
            "lidar.azimuth_step_deg: Input should be greater",
        ),
        (
            "world: urban\nurban:\n  moving_speed_mps: [6, -1]\n",
            "urban.moving_speed_mps.1: Input should be greater",
        ),
        (
            "world: urban\nextrinsic:\n  camera_position_m: [0, 0, .nan]\n",
            "camera_position_m.2: Input should be a",
        ),
        ("world: vineyard\n", "describes world 'vineyard', not 'urban'"),
    ],
)
def test_synth_configs_are_range_checked(tmp_path, text, key):
    path = tmp_path / "urban.yaml"
    path.write_text(text)
    message = str(pytest.raises(ConfigError, load_synth_config, "urban", path).value)
    assert key in message and "\n" not in message
