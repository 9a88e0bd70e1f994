"""Fixtures shared by the tests of ``calib``."""

import pytest

from calib.data import Frame
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config


@pytest.fixture(scope="session")
def small_urban() -> list[Frame]:
    """Two frames of the urban world at the small camera, still (no wind, no camera time offset),
    seed 5: what the contour score and the check are tested on."""
    still = {"wind": {"amplitude_m": 0.0}, "timing": {"camera_offset_s": 0.0}}
    synth = Synthesizer(load_synth_config("urban", small=True, **still), 2, seed=5)
    return [synth.render(i).frame for i in range(2)]
