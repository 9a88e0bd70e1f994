"""What a real camera does to the light of the scene: lens blur, vignetting, an exposure error per
frame, photon (shot) noise, and JPEG compression.

The renderer's images are otherwise sharper, cleaner and more evenly exposed than real ones, so a
matcher measured on them looks better than it is on real frames. :func:`expose` works on linear
light (the optics and the sensor), :func:`compress` on the 8-bit sRGB image (the encoder); both
are pure, and every effect at zero strength returns its input unchanged.
"""

from __future__ import annotations

import cv2
import numpy as np

from calib.synth.synth_config import CameraEffectsConfig

__all__ = ["compress", "expose", "vignetting_gain"]


def vignetting_gain(height: int, width: int, strength: float) -> np.ndarray:
    """``(H, W)`` float32 light falloff ``1 − strength · (r / r_corner)²`` about the image centre:
    1 at the centre, ``1 − strength`` at the corner pixels (the second-order term of the cos⁴ law,
    scaled so the strength is the corner loss a user reads off a flat-field image)."""
    v = np.arange(height, dtype=np.float32)[:, None] - (height - 1) / 2
    u = np.arange(width, dtype=np.float32)[None, :] - (width - 1) / 2
    r2_corner = ((height - 1) / 2) ** 2 + ((width - 1) / 2) ** 2
    return 1.0 - strength * (u * u + v * v) / max(r2_corner, 1e-12)


def expose(linear: np.ndarray, config: CameraEffectsConfig, rng: np.random.Generator) -> np.ndarray:
    """The optics and the sensor: lens blur, vignetting, the frame's exposure gain, shot noise.

    In the order light meets them, so the noise is not blurred and the gain scales the signal the
    shot noise grows with. The gain ``2^N(0, exposure_std_stops)`` over- or under-exposes the whole
    frame: a bright frame clips its highlights (edges in them vanish), a dark one loses contrast to
    the fixed read noise the renderer adds afterwards.

    Args:
        linear: ``(H, W, 3)`` float32 linear RGB (1 is the sensor's white).
        config: the strengths.
        rng: the frame's generator for the effects (draws only for the effects that are on).

    Returns:
        ``(H, W, 3)`` float32 linear RGB, unclipped; ``linear`` itself when every effect is off.
    """
    out = linear
    if config.blur_px > 0:
        out = cv2.GaussianBlur(out, (0, 0), config.blur_px, borderType=cv2.BORDER_REFLECT)
    if config.vignetting > 0:
        out = out * vignetting_gain(*out.shape[:2], config.vignetting)[..., None]
    if config.exposure_std_stops > 0:
        out = out * np.float32(2.0 ** rng.normal(0.0, config.exposure_std_stops))
    if config.shot_noise > 0:
        std = np.sqrt(config.shot_noise * np.clip(out, 0.0, None))
        out = out + std * rng.standard_normal(out.shape, np.float32)
    return out


def compress(image: np.ndarray, quality: int | None) -> np.ndarray:
    """JPEG round trip of ``image (H, W, 3)`` uint8 RGB at ``quality`` (1–100; ``None``: the image
    unchanged): 8x8 block edges, ringing at strong edges and smeared chroma, as in the real
    fixtures' JPEG frames (nuScenes) and any camera recorded through a compressed stream."""
    if quality is None:
        return image
    # OpenCV encodes BGR: swap so the chroma subsampling acts on the true colour channels
    ok, data = cv2.imencode(".jpg", image[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return np.ascontiguousarray(cv2.imdecode(data, cv2.IMREAD_COLOR)[..., ::-1])
