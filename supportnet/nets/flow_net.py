"""A compact RAFT-style network for LiDAR–camera matching, CMRNext's formulation.

Flow goes from the image of the projected LiDAR scan to the RGB image: at every pixel ``x`` where
a LiDAR point lands under the current extrinsic, ``f(x)`` says where in the RGB image that point
really lies, ``x + f(x)``. As in RAFT (Teed & Deng, ECCV 2020): feature encoders at 1/8
resolution for both images, an all-pairs correlation volume with a pyramid (RAFT Eq. 1–2), a
context encoder on the LiDAR image, and a convolutional GRU that refines the flow from lookups of
the volume around the current estimate (RAFT Sec. 3.3).

In place of RAFT's convex upsampling, the GRU refines the local model of the flow an extrinsic
error causes, ``f(x) = a(x) + b(x) · ρ(x)`` with ``ρ = near_m / depth`` (rotation moves a point
independently of its depth, translation in inverse proportion to it; the EdgeMatcher fits the same
model): ``a`` and ``b`` vary smoothly and are upsampled ×8 bilinearly, ``ρ`` is read at full
resolution from the LiDAR image, so a pole and the field behind it in one 8x8 cell get their own
flows.

A second, fixed correlation volume sits beside the learned one: of the two modalities' edge
orientation fields ``e · (cos 2θ, sin 2θ)`` (those the training-free EdgeMatcher correlates), the
LiDAR one drawn with the LiDAR image, the image one computed in the network. Features learned from
scratch carry no cross-modal signal at first, and on two CPU cores they never came to (validation
endpoint error stayed at the no-flow baseline for 2,000 steps); the fixed volume gives the update
block something to read from the first step, and the learned one room to improve on it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field
from torch import nn

from supportnet.nets.contract import Contract

__all__ = ["FlowConfig", "FlowNet", "LIDAR_CHANNELS", "edge_features", "image_orientation", "lidar_input"]

STRIDE = 8
LIDAR_CHANNELS = ("mask", "inverse_depth", "relative_intensity", "edge_cos", "edge_sin")
"""The LiDAR image's channels: 1 where a point lands; ``near_m / depth`` (≤ 1); its intensity over
the scan's 99th percentile (:func:`~supportnet.runtime.flow_matcher.relative_intensity`: scanners
report 0–1 or 0–255); and the scan's edge orientation field ``e · (cos 2θ, sin 2θ)``
(:func:`calib.match.edge_matcher.lidar_edges`)."""
EDGE_GAIN = 8.0
"""Scale of the edge features, so the fixed correlation starts at the learned one's magnitude."""


class FlowConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    feature_dim: int = Field(64, ge=8, description="channels of the matching features (1/8 resolution)")
    hidden_dim: int = Field(48, ge=8, description="GRU state channels")
    context_dim: int = Field(32, ge=8, description="context channels fed to the GRU at every step")
    levels: int = Field(3, ge=1, le=4, description="correlation pyramid levels")
    radius: int = Field(3, ge=1, description="lookup radius at every level (1/8-resolution pixels)")
    iterations: int = Field(6, ge=1, description="GRU refinement steps")


def lidar_input(
    depth: torch.Tensor, intensity: torch.Tensor, edges: torch.Tensor, near_m: float = 2.0
) -> torch.Tensor:
    """The network's LiDAR image from rendered depth and intensity and the scan's edge field.

    Args:
        depth: ``(..., H, W)`` metres, 0 where no point lands.
        intensity: ``(..., H, W)`` in [0, 1].
        edges: ``(..., 2, H, W)`` orientation field.

    Returns:
        ``(..., 5, H, W)`` with the channels of :data:`LIDAR_CHANNELS`.
    """
    mask = (depth > 0).to(depth.dtype)
    inverse = torch.where(depth > 0, near_m / depth.clamp_min(1e-6), torch.zeros_like(depth)).clamp(max=1.0)
    return torch.cat([torch.stack([mask, inverse, intensity * mask], dim=-3), edges.to(depth.dtype)], dim=-3)


def image_orientation(image: torch.Tensor, blur_px: float = 0.7) -> torch.Tensor:
    """Edge orientation field of an image, as :func:`calib.match.edge_matcher.image_edges` in torch.

    The strength ``m² / (m² + c²)`` saturates; ``c²`` is a quarter of the image's mean ``m²`` (the
    EdgeMatcher's median gradient needs a sort that ONNX lacks).

    Args:
        image: ``(B, 3, H, W)``, any per-channel affine normalisation.

    Returns:
        ``(B, 2, H, W)``: ``strength · (cos 2θ, sin 2θ)`` of the grey gradient.
    """
    grey = image.mean(1, keepdim=True)
    x = torch.arange(-2, 3, dtype=image.dtype, device=image.device)
    g = torch.exp(-0.5 * (x / blur_px) ** 2)
    g = g / g.sum()
    smooth = torch.tensor([1.0, 2.0, 1.0], dtype=image.dtype, device=image.device) / 8
    diff = torch.tensor([-1.0, 0.0, 1.0], dtype=image.dtype, device=image.device)
    grey = F.conv2d(F.pad(grey, (2, 2, 2, 2), mode="replicate"), (g[:, None] * g[None]).view(1, 1, 5, 5))
    grey = F.pad(grey, (1, 1, 1, 1), mode="replicate")
    gx = F.conv2d(grey, (smooth[:, None] * diff[None]).view(1, 1, 3, 3))  # Sobel / 8
    gy = F.conv2d(grey, (diff[:, None] * smooth[None]).view(1, 1, 3, 3))
    m2 = gx * gx + gy * gy
    c2 = 0.25 * m2.mean(dim=(-2, -1), keepdim=True) + 1e-8
    return torch.cat([gx * gx - gy * gy, 2 * gx * gy], dim=1) / (m2 + c2)


