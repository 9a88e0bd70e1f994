"""The README's library example runs as written, on a synthetic world with a known extrinsic."""

import re
from pathlib import Path

import numpy as np
import pytest

import supportnet
from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config

README = Path(__file__).resolve().parents[2] / "README.md"


def readme_example() -> str:
    pattern = r"<!-- api:start -->\s*```python\n(.*?)```\s*<!-- api:end -->"
    match = re.search(pattern, README.read_text(), re.S)
    assert match, "README.md has no library example between <!-- api:start --> and <!-- api:end -->"
    return match.group(1)


@pytest.fixture(scope="module")
def synth_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("api")
    write_sequence(
        Synthesizer(load_synth_config("urban", small=True), 11, seed=3), root / "data" / "synth", "01"
    )
    return root


def test_the_readme_library_example_runs(synth_dataset, monkeypatch):
    monkeypatch.chdir(synth_dataset)
    namespace: dict = {}
    exec(compile(readme_example(), str(README), "exec"), namespace)  # noqa: S102 - our own README
    result, online = namespace["result"], namespace["online"]
    assert isinstance(result, supportnet.CalibrationResult)
    assert result.T_cam_lidar.shape == (4, 4) and result.covariance.shape == (6, 6)
    assert result.initial_error.translation_cm == pytest.approx(10.0)
    assert result.error.translation_cm < result.initial_error.translation_cm
    assert result.error.rotation_deg < result.initial_error.rotation_deg
    assert isinstance(online, supportnet.OnlineCalibrator)
    assert not np.allclose(online.T_cam_lidar, online.T_init)  # a window closed and moved it


def test_errors_are_one_family():
    for error in (supportnet.DataError, supportnet.ConfigError, supportnet.NumericalError):
        assert issubclass(error, supportnet.SupportnetError)
    with pytest.raises(supportnet.DataError):
        supportnet.open_dataset("/nonexistent/dataset")
    with pytest.raises(supportnet.ConfigError, match="not uniform"):
        supportnet.Calibrator(support="sometimes")
    with pytest.raises(AttributeError):
        _ = supportnet.no_such_thing


def test_version_is_exported():
    assert re.match(r"\d+\.\d+", supportnet.__version__)
