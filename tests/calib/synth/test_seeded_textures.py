"""Issue 19, defect 2: ``synth --seed 256`` crashed (OverflowError: ``seed + index`` with a uint8
material index) and seeds 250-255 silently reused other seeds' textures (the sum wrapped, and
``seed + index`` collides across seeds anyway). Texture lattices are now keyed by
``(seed, purpose, material, octave)``."""

import hashlib

import numpy as np
import pytest

from calib.errors import ConfigError
from calib.synth import noise
from calib.synth.generate import Synthesizer
from calib.synth.materials import MATERIALS, sky, surface
from calib.synth.synth_config import load_synth_config

SMALL = {
    "camera": {"width": 64, "height": 24, "fx": 37.0, "fy": 37.0, "cx": 31.5, "cy": 11.5},
    "lidar": {"beams": 8, "azimuth_step_deg": 2.0},
}


def _all_materials(n: int = 64) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(0)
    material = np.repeat(np.arange(len(MATERIALS), dtype=np.uint8), n)  # uint8, as the ray caster returns
    points = rng.uniform(-20, 20, (len(material), 3))
    normals = np.tile([0.0, 0.0, 1.0], (len(material), 1))
    return material, points, normals, np.ones(len(material), np.uint16)


_TABLE = noise._table


def _lattices(seed: int, monkeypatch) -> set[str]:
    """Digests of every noise lattice one seed's camera shading uses (every material and the sky)."""
    used = set()

    def spy(key):
        values = _TABLE(key)
        used.add(hashlib.sha256(values.tobytes()).hexdigest())
        return values

    monkeypatch.setattr(noise, "_table", spy)
    monkeypatch.setattr(noise, "_TABLES", {})
    surface(*_all_materials(), seed=seed)
    sky(np.array([[0.3, 0.2, 0.93]]), np.array([0.0, 0.0, 1.0]), seed=seed)
    return used


def test_no_two_seeds_share_a_texture(monkeypatch):
    seeds = [0, 1, 2, 5, 6, 250, 251, 252, 253, 254, 255, 256, 257]
    lattices = {seed: _lattices(seed, monkeypatch) for seed in seeds}
    assert all(len(used) >= len(MATERIALS) for used in lattices.values())
    for i, a in enumerate(seeds):
        for b in seeds[i + 1 :]:
            assert not lattices[a] & lattices[b], f"seeds {a} and {b} share a texture"


@pytest.mark.parametrize("seed", [255, 256, 2**32 - 1])
def test_large_seeds_shade_every_material(seed):
    rgb, reflectance = surface(*_all_materials(), seed=seed)
    assert np.isfinite(rgb).all() and np.isfinite(reflectance).all()


def test_seeds_250_to_255_render_pairwise_different_images():
    config = load_synth_config("vineyard", **SMALL)
    images = {seed: Synthesizer(config, 1, seed).render(0).frame.image for seed in range(250, 257)}
    images[2**32 - 1] = Synthesizer(config, 1, 2**32 - 1).render(0).frame.image
    seeds = list(images)
    for i, a in enumerate(seeds):
        for b in seeds[i + 1 :]:
            assert not np.array_equal(images[a], images[b]), (a, b)


@pytest.mark.parametrize(
    ("kwargs", "where"),
    [
        ({"seed": -1}, "seed"),
        ({"seed": 2**32}, "seed"),
        ({"frames": 0}, "frames"),
        ({"drift": (float("nan"), 1.0)}, "drift"),
        ({"drift": (5.0, float("inf"))}, "drift"),
        ({"drift": (-1.0, 0.0)}, "drift"),
        ({"drift": (500.0, 1.0)}, "drift"),
    ],
)
def test_the_synthesizer_refuses_out_of_range_arguments_before_building(kwargs, where):
    arguments = {"frames": 1, "seed": 0, **kwargs}
    with pytest.raises(ConfigError) as info:
        Synthesizer(load_synth_config("vineyard", **SMALL), **arguments)
    assert str(info.value).startswith(f"{where}: ") and "\n" not in str(info.value)


def test_noise_keys_outside_32_bits_are_refused():
    with pytest.raises(ValueError):
        noise.value_noise(np.zeros((1, 3)), 1.0, (2**32, 0))
    with pytest.raises(ValueError):
        noise.fbm(np.zeros((1, 3)), 1.0, 2, -1)