def edge_features(field: torch.Tensor) -> torch.Tensor:
    """``(B, 2, H, W)`` orientation field → ``(B, 8, H/8, W/8)``: its means over the four 4x4
    quarters of every 8x8 cell, so a cell's features keep where in the cell its edges lie."""
    return EDGE_GAIN * F.pixel_unshuffle(F.avg_pool2d(field, 4), 2)


def _stage(c_in: int, c_out: int, stride: int, norm: bool) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(2):
        layers.append(nn.Conv2d(c_in if i == 0 else c_out, c_out, 3, stride if i == 0 else 1, 1))
        if norm:
            layers.append(nn.InstanceNorm2d(c_out))
        layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


class Encoder(nn.Sequential):
    """``(B, C, H, W)`` → ``(B, out, H/8, W/8)``: three stride-2 stages, then a 1x1 projection."""

    def __init__(self, c_in: int, c_out: int, norm: bool) -> None:
        super().__init__(_stage(c_in, 24, 2, norm), _stage(24, 32, 2, norm), _stage(32, 48, 2, norm))
        self.add_module("project", nn.Conv2d(48, c_out, 1))


def correlation_pyramid(source: torch.Tensor, target: torch.Tensor, levels: int) -> list[torch.Tensor]:
    """All-pairs correlation (RAFT Eq. 1) and its pooled pyramid (Eq. 2).

    Args:
        source, target: ``(B, C, h, w)`` features of the LiDAR and the RGB image.

    Returns:
        ``levels`` tensors ``(B·h·w, 1, h / 2^l, w / 2^l)``: for each source pixel, its dot
        products with every target pixel, divided by ``√C``.
    """
    B, C, h, w = source.shape
    corr = source.flatten(2).transpose(1, 2) @ target.flatten(2) / C**0.5  # (B, hw, hw)
    pyramid = [corr.reshape(B * h * w, 1, h, w)]
    for _ in range(levels - 1):
        pyramid.append(F.avg_pool2d(pyramid[-1], 2, 2))
    return pyramid


