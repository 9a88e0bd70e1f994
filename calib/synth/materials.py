"""Surface appearance: albedo textures fixed in world coordinates, LiDAR reflectance, shading.

Every material is one row of :data:`MATERIALS`; meshes store its index. Colours are linear RGB in
``[0, 1]``; :func:`to_srgb` turns the shaded result into an 8-bit image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.synth.noise import fbm, value_noise

__all__ = ["MATERIALS", "Material", "material_id", "sky", "surface", "to_srgb"]


@dataclass(frozen=True)
class Material:
    """Appearance of one surface type.

    Attributes:
        color, color2: linear RGB between which the texture blends.
        scale: size in metres of the texture's blobs.
        reflectance: LiDAR reflectance in ``[0, 1]`` (intensity before the incidence angle).
        pattern: ``noise`` (blend by fractal noise), ``ground`` (grass with bare-soil patches),
            ``facade`` (wall with a grid of windows), ``streaks`` (bark, wood: stretched
            vertically), ``paint`` (one colour per instance, as car bodies).
    """

    name: str
    color: tuple[float, float, float]
    color2: tuple[float, float, float]
    scale: float
    reflectance: float
    pattern: str = "noise"


MATERIALS: tuple[Material, ...] = (
    Material("grass", (0.10, 0.20, 0.04), (0.22, 0.30, 0.08), 0.6, 0.35, "ground"),
    Material("soil", (0.22, 0.15, 0.09), (0.34, 0.25, 0.16), 0.4, 0.25),
    Material("leaf", (0.06, 0.20, 0.03), (0.18, 0.32, 0.05), 0.25, 0.45),
    Material("bark", (0.16, 0.10, 0.06), (0.30, 0.21, 0.13), 0.08, 0.30, "streaks"),
    Material("wood", (0.28, 0.22, 0.15), (0.45, 0.37, 0.26), 0.15, 0.40, "streaks"),
    Material("galvanised", (0.45, 0.46, 0.47), (0.60, 0.61, 0.62), 0.3, 0.55),
    Material("wire", (0.55, 0.55, 0.56), (0.70, 0.70, 0.70), 0.5, 0.60),
    Material("pipe", (0.02, 0.02, 0.02), (0.06, 0.06, 0.06), 0.5, 0.12),
    Material("corrugated", (0.40, 0.40, 0.38), (0.55, 0.50, 0.45), 1.0, 0.50, "facade"),
    Material("facade", (0.45, 0.38, 0.30), (0.65, 0.60, 0.52), 2.0, 0.45, "facade"),
    Material("roof", (0.30, 0.12, 0.08), (0.42, 0.20, 0.12), 0.5, 0.30),
    Material("paint", (0.50, 0.05, 0.05), (0.05, 0.10, 0.45), 1.0, 0.55, "paint"),
    Material("glass", (0.02, 0.03, 0.04), (0.08, 0.10, 0.12), 0.5, 0.05),
    Material("tyre", (0.02, 0.02, 0.02), (0.04, 0.04, 0.04), 0.2, 0.08),
    Material("asphalt", (0.07, 0.07, 0.075), (0.16, 0.16, 0.16), 0.5, 0.15),
    Material("marking", (0.80, 0.80, 0.78), (0.90, 0.90, 0.88), 0.3, 0.90),
    Material("concrete", (0.35, 0.34, 0.32), (0.50, 0.49, 0.46), 0.4, 0.40),
    Material("metal", (0.30, 0.31, 0.33), (0.45, 0.46, 0.48), 0.3, 0.50),
    Material("sign", (0.70, 0.70, 0.72), (0.05, 0.15, 0.55), 0.3, 0.95, "paint"),
)

_INDEX = {m.name: i for i, m in enumerate(MATERIALS)}

# What each noise lattice is for: a world's lattices are keyed ``(seed, purpose, index)``, never by
# adding offsets to the seed (seed 250 + material 6 would be seed 256's material 0)
_TEXTURE, _BARE_SOIL, _GRAIN, _CLOUDS = 1, 2, 3, 4
_SOIL = MATERIALS[_INDEX["soil"]]  # bare patches in grass look and reflect like soil
_GLASS_REFLECTANCE = 0.03  # facade windows: most of the beam passes or mirrors away

# A small palette for per-instance colours (car paint, signs, walls)
_PAINT = np.array(
    [
        [0.50, 0.05, 0.05],
        [0.05, 0.10, 0.40],
        [0.60, 0.60, 0.62],
        [0.03, 0.03, 0.03],
        [0.25, 0.27, 0.30],
        [0.55, 0.45, 0.10],
        [0.70, 0.70, 0.68],
        [0.10, 0.25, 0.12],
    ]
)


def material_id(name: str) -> int:
    """Index of the material called ``name`` in :data:`MATERIALS`."""
    return _INDEX[name]


def _instance_color(instance: np.ndarray, jitter: float) -> np.ndarray:
    color = _PAINT[(instance.astype(np.int64) * 7 + 3) % len(_PAINT)]
    return color * (1.0 + jitter * (((instance.astype(np.int64) * 2654435761) % 97) / 97.0 - 0.5))[:, None]


def _windows(m: Material, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Where a facade has windows: a grid on the wall; the horizontal coordinate runs along it."""
    along = p[:, 0] * -n[:, 1] + p[:, 1] * n[:, 0]
    floor = 1.5 * m.scale
    window = (np.mod(along, floor) > 0.35 * floor) & (np.mod(p[:, 2] + 0.3 * floor, floor) > 0.45 * floor)
    return window & (np.abs(n[:, 2]) < 0.5)


