"""Pinhole projection, z-buffer visibility and depth/intensity images of a LiDAR scan.

Pixels are ``(u, v)`` = (column, row) with the origin at the centre of the top-left pixel, so the
pixel holding ``(u, v)`` is ``(round(v), round(u))``. ``K`` is the 3x3 pinhole matrix of the
undistorted image (DESIGN.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

__all__ = [
    "MISSING_RETURN_M",
    "ProjectedScan",
    "measured",
    "Visibility",
    "project_points",
    "project_scan",
    "render_image",
    "transform_points",
    "unproject_points",
    "zbuffer_visibility",
]


def transform_points(T_a_b: torch.Tensor, points_b: torch.Tensor) -> torch.Tensor:
    """Apply ``T_a_b (..., 4, 4)`` to ``points_b (..., N, 3)``; returns ``points_a (..., N, 3)``."""
    if T_a_b.shape[-2:] != (4, 4) or points_b.shape[-1] != 3:
        raise ValueError(
            f"expected T (..., 4, 4) and points (..., N, 3), got {tuple(T_a_b.shape)} "
            f"and {tuple(points_b.shape)}"
        )
    R = T_a_b[..., :3, :3]
    t = T_a_b[..., None, :3, 3]
    return points_b @ R.transpose(-1, -2) + t


def project_points(
    points_cam: torch.Tensor, K: torch.Tensor, eps: float = 1e-6
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pinhole projection ``u = π(K, p)``.

    Args:
        points_cam: ``(..., N, 3)`` points in the camera frame (z forward).
        K: ``(..., 3, 3)`` intrinsics.
        eps: depth floor that keeps the division finite; callers mask ``depth <= 0`` themselves.

    Returns:
        ``uv (..., N, 2)`` pixels and ``depth (..., N)`` (the camera-frame z).
    """
    if points_cam.shape[-1] != 3 or K.shape[-2:] != (3, 3):
        raise ValueError(
            f"expected points (..., N, 3) and K (..., 3, 3), got {tuple(points_cam.shape)} "
            f"and {tuple(K.shape)}"
        )
    depth = points_cam[..., 2]
    xy = points_cam[..., :2] / depth.clamp(min=eps)[..., None]
    uv = xy @ K[..., :2, :2].transpose(-1, -2) + K[..., None, :2, 2]
    return uv, depth