def lookup(pyramid: list[torch.Tensor], coords: torch.Tensor, radius: int) -> torch.Tensor:
    """Correlation values in a ``(2r+1)²`` window around ``coords`` at every level (RAFT Sec. 3.2).

    Args:
        pyramid: from :func:`correlation_pyramid`.
        coords: ``(B, 2, h, w)`` target positions (x, y) in 1/8-resolution pixels.

    Returns:
        ``(B, levels·(2r+1)², h, w)``.
    """
    B, _, h, w = coords.shape
    d = torch.arange(-radius, radius + 1, dtype=coords.dtype, device=coords.device)
    dy, dx = torch.meshgrid(d, d, indexing="ij")
    delta = torch.stack([dx, dy], dim=-1).view(1, 2 * radius + 1, 2 * radius + 1, 2)
    centre = coords.permute(0, 2, 3, 1).reshape(B * h * w, 1, 1, 2)
    out = []
    for level, corr in enumerate(pyramid):
        xy = centre / 2**level + delta
        h_c, w_c = corr.shape[-2:]  # pixel i's centre is at (2i + 1) / size − 1 (align_corners=False)
        grid = torch.stack([(2 * xy[..., 0] + 1) / w_c - 1, (2 * xy[..., 1] + 1) / h_c - 1], dim=-1)
        sampled = F.grid_sample(corr, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
        out.append(sampled.view(B, h, w, -1))
    return torch.cat(out, dim=-1).permute(0, 3, 1, 2)


class ConvGRU(nn.Module):
    """``h' = (1 − z) h + z q`` with 3x3 convolutions for the gates (RAFT Sec. 3.3)."""

    def __init__(self, hidden: int, inputs: int) -> None:
        super().__init__()
        self.z = nn.Conv2d(hidden + inputs, hidden, 3, padding=1)
        self.r = nn.Conv2d(hidden + inputs, hidden, 3, padding=1)
        self.q = nn.Conv2d(hidden + inputs, hidden, 3, padding=1)

    def forward(self, h: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        hx = torch.cat([h, x], dim=1)
        z, r = torch.sigmoid(self.z(hx)), torch.sigmoid(self.r(hx))
        q = torch.tanh(self.q(torch.cat([r * h, x], dim=1)))
        return (1 - z) * h + z * q


class UpdateBlock(nn.Module):
    """Motion features (correlation + current flow model) → GRU → increment of the flow model."""

    def __init__(self, config: FlowConfig) -> None:
        super().__init__()
        corr = 2 * config.levels * (2 * config.radius + 1) ** 2  # the learned and the edge volume
        self.motion = nn.Sequential(
            nn.Conv2d(corr + 4, 64, 3, padding=1), nn.ReLU(inplace=True), nn.Conv2d(64, 60, 3, padding=1)
        )
        self.gru = ConvGRU(config.hidden_dim, 64 + config.context_dim)
        self.head = nn.Sequential(
            nn.Conv2d(config.hidden_dim, 64, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(64, 4, 3, padding=1),
        )

    def forward(
        self, h: torch.Tensor, context: torch.Tensor, corr: torch.Tensor, model: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One step: ``model (B, 4, h, w)`` is the current ``(a, b)``; returns the new state and
        the increment of ``(a, b)``."""
        motion = torch.cat([F.relu(self.motion(torch.cat([corr, model], dim=1))), model], dim=1)
        h = self.gru(h, torch.cat([motion, context], dim=1))
        return h, self.head(h)


class FlowNet(nn.Module):
    """LiDAR image + RGB image → flow from the first to the second, at full resolution.

    Any input size works: inputs are padded to a multiple of 8 and the flow cropped back.
    """

    def __init__(self, config: FlowConfig = FlowConfig()) -> None:
        super().__init__()
        self.config = config
        self.image_encoder = Encoder(3, config.feature_dim, norm=True)
        self.lidar_encoder = Encoder(len(LIDAR_CHANNELS), config.feature_dim, norm=True)
        self.context_encoder = Encoder(
            len(LIDAR_CHANNELS), config.hidden_dim + config.context_dim, norm=False
        )
        self.update = UpdateBlock(config)

    def contract(self, near_m: float, working_focal_px: float) -> Contract:
        """The export contract: the image as the support predictor's, the LiDAR image in ``extra``."""
        return Contract(
            stride=STRIDE,
            target="flow",
            output="flow",
            extra={
                "near_m": near_m,
                "working_focal_px": working_focal_px,
                "lidar_channels": list(LIDAR_CHANNELS),
            },
        )

    def forward(self, image: torch.Tensor, lidar: torch.Tensor, all_iterations: bool = False):
        """Flow of every LiDAR pixel.

        Args:
            image: ``(B, 3, H, W)`` normalised RGB (see the contract).
            lidar: ``(B, 5, H, W)`` from :func:`lidar_input`.
            all_iterations: return every refinement step's flow (training), not only the last.

        Returns:
            ``(B, 2, H, W)`` pixels (x, y), or a list of them, one per iteration.
        """
        H, W = image.shape[-2:]
        pad = (0, (-W) % STRIDE, 0, (-H) % STRIDE)
        image, lidar = F.pad(image, pad), F.pad(lidar, pad)
        pyramid = correlation_pyramid(
            self.lidar_encoder(lidar), self.image_encoder(image), self.config.levels
        )
        edges = correlation_pyramid(
            edge_features(lidar[:, 3:5]), edge_features(image_orientation(image)), self.config.levels
        )
        hidden, context = self.context_encoder(lidar).split(
            [self.config.hidden_dim, self.config.context_dim], 1
        )
        h, context = torch.tanh(hidden), F.relu(context)
        B, _, h8, w8 = context.shape
        ys, xs = torch.meshgrid(
            torch.arange(h8, dtype=image.dtype, device=image.device),
            torch.arange(w8, dtype=image.dtype, device=image.device),
            indexing="ij",
        )
        base = torch.stack([xs, ys]).unsqueeze(0)
        rho = lidar[:, 1:2]  # near_m / depth, 0 where no point
        rho_cell = F.avg_pool2d(rho, STRIDE) / F.avg_pool2d(lidar[:, :1], STRIDE).clamp_min(1e-6)
        model = torch.zeros(B, 4, h8, w8, dtype=image.dtype, device=image.device)  # (a, b)
        flows = []
        for step in range(self.config.iterations):
            flow = model[:, :2] + model[:, 2:] * rho_cell  # the cell's mean point, 1/8 pixels
            corr = torch.cat(
                [lookup(volume, base + flow, self.config.radius) for volume in (pyramid, edges)], 1
            )
            h, delta = self.update(h, context, corr, model)
            model = model + delta
            if all_iterations or step == self.config.iterations - 1:
                up = F.interpolate(model, scale_factor=STRIDE, mode="bilinear", align_corners=False)
                flows.append((STRIDE * (up[:, :2] + up[:, 2:] * rho))[..., :H, :W])
        return flows if all_iterations else flows[-1]
