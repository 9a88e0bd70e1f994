"""``SupportUNet``: the image → support-logit network of Stage 3 online.

A small U-Net (Ronneberger et al. 2015) that runs at ``1/stem_stride`` of the input resolution:
the support maps it learns are Gaussian sums with σ = 6 px (Eq. 2), so full-resolution features
buy nothing but time. At 1/4 (the default; its decoder ends there) it runs twice as fast as at
1/2 and correlates as well with held-out offline maps (``benchmarks/bench_predictor.py``, the
model card). Its output stays at 1/``stem_stride`` (:meth:`SupportUNet.coarse`, what an export
computes); :meth:`SupportUNet.forward` upsamples it bilinearly to the input size, as
:class:`~supportnet.runtime.support_predictor.SupportPredictor` does after onnxruntime. Any input
size works: the input is padded to a multiple of ``stride`` and the output cropped back.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field
from torch import nn

from supportnet.nets.contract import Contract

__all__ = ["CoarseLogits", "ModelConfig", "SupportUNet"]


class ModelConfig(BaseModel):
    """Width and depth of :class:`SupportUNet`."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    width: int = Field(16, ge=4, description="channels of the first level; each level doubles them")
    depth: int = Field(3, ge=1, le=5, description="down-sampling levels below the stem")
    stem_stride: int = Field(4, ge=1, le=4, description="the network runs at 1/stem_stride resolution")


def _conv(c_in: int, c_out: int, kernel: int, stride: int = 1) -> nn.Sequential:
    """A convolution (odd ``kernel``; ``1/stride`` of the size out) with batch norm and ReLU."""
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, kernel, stride, padding=kernel // 2, bias=False),
        nn.BatchNorm2d(c_out),
        nn.ReLU(inplace=True),
    )


def _block(c_in: int, c_out: int) -> nn.Sequential:
    """Two 3x3 convolutions, each with batch norm and ReLU."""
    return nn.Sequential(*_conv(c_in, c_out, 3), *_conv(c_out, c_out, 3))


class SupportUNet(nn.Module):
    """RGB image → support logits (apply a sigmoid for support in [0, 1]).

    Args:
        config: width, depth and stem stride.

    Shape:
        - image: ``(B, 3, H, W)`` normalised RGB (see :mod:`supportnet.nets.contract`), any ``H, W``.
        - output: ``(B, 1, H, W)`` logits (:meth:`coarse`: ``(B, 1, ⌈H/stride⌉·stride/stem_stride,
          …)``, before the upsampling).
    """

    def __init__(self, config: ModelConfig = ModelConfig()) -> None:
        super().__init__()
        self.config = config
        widths = [config.width * 2**level for level in range(config.depth + 1)]
        # a kernel of 2s − 1 taps sees every pixel at stride s (no aliasing gaps)
        self.stem = _conv(3, widths[0], 2 * config.stem_stride - 1, config.stem_stride)
        self.down = nn.ModuleList(
            _block(c_in, c_out) for c_in, c_out in zip([widths[0], *widths[:-1]], widths, strict=True)
        )
        self.up = nn.ModuleList(_block(widths[i + 1] + widths[i], widths[i]) for i in range(config.depth))
        self.head = nn.Conv2d(widths[0], 1, 1)

    @property
    def stride(self) -> int:
        """Input sizes are padded to a multiple of this."""
        return self.config.stem_stride * 2**self.config.depth

    def contract(self, target: str = "agreement", working_focal_px: float | None = None) -> Contract:
        """The pre-processing contract an export of this network carries (its config included),
        with the focal length of the images it learned from where known (``working_focal_px``: a
        predictor resamples an image of a longer focal length down to it first)."""
        extra: dict = {"model": self.config.model_dump()}
        if working_focal_px is not None:
            extra["working_focal_px"] = float(working_focal_px)
        return Contract(stride=self.stride, target=target, output_stride=self.config.stem_stride, extra=extra)

    def coarse(self, image: torch.Tensor) -> torch.Tensor:
        """Logits at ``1/stem_stride`` of the input padded to a multiple of :attr:`stride`."""
        H, W = image.shape[-2:]
        x = self.stem(F.pad(image, (0, (-W) % self.stride, 0, (-H) % self.stride), mode="replicate"))
        skips = []
        for level, block in enumerate(self.down):  # contracting path
            x = block(x if level == 0 else F.max_pool2d(x, 2))
            skips.append(x)
        x = skips.pop()
        for block in reversed(self.up):  # expanding path with skip connections
            x = F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skips.pop()], dim=1))
        return self.head(x)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        H, W = image.shape[-2:]
        logits, s = self.coarse(image), self.config.stem_stride
        if s > 1:  # bilinear, half-pixel centres (SupportPredictor does the same after an export)
            logits = F.interpolate(logits, scale_factor=float(s), mode="bilinear", align_corners=False)
        return logits[..., :H, :W]


class CoarseLogits(nn.Module):
    """What an export of a :class:`SupportUNet` computes: its :meth:`~SupportUNet.coarse` logits
    (the run time upsamples them, :class:`~supportnet.nets.contract.Contract`'s ``output_stride``)."""

    def __init__(self, net: SupportUNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.net.coarse(image)