def unproject_points(uv: torch.Tensor, depth: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`project_points`: ``uv (..., N, 2)``, ``depth (..., N)`` -> ``(..., N, 3)``."""
    if uv.shape[-1] != 2 or uv.shape[:-1] != depth.shape:
        raise ValueError(
            f"expected uv (..., N, 2) and depth (..., N), got {tuple(uv.shape)}, {tuple(depth.shape)}"
        )
    ones = torch.ones_like(uv[..., :1])
    rays = torch.cat([uv, ones], dim=-1) @ torch.linalg.inv(K).transpose(-1, -2)
    return rays * depth[..., None]


@dataclass(frozen=True)
class Visibility:
    """Parameters of the windowed z-buffer test.

    A point is hidden when a point within ``window x window`` pixels is nearer by more than
    ``max(rel_tol · depth, abs_tol)``: a one-pixel z-buffer would let background points leak
    through the gaps between the sparse returns of a nearer surface.
    """

    window: int = 5
    rel_tol: float = 0.1
    abs_tol: float = 0.2
    min_depth: float = 0.5

    def __post_init__(self) -> None:
        if self.window < 1 or self.window % 2 == 0:
            raise ValueError(f"window must be an odd positive number of pixels, got {self.window}")


def _pixel_index(uv: torch.Tensor, image_size: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Flat pixel index of each ``uv (N, 2)`` and whether it falls inside ``image_size=(H, W)``."""
    H, W = image_size
    col = torch.round(uv[:, 0]).long()
    row = torch.round(uv[:, 1]).long()
    inside = (col >= 0) & (col < W) & (row >= 0) & (row < H)
    return row.clamp(0, H - 1) * W + col.clamp(0, W - 1), inside


def pixel_lookup(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Values of ``image (H, W, ...)`` at the nearest pixel of each ``uv (N, 2)`` (rounded as the
    z-buffer rounds), clipped to the border.

    Returns:
        ``(N, ...)``.
    """
    H, W = image.shape[:2]
    col = np.clip(np.rint(uv[:, 0]).astype(np.int64), 0, W - 1)
    row = np.clip(np.rint(uv[:, 1]).astype(np.int64), 0, H - 1)
    return image[row, col]


def _min_depth_image(
    flat: torch.Tensor, depth: torch.Tensor, valid: torch.Tensor, image_size: tuple[int, int]
) -> torch.Tensor:
    """Per-pixel nearest depth ``(H*W,)``, ``inf`` where no valid point lands."""
    H, W = image_size
    zbuf = torch.full((H * W,), float("inf"), dtype=depth.dtype, device=depth.device)
    return zbuf.scatter_reduce(0, flat[valid], depth[valid], reduce="amin")


def zbuffer_visibility(
    uv: torch.Tensor,
    depth: torch.Tensor,
    image_size: tuple[int, int],
    visibility: Visibility = Visibility(),
) -> torch.Tensor:
    """Which projected points the camera sees: in front, inside the image, and not occluded.

    Args:
        uv: ``(N, 2)`` projected pixels.
        depth: ``(N,)`` camera-frame depths.
        image_size: ``(H, W)``.
        visibility: window and tolerances of the occlusion test.

    Returns:
        ``(N,)`` boolean mask.
    """
    if uv.ndim != 2 or uv.shape[-1] != 2 or depth.shape != uv.shape[:1]:
        raise ValueError(f"expected uv (N, 2) and depth (N,), got {tuple(uv.shape)}, {tuple(depth.shape)}")
    H, W = image_size
    flat, inside = _pixel_index(uv, image_size)
    valid = inside & (depth > visibility.min_depth) & torch.isfinite(depth)
    zbuf = _min_depth_image(flat, depth, valid, image_size).view(1, 1, H, W)
    pad = visibility.window // 2
    local_min = -F.max_pool2d(-zbuf, visibility.window, stride=1, padding=pad).view(-1)
    tol = torch.clamp(depth * visibility.rel_tol, min=visibility.abs_tol)
    return valid & (depth <= local_min[flat] + tol)


def render_image(
    uv: torch.Tensor,
    depth: torch.Tensor,
    image_size: tuple[int, int],
    values: torch.Tensor | None = None,
) -> torch.Tensor:
    """Sparse image of a projected scan: at each pixel, the value of its nearest point.

    Args:
        uv: ``(N, 2)`` pixels of points already known visible (see :func:`zbuffer_visibility`).
        depth: ``(N,)`` depths, used to pick the nearest point per pixel.
        image_size: ``(H, W)``.
        values: ``(N,)`` or ``(N, C)`` what to draw (e.g. intensity); the depth itself when ``None``.

    Returns:
        ``(H, W)`` image (``(H, W, C)`` for ``(N, C)`` values), zero where no point lands.
    """
    H, W = image_size
    values = depth if values is None else values
    flat, inside = _pixel_index(uv, image_size)
    zbuf = _min_depth_image(flat, depth, inside, image_size)
    winner = inside & (depth == zbuf[flat])
    image = torch.zeros(H * W, *values.shape[1:], dtype=values.dtype, device=values.device)
    image[flat[winner]] = values[winner]
    return image.view(H, W, *values.shape[1:])


@dataclass(frozen=True)
class ProjectedScan:
    """The visible part of a scan under one extrinsic (numpy, float64 pixels).

    Attributes:
        index: ``(M,)`` indices into the scan's points.
        uv: ``(M, 2)`` sub-pixel image coordinates.
        depth: ``(M,)`` camera-frame depth in metres.
        intensity: ``(M,)`` the scan's fourth column.
        image_size: ``(H, W)``.
    """

    index: np.ndarray
    uv: np.ndarray
    depth: np.ndarray
    intensity: np.ndarray
    image_size: tuple[int, int]

    def depth_image(self) -> np.ndarray:
        """``(H, W)`` float32 depth of the nearest point per pixel, 0 where none."""
        return self._render(None)

    def intensity_image(self) -> np.ndarray:
        """``(H, W)`` float32 intensity of the nearest point per pixel, 0 where none."""
        return self._render(self.intensity)

    def depth_and_intensity_images(self) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`depth_image` and :meth:`intensity_image` from one z-buffer (the same pixels win)."""
        both = self._render(np.column_stack([self.depth, self.intensity]))
        return both[..., 0], both[..., 1]

    def _render(self, values: np.ndarray | None) -> np.ndarray:
        v = None if values is None else torch.as_tensor(values, dtype=torch.float64)
        img = render_image(torch.as_tensor(self.uv), torch.as_tensor(self.depth), self.image_size, v)
        return img.numpy().astype(np.float32)


MISSING_RETURN_M = 0.1
"""A return nearer the LiDAR's centre than this is a missing one: organised clouds (Ouster's
drivers, many converters) keep a missing return in its place as (0, 0, 0) or at its beam's origin
a few centimetres off the centre. No LiDAR measures this near (minimum ranges: 0.1 m for a Livox
Mid-360, 0.25–1 m for spinning ones)."""


def measured(points_lidar: np.ndarray) -> np.ndarray:
    """``(N,)`` bool: the returns of ``points_lidar (N, 3+)`` that are not missing ones
    (:data:`MISSING_RETURN_M`)."""
    xyz = np.asarray(points_lidar, np.float64)[:, :3]
    return np.einsum("ij,ij->i", xyz, xyz) >= MISSING_RETURN_M**2


def project_scan(
    points_lidar: np.ndarray,
    T_cam_lidar: np.ndarray,
    K: np.ndarray,
    image_size: tuple[int, int],
    visibility: Visibility | None = Visibility(),
) -> ProjectedScan:
    """Project a scan ``(N, 4)`` (x, y, z, intensity) and keep the points the camera sees.

    Args:
        points_lidar: ``(N, 3)`` or ``(N, 4)`` points in the LiDAR frame.
        T_cam_lidar: ``(4, 4)`` extrinsic.
        K: ``(3, 3)`` intrinsics.
        image_size: ``(H, W)``.
        visibility: occlusion test; ``None`` keeps every point in front of the camera and inside
            the image (no occlusion handling).

    Missing returns (within :data:`MISSING_RETURN_M` of the LiDAR's centre) are never kept: where
    the LiDAR's centre lies in view, thousands of them would fall on one pixel.
    """
    points = np.asarray(points_lidar, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] < 3:
        raise ValueError(f"points_lidar must be (N, 3) or (N, 4), got {tuple(points.shape)}")
    T_cam_lidar = np.asarray(T_cam_lidar, np.float64)
    min_depth = (visibility or Visibility()).min_depth
    # only points ahead of the camera can be seen (half of a 360° scan): their depth alone
    # first, with a margin for its rounding, and the projection of those; the exact test decides
    ahead = np.flatnonzero(points[:, :3] @ T_cam_lidar[2, :3] + T_cam_lidar[2, 3] > min_depth - 1e-6)
    ahead = ahead[measured(points[ahead])]
    pts = torch.as_tensor(points[ahead])
    points_cam = transform_points(torch.as_tensor(T_cam_lidar), pts[:, :3])
    uv, depth = project_points(points_cam, torch.as_tensor(np.asarray(K, np.float64)))
    if visibility is None:
        _, inside = _pixel_index(uv, image_size)
        mask = inside & (depth > min_depth)
    else:
        mask = zbuffer_visibility(uv, depth, image_size, visibility)
    index = torch.nonzero(mask).view(-1)
    intensity = pts[:, 3] if pts.shape[1] > 3 else torch.zeros(len(pts), dtype=pts.dtype)
    return ProjectedScan(
        index=ahead[index.numpy()],
        uv=uv[index].numpy(),
        depth=depth[index].numpy(),
        intensity=intensity[index].numpy(),
        image_size=(int(image_size[0]), int(image_size[1])),
    )