def _bare_soil(m: Material, p: np.ndarray, seed: int) -> np.ndarray:
    """Patches of bare soil in grass: large, low-frequency blobs."""
    return fbm(p, 6.0 * m.scale, 2, (seed, _BARE_SOIL, 0)) > 0.58


def surface(
    material: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    instance: np.ndarray,
    seed: int = 0,
    color: bool = True,
) -> tuple[np.ndarray | None, np.ndarray]:
    """Surface colour and LiDAR reflectance at hit points.

    Args:
        material: ``(N,)`` indices into :data:`MATERIALS` (all valid).
        points: ``(N, 3)`` world coordinates. normals: ``(N, 3)``. instance: ``(N,)``.
        seed: the world's seed, an integer in [0, 2³²).
        color: compute the albedo too (the LiDAR needs only reflectance).

    Returns:
        ``rgb (N, 3)`` linear albedo (``None`` without ``color``) and ``reflectance (N,)``.
    """
    rgb = np.zeros((len(material), 3), np.float32) if color else None
    reflectance = np.zeros(len(material), np.float32)
    for index in np.unique(material):
        sel = material == index
        m = MATERIALS[index]
        p, n, inst = points[sel], normals[sel], instance[sel]
        mask = (
            _windows(m, p, n)
            if m.pattern == "facade"
            else (_bare_soil(m, p, seed) if m.pattern == "ground" else np.zeros(len(p), bool))
        )
        reflectance[sel] = np.where(
            mask, _GLASS_REFLECTANCE if m.pattern == "facade" else _SOIL.reflectance, m.reflectance
        )
        if not color:
            continue
        q = p * (1.0, 1.0, 0.15) if m.pattern == "streaks" else p
        w = fbm(q, m.scale, 3, (seed, _TEXTURE, int(index)))[:, None]
        if m.pattern in ("paint", "facade"):
            base = _instance_color(inst, 0.3)
            c = base * (0.9 + 0.2 * w) if m.pattern == "paint" else (0.7 * base + 0.3 * np.asarray(m.color))
        else:
            c = (1 - w) * np.asarray(m.color) + w * np.asarray(m.color2)
        if m.pattern == "facade":
            c = np.where(mask[:, None], np.asarray(m.color2) * 0.15 + 0.04, c * (0.8 + 0.4 * w))
        elif m.pattern == "ground":
            bare = (1 - w) * np.asarray(_SOIL.color) + w * np.asarray(_SOIL.color2)
            c = np.where(mask[:, None], bare, c)
        # Fine grain (a few centimetres) so every surface carries trackable texture
        rgb[sel] = c * (0.75 + 0.5 * value_noise(p, 0.03, (seed, _GRAIN, 0)))[:, None]
    return rgb, reflectance


def sky(directions: np.ndarray, sun: np.ndarray, seed: int = 0) -> np.ndarray:
    """Sky radiance along ``(N, 3)`` world directions: a blue gradient, the sun's glow, clouds."""
    up = np.clip(directions[:, 2], 0.0, 1.0)
    horizon = np.array([0.75, 0.82, 0.92])
    zenith = np.array([0.20, 0.38, 0.80])
    rgb = horizon + (zenith - horizon) * np.sqrt(up)[:, None]
    glow = np.clip(directions @ sun, 0.0, 1.0) ** 64
    plane = directions[:, :2] / np.maximum(up, 0.05)[:, None] * 500.0
    cloud = fbm(np.column_stack([plane, np.zeros(len(plane))]), 400.0, 3, (seed, _CLOUDS, 0))
    cloud = np.clip((cloud - 0.5) * 3, 0, 1)
    cloud *= np.clip((up - 0.03) / 0.12, 0, 1)  # fade out towards the horizon, where they would smear
    rgb = rgb * (1 - cloud[:, None]) + 0.95 * cloud[:, None]
    return rgb + glow[:, None] * 0.5


def to_srgb(linear: np.ndarray) -> np.ndarray:
    """Linear RGB (any range) to 8-bit sRGB-like values (gamma 2.2, clipped)."""
    return (np.clip(linear, 0.0, 1.0) ** (1 / 2.2) * 255.0 + 0.5).astype(np.uint8)
