"""The pre-processing contract between training and run time (numpy and OpenCV only).

The exported ONNX model stores it in its metadata (key ``supportnet.contract``, JSON) and
:class:`supportnet.runtime.support_predictor.SupportPredictor` reads it back, so a model always
comes with how to feed it: RGB channels first, scaled to [0, 1], then normalised by ``mean`` and ``std``; the
output is a logit (sigmoid → support in [0, 1]).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from functools import cached_property

import cv2
import numpy as np

__all__ = ["METADATA_KEY", "Contract"]

METADATA_KEY = "supportnet.contract"


@dataclass(frozen=True)
class Contract:
    """How images become the network's input and what its output means.

    Attributes:
        mean, std: per RGB channel, applied after scaling to [0, 1].
        stride: the network pads inputs to a multiple of this (informational: it does so itself).
        target: which offline map it learned (``agreement`` or ``support``).
        layout: input layout, always ``NCHW`` float32 RGB.
        output: ``logits`` (a support predictor, one channel) or ``flow`` (a flow matcher: two
            channels, pixels; its LiDAR input is described in ``extra``).
        output_stride: the output comes at ``1/output_stride`` of the input padded to a multiple
            of ``stride``; the run time upsamples it bilinearly (half-pixel centres) and crops it
            to the input's size (1: the input's size already).
        version: of this contract.
    """

    mean: tuple[float, float, float] = (0.485, 0.456, 0.406)
    std: tuple[float, float, float] = (0.229, 0.224, 0.225)
    stride: int = 16
    target: str = "agreement"
    layout: str = "NCHW"
    output: str = "logits"
    output_stride: int = 1
    version: int = 1
    extra: dict = field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> Contract:
        """Raises ``ValueError`` (with the reason) when ``text`` is not a contract this code reads."""
        data = json.loads(text)
        if not isinstance(data, dict) or data.get("version") != 1:
            raise ValueError(
                f"unsupported contract version {data.get('version') if isinstance(data, dict) else data!r}"
            )
        if data.get("layout") != "NCHW" or data.get("output") not in ("logits", "flow"):
            raise ValueError(f"unsupported layout/output {data.get('layout')}/{data.get('output')}")
        data["mean"], data["std"] = tuple(data["mean"]), tuple(data["std"])
        return cls(**data)

    def preprocess(self, images: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``(B, H, W, 3)`` or ``(H, W, 3)`` RGB (uint8, or float in [0, 1]) → ``(B, 3, H, W)`` float32
        input, written into ``out`` where it is given (and of that shape: a caller that runs
        many frames passes the same one each time, ``SupportPredictor``). uint8 images go through
        a 256-entry table per channel, one OpenCV look-up per channel plane straight into
        ``out`` (a tenth of the time of the arithmetic on a 624x188 frame, the same values;
        0.5 ms against 0.85 for one look-up of all three channels and a copy per channel, 1.7
        against 2.5–3.8 ms at 1242x375, between onnxruntime runs on this 2-core machine)."""
        images = np.asarray(images)
        if images.ndim == 3:
            images = images[None]
        if images.ndim != 4 or images.shape[-1] != 3:
            raise ValueError(f"expected (B, H, W, 3) or (H, W, 3) RGB images, got {images.shape}")
        shape = (len(images), 3, *images.shape[1:3])
        if out is None or out.shape != shape or out.dtype != np.float32:
            out = np.empty(shape, np.float32)
        for b, image in enumerate(images):
            planes = cv2.split(np.ascontiguousarray(image)) if images.dtype == np.uint8 else None
            for channel in range(3):
                if planes is not None:
                    cv2.LUT(planes[channel], self._table[channel], dst=out[b, channel])
                else:
                    plane = image[..., channel].astype(np.float32) - np.float32(self.mean[channel])
                    np.divide(plane, np.float32(self.std[channel]), out=out[b, channel])
        return out

    @cached_property
    def _table(self) -> np.ndarray:
        """``(3, 256, 1)`` float32: the normalised value of every uint8 level, per channel."""
        levels = np.arange(256, dtype=np.float32)[None, :, None] / np.float32(255.0)
        return (levels - np.float32(self.mean)[:, None, None]) / np.float32(self.std)[:, None, None]
