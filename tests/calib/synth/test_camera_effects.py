"""The synthetic camera's effects: known answers on small arrays, identity at zero strength,
reproducibility, and that they touch the image alone."""

import numpy as np
import pytest
from pydantic import ValidationError

from calib.errors import ConfigError
from calib.synth.camera_effects import compress, expose, vignetting_gain
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import CameraEffectsConfig, load_synth_config

ON = CameraEffectsConfig(
    blur_px=1.0, vignetting=0.3, exposure_std_stops=0.5, shot_noise=0.004, jpeg_quality=70
)


def _scene(seed: int = 0) -> np.ndarray:
    """``(24, 40, 3)`` float32 linear image: random blocks of 4x4 pixels (sharp edges)."""
    blocks = np.random.default_rng(seed).uniform(0.05, 0.8, (6, 10, 3)).astype(np.float32)
    return np.kron(blocks, np.ones((4, 4, 1), np.float32))


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float(10 * np.log10(255.0**2 / mse))


def test_vignetting_darkens_the_corners_by_the_configured_factor():
    gain = vignetting_gain(5, 7, 0.3)
    assert gain.shape == (5, 7) and gain.dtype == np.float32
    assert gain[2, 3] == pytest.approx(1.0)
    np.testing.assert_allclose(gain[[0, 0, -1, -1], [0, -1, 0, -1]], 0.7, rtol=1e-6)
    flat = np.full((5, 7, 3), 0.5, np.float32)
    out = expose(flat, CameraEffectsConfig(vignetting=0.3), np.random.default_rng(0))
    np.testing.assert_allclose(out[0, 0], 0.35, rtol=1e-6)
    assert np.all(out <= 0.5 + 1e-7)


def test_zero_strength_is_the_identity():
    image = _scene()
    assert expose(image, CameraEffectsConfig(), np.random.default_rng(0)) is image
    rgb = (image * 255).astype(np.uint8)
    assert compress(rgb, None) is rgb


def test_shapes_dtypes_and_the_same_seed_gives_the_same_output():
    image = _scene()
    a = expose(image, ON, np.random.default_rng(3))
    assert a.shape == image.shape and a.dtype == np.float32
    np.testing.assert_array_equal(a, expose(image, ON, np.random.default_rng(3)))
    assert not np.array_equal(a, expose(image, ON, np.random.default_rng(4)))
    np.testing.assert_array_equal(image, _scene())  # the input is not modified


def test_blur_keeps_the_mean_and_lowers_the_contrast():
    image = _scene()
    blurred = expose(image, CameraEffectsConfig(blur_px=1.5), np.random.default_rng(0))
    assert blurred.mean() == pytest.approx(image.mean(), rel=1e-3)
    assert np.abs(np.diff(blurred, axis=1)).max() < 0.8 * np.abs(np.diff(image, axis=1)).max()


def test_shot_noise_grows_with_the_signal():
    flat = np.concatenate([np.full((16, 16, 3), 0.04, np.float32), np.full((16, 16, 3), 0.64, np.float32)])
    out = expose(flat, CameraEffectsConfig(shot_noise=0.01), np.random.default_rng(0))
    dark, bright = out[:16].std(), out[16:].std()
    assert dark == pytest.approx(0.02, rel=0.15) and bright == pytest.approx(0.08, rel=0.15)


def test_lower_jpeg_quality_lowers_the_psnr():
    rgb = (np.clip(_scene(), 0, 1) * 255).astype(np.uint8)
    psnr = {q: _psnr(compress(rgb, q), rgb) for q in (95, 60, 20)}
    assert compress(rgb, 60).shape == rgb.shape and compress(rgb, 60).dtype == np.uint8
    assert psnr[95] > psnr[60] > psnr[20]


def test_the_config_refuses_typos_and_out_of_range_values():
    with pytest.raises(ValidationError, match="blur_sigma"):
        CameraEffectsConfig(blur_sigma=1.0)
    with pytest.raises(ValidationError):
        CameraEffectsConfig(vignetting=1.0)  # a corner gain of 0
    with pytest.raises(ValidationError):
        CameraEffectsConfig(jpeg_quality=0)
    with pytest.raises(ConfigError, match="camera_effects.blurr_px"):
        load_synth_config("urban", camera_effects={"blurr_px": 1.0})


def test_effects_change_the_image_and_leave_the_scan():
    tiny = {"width": 48, "height": 24, "fx": 30.0, "fy": 30.0, "cx": 23.5, "cy": 11.5}
    off, on = (
        load_synth_config("urban", camera=tiny, camera_effects=effects)
        for effects in (CameraEffectsConfig().model_dump(), ON.model_dump())
    )
    a, b = (Synthesizer(config, 1, seed=3).render(0).frame for config in (off, on))
    np.testing.assert_array_equal(a.points, b.points)
    assert a.image.shape == b.image.shape and not np.array_equal(a.image, b.image)
