"""The training-free Stage 2 matcher: LiDAR edges against image edges, searched densely.

Both modalities become an *orientation field* ``e · (cos 2θ, sin 2θ)`` (edge strength ``e`` and
doubled edge angle ``2θ``, so an edge matches whatever its contrast polarity): on the LiDAR side
from the log-depth and intensity images of the projected scan (depth discontinuities between
neighbouring returns, and the silhouette against no-return sky), on the image side from the grey
gradient. A correlation cost volume ``C(x, d) = Σ_{y∈W(x)} ⟨L(y), I(y + d)⟩`` over a window ``W``
is computed for every pixel at once, coarse to fine on a pyramid (as PWC-Net and RAFT do for
flow); the peak, refined to sub-pixel by a parabola, is the flow ``f`` from the projected LiDAR
image to the RGB image. Each visible point reads the flow at its pixel.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field, NonNegativeFloat
from scipy import ndimage

from calib.data.types import Frame
from calib.features import level_laser_gains, ring_spacing_deg
from calib.match.correspondences import Correspondences, working_view
from calib.projection import ProjectedScan, Visibility, project_scan

__all__ = ["EdgeMatcher", "EdgeMatcherConfig", "image_edges", "lidar_edges", "lidar_field"]


class EdgeMatcherConfig(BaseModel):
    """Parameters of :class:`EdgeMatcher`; pixel sizes refer to the working resolution."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    working_focal_px: float = Field(
        360.0,
        gt=0,
        description="images with a longer focal length are resampled down to it, so the "
        "pixel parameters below mean the same angles on every camera (KITTI at half resolution)",
    )
    fill_radius_deg: float = Field(
        0.42,
        gt=0,
        description="a pixel farther than this from every return is 'no return' (sky) "
        "when the LiDAR looks there; about one ring spacing, so a silhouette against the sky "
        "falls half a spacing beyond the last return, where the true edge lies on average "
        "(KITTI's HDL-64: 0.4°); a scan whose rings lie farther apart uses its own median "
        "spacing (nuScenes' 32 rings: 1.33°), else its pixels between rings would read as sky",
    )
    far_depth_m: float = Field(200.0, gt=0, description="depth given to no-return pixels")
    depth_edge_px: tuple[NonNegativeFloat, NonNegativeFloat] = Field(
        (0.04, 0.2),
        description="|∇ log depth| per pixel where a depth edge starts and is full "
        "(ground seen at a grazing angle stays below the start)",
    )
    intensity_edge_px: float = Field(0.08, gt=0, description="|∇ intensity| per pixel of a full edge")
    intensity_weight: float = Field(0.5, ge=0, description="intensity edges relative to depth edges")
    level_laser_gains: bool = Field(
        True,
        description="level each laser's intensity gain to its neighbours' before drawing intensity "
        "edges (:func:`calib.features.level_laser_gains`; scans stored line by line only)",
    )
    image_blur_px: float = Field(0.7, ge=0, description="Gaussian σ before the image gradient")
    highpass_px: float = Field(3.0, gt=0, description="σ of the local mean removed from both fields")
    levels: int = Field(3, ge=1, le=5, description="pyramid levels, each half the previous size")
    search_radius: int = Field(3, ge=1, description="search radius at the coarsest level (its pixels)")
    refine_radius: int = Field(2, ge=1, description="search radius at each finer level")
    window: int = Field(31, ge=3, description="aggregation window (odd, pixels of each level)")
    smooth_window: int = Field(
        121,
        ge=1,
        description="window of the final local flow model a + b/z, fitted to "
        "the confidence-weighted estimates (odd)",
    )
    min_signal: float = Field(
        0.05,
        ge=0,
        description="a point gets a residual when the mean LiDAR edge strength in its window reaches this",
    )
    sharpness_scale: float = Field(0.02, gt=0, description="peak curvature giving confidence 1/2")
    min_confidence: float = Field(
        0.2,
        ge=0,
        le=1,
        description="a point gets a residual when its confidence reaches this too (about half the "
        "points; on still synthetic frames it takes the rigid-class median error from 0.55 to 0.45 px)",
    )

    def model_post_init(self, __context: object) -> None:
        if self.window % 2 == 0:
            raise ValueError(f"window must be odd, got {self.window}")
        if self.depth_edge_px[1] <= self.depth_edge_px[0]:
            raise ValueError(f"depth_edge_px: the full edge must exceed the start, got {self.depth_edge_px}")


def _orientation_field(gx: np.ndarray, gy: np.ndarray, strength: np.ndarray) -> np.ndarray:
    """``strength · (cos 2θ, sin 2θ)`` of the gradient ``(gx, gy)``; ``(2, H, W)`` float32."""
    m2 = gx * gx + gy * gy + 1e-12
    return np.stack([(gx * gx - gy * gy) / m2, 2 * gx * gy / m2]).astype(np.float32) * strength


def _gradient(image: np.ndarray, blur_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel derivatives (Sobel / 8) of ``image (H, W)`` after a Gaussian blur; and magnitude."""
    image = image.astype(np.float32)
    if blur_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), blur_px)
    gx = cv2.Sobel(image, cv2.CV_32F, 1, 0) / 8
    gy = cv2.Sobel(image, cv2.CV_32F, 0, 1) / 8
    return gx, gy, np.hypot(gx, gy)


def image_edges(image: np.ndarray, config: EdgeMatcherConfig = EdgeMatcherConfig()) -> np.ndarray:
    """Orientation field of an RGB image.

    The strength ``m² / (m² + c²)`` with ``c`` the median gradient saturates, so the contrast of
    an edge matters less than its position (LiDAR edges carry no image contrast).

    Args:
        image: ``(H, W, 3)`` uint8 RGB.

    Returns:
        ``(2, H, W)`` float32.
    """
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255
    gx, gy, m = _gradient(grey, config.image_blur_px)
    c = max(float(np.median(m)), 1e-4)
    return _orientation_field(gx, gy, m**2 / (m**2 + c**2))


def _lidar_sees(
    points_lidar: np.ndarray,
    T_cam_lidar: np.ndarray,
    K: np.ndarray,
    image_size: tuple[int, int],
    margin_deg: float,
) -> np.ndarray:
    """``(H, W)`` bool: pixels whose ray lies within the scan's elevation range (seen from the
    LiDAR), where a missing return means open sky rather than a pixel outside the LiDAR's view."""
    xyz = points_lidar[::7, :3].astype(np.float64)  # a subsample bounds the elevation range
    elevation = np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
    top, bottom = np.percentile(elevation, [99.9, 0.1]) if len(xyz) else (0.0, 0.0)
    H, W = image_size
    # ray of pixel (u, v) in the LiDAR frame: R_lidar_cam · K⁻¹ [u, v, 1]ᵀ, by broadcasting
    M = (T_cam_lidar[:3, :3].T @ np.linalg.inv(K)).astype(np.float32)
    u = np.arange(W, dtype=np.float32)[None, :]
    v = np.arange(H, dtype=np.float32)[:, None]
    x, y, z = (M[i, 0] * u + M[i, 1] * v + M[i, 2] for i in range(3))
    ray_elevation = np.degrees(np.arctan2(z, np.hypot(x, y)))
    return (ray_elevation < top - margin_deg) & (ray_elevation > bottom + margin_deg)


def lidar_edges(
    scan: ProjectedScan,
    points_lidar: np.ndarray,
    T_cam_lidar: np.ndarray,
    K: np.ndarray,
    config: EdgeMatcherConfig = EdgeMatcherConfig(),
) -> tuple[np.ndarray, np.ndarray]:
    """Orientation field of a projected scan: depth and intensity edges between returns.

    Every pixel takes the depth and intensity of its nearest visible return (a Voronoi fill, so
    a discontinuity falls midway between the last foreground and the first background return);
    pixels farther than the fill radius from any return, where the LiDAR looks, are open sky at
    ``far_depth_m``. Outside the LiDAR's view the field is zero.

    Args:
        scan: visible points under ``T_cam_lidar`` (:func:`~calib.projection.project_scan`).
        points_lidar: ``(N, 3+)`` the whole scan (its elevation range bounds the LiDAR's view).
        T_cam_lidar: ``(4, 4)``. K: ``(3, 3)`` of the image the scan was projected into.

    Returns:
        ``field (2, H, W)`` float32 and ``inverse_depth (H, W)`` float32 of the nearest return
        (0 in open sky).
    """
    H, W = scan.image_size
    if len(scan.index) == 0:
        return np.zeros((2, H, W), np.float32), np.zeros((H, W), np.float32)
    ids = np.full((H, W), -1, np.int64)
    far_first = np.argsort(-scan.depth)  # the nearest return of a pixel is written last
    rc = np.rint(scan.uv[far_first, ::-1]).astype(int)
    ids[rc[:, 0], rc[:, 1]] = far_first
    dist = ndimage.distance_transform_edt(ids < 0)
    fill_deg = max(config.fill_radius_deg, ring_spacing_deg(points_lidar))
    fill_px = K[0, 0] * np.tan(np.radians(fill_deg))
    sees = _lidar_sees(points_lidar, T_cam_lidar, K, (H, W), fill_deg)
    # open sky seeds a Voronoi cell of its own, so an object's silhouette against the sky falls
    # midway between its last return and the sky, not at the fill radius
    sky = len(scan.depth)
    ids[(dist > fill_px) & sees] = sky
    _, (ri, ci) = ndimage.distance_transform_edt(ids < 0, return_indices=True)
    nearest = ids[ri, ci]
    depth = np.append(scan.depth, config.far_depth_m)
    intensity = np.append(scan.intensity / max(float(np.percentile(scan.intensity, 99)), 1e-6), 0.0)
    log_depth, intensity = np.log(depth[nearest]), intensity[nearest]

    gx, gy, m = _gradient(log_depth, 0.7)
    start, full = config.depth_edge_px
    field = _orientation_field(gx, gy, np.clip((m - start) / (full - start), 0, 1))
    gx, gy, m = _gradient(np.clip(intensity, 0, 1), 0.7)
    field += config.intensity_weight * _orientation_field(gx, gy, np.clip(m / config.intensity_edge_px, 0, 1))
    inverse_depth = np.append(1.0 / scan.depth, 0.0)[nearest].astype(np.float32)
    return field * ((dist <= fill_px + 1) | sees), inverse_depth


def _splat(values: np.ndarray, uv: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Forward-warp ``values (C, N)`` to sub-pixel positions ``uv (N, 2)`` by bilinear splatting,
    normalised where several land on one pixel; ``(C, H, W)`` float32, zero where none lands."""
    H, W = image_size
    base = np.floor(uv).astype(np.int64)
    frac = (uv - base).astype(np.float32)
    out = np.zeros((len(values), H * W), np.float32)
    weight = np.zeros(H * W, np.float32)
    for dv in (0, 1):
        for du in (0, 1):
            w = (frac[:, 0] if du else 1 - frac[:, 0]) * (frac[:, 1] if dv else 1 - frac[:, 1])
            col, row = base[:, 0] + du, base[:, 1] + dv
            inside = (col >= 0) & (col < W) & (row >= 0) & (row < H) & (w > 0)
            flat = row[inside] * W + col[inside]
            np.add.at(weight, flat, w[inside])
            for c in range(len(values)):
                np.add.at(out[c], flat, w[inside] * values[c, inside])
    return (out / np.maximum(weight, 1.0)).reshape(len(values), H, W)


def lidar_field(
    points_lidar: np.ndarray,
    T_cam_lidar: np.ndarray,
    K: np.ndarray,
    image_size: tuple[int, int],
    config: EdgeMatcherConfig = EdgeMatcherConfig(),
) -> tuple[np.ndarray, np.ndarray]:
    """The LiDAR's orientation field as the camera sees it, free of the parallax between the
    two sensors.

    The camera sits elsewhere than the LiDAR (27 cm ahead on KITTI), so beside every near object
    it sees a strip of background that the LiDAR's rays never reached. Drawn in the camera's
    image (:func:`lidar_edges` on the camera's projection), such a strip reads as open sky or as
    background pulled over it, and its far border becomes an edge the image does not have, on the
    side of the object away from the camera's offset: read by a refinement as a translation
    (1.2 cm along the optical axis on the synthetic urban world, started from the truth; 0.6 cm
    with this field). So the field is built in a virtual camera at the LiDAR's centre, with the
    camera's orientation and ``K`` (there no return hides another), and every edge pixel ``ũ``
    is carried into the camera at the depth ``z`` of its nearer side: ``u' = π(K, z·K⁻¹ũ + t)``.
    The strips stay empty, as nothing was measured there.

    Args:
        points_lidar: ``(N, 3+)`` the scan. T_cam_lidar: ``(4, 4)``. K: ``(3, 3)``.
        image_size: ``(H, W)``.

    Returns:
        ``field (2, H, W)`` float32 and ``inverse_depth (H, W)`` of the nearest return (virtual view).
    """
    T_centre = np.array(T_cam_lidar, np.float64)
    T_centre[:3, 3] = 0.0
    levelled = level_laser_gains(points_lidar) if config.level_laser_gains else points_lidar
    scan = project_scan(levelled, T_centre, K, image_size, None)
    field, inverse_depth = lidar_edges(scan, points_lidar, T_centre, K, config)
    rows, cols = np.nonzero(np.abs(field).sum(0) > 0)
    # the nearer side of an edge: the largest inverse depth around it (0 in open sky: no parallax)
    nearer = ndimage.maximum_filter(inverse_depth, size=5)[rows, cols].astype(np.float64)
    rays = np.linalg.inv(K) @ np.stack([cols, rows, np.ones_like(cols)]).astype(np.float64)
    t = np.asarray(T_cam_lidar, np.float64)[:3, 3, None]
    uvw = K @ (rays + t * nearer)  # K (z·ray + t) / z: the same direction up to scale
    ahead = uvw[2] > 0
    uv = uvw[:2, ahead] / uvw[2, ahead]
    return _splat(field[:, rows[ahead], cols[ahead]], uv.T, image_size), inverse_depth


def _box_1d(x: torch.Tensor, k: int, dim: int) -> torch.Tensor:
    """Mean over a centred run of ``k`` samples along ``dim`` (fewer at the borders), by a
    cumulative sum: the cost does not grow with ``k``."""
    n, r = x.shape[dim], k // 2
    pad = [0, 0] * (x.ndim - 1 - dim % x.ndim) + [r + 1, r]
    c = F.pad(x, pad).cumsum(dim)
    total = c.narrow(dim, k, n) - c.narrow(dim, 0, n)
    i = torch.arange(n)
    count = ((i + r).clamp(max=n - 1) - (i - r).clamp(min=0) + 1).to(x.dtype)
    view = [1] * x.ndim
    view[dim] = n
    return total / count.view(view)


def _box(x: torch.Tensor, k: int) -> torch.Tensor:
    """Mean over a ``k x k`` window of ``x (C, H, W)`` (clipped at the borders), same size out."""
    return _box_1d(_box_1d(x, k, -1), k, -2)


def _downsample(x: np.ndarray) -> np.ndarray:
    """Next pyramid level of ``x (C, H, W)``: Gaussian blur (σ = 1 px) then 2x2 mean, so the
    coarse field stays smooth enough for a sub-pixel peak; odd sizes round up."""
    _, H, W = x.shape
    blurred = np.stack([cv2.GaussianBlur(c, (5, 5), 1.0, borderType=cv2.BORDER_REPLICATE) for c in x])
    padded = np.pad(blurred, ((0, 0), (0, H % 2), (0, W % 2)), mode="edge")
    return 0.25 * (
        padded[:, 0::2, 0::2] + padded[:, 1::2, 0::2] + padded[:, 0::2, 1::2] + padded[:, 1::2, 1::2]
    )


def _correlate(lidar: torch.Tensor, image: torch.Tensor, radius: int) -> torch.Tensor:
    """``(D, H, W)`` per-pixel ⟨L(y), I(y + d)⟩ for the ``D = (2r+1)²`` displacements ``d``,
    row-major over ``(dv, du)`` from ``(−r, −r)``."""
    _, H, W = lidar.shape
    padded = F.pad(image, (radius, radius, radius, radius))
    n = 2 * radius + 1
    return torch.stack(
        [(lidar * padded[:, dv : dv + H, du : du + W]).sum(0) for dv in range(n) for du in range(n)]
    )


def _normalised_cost(lidar: torch.Tensor, image: torch.Tensor, radius: int, window: int) -> torch.Tensor:
    """``(D, H, W)`` window-aggregated correlation divided by the RMS of the image field in the
    displaced window. Without the division the peak leans toward displacements whose window
    holds more image edges (Cauchy–Schwarz bounds the correlation by that energy, not by the
    match); with it, a field matched against itself peaks exactly at zero."""
    energy = _box(image.pow(2).sum(0, keepdim=True), window)
    rms = _correlate(torch.ones_like(energy), energy, radius).clamp(min=1e-12).sqrt()
    return _box(_correlate(lidar, image, radius), window) / (rms + 1e-3)


def _warp(image: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """``image (C, H, W)`` sampled at ``x + flow(x)``; ``flow (2, H, W)`` as ``(du, dv)``."""
    _, H, W = image.shape
    v, u = torch.meshgrid(torch.arange(H, dtype=flow.dtype), torch.arange(W, dtype=flow.dtype), indexing="ij")
    grid = torch.stack([(u + flow[0]) * 2 / max(W - 1, 1) - 1, (v + flow[1]) * 2 / max(H - 1, 1) - 1], -1)
    return F.grid_sample(image[None], grid[None], align_corners=True, padding_mode="zeros")[0]


def _peak(cost: torch.Tensor, radius: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Sub-pixel peak of a cost volume ``(D, H, W)``.

    Returns:
        ``offset (2, H, W)`` as ``(du, dv)``, ``peak (H, W)``, and the curvatures across the peak
        along u and v ``(H, W)`` (zero where the peak lies on the search border).
    """
    n = 2 * radius + 1
    peak, best = cost.max(0)
    bv, bu = best // n - radius, best % n - radius
    offsets, curvatures = [], []
    for b, step in ((bu, 1), (bv, n)):
        inner = b.abs() < radius
        lo = cost.gather(0, (best - step).clamp(0, n * n - 1)[None])[0]
        hi = cost.gather(0, (best + step).clamp(0, n * n - 1)[None])[0]
        curvature = torch.where(inner, 2 * peak - lo - hi, torch.zeros_like(peak))
        # parabola through (−1, lo), (0, peak), (1, hi): vertex at (hi − lo) / (2 (2 peak − lo − hi))
        sub = torch.where(curvature > 0, (hi - lo) / (2 * curvature.clamp(min=1e-12)), torch.zeros_like(peak))
        offsets.append(b + sub.clamp(-0.5, 0.5))
        curvatures.append(curvature)
    return torch.stack(offsets), peak, curvatures[0], curvatures[1]


def _depth_model_fit(
    flow: torch.Tensor, weight: torch.Tensor, inverse_depth: torch.Tensor, window: int, ridge: float = 1e-4
) -> torch.Tensor:
    """Per pixel, the weighted least-squares fit of ``f(y) = a + b / z(y)`` to the flow estimates
    in a window around it, evaluated at the pixel.

    A small extrinsic error moves a point at depth ``z`` by a rotation part that varies slowly
    over the image plus a translation part proportional to ``1 / z`` (the pinhole model to first
    order), so the model averages the estimates of many edges, which the LiDAR's ring spacing
    localises only to a pixel or so each, without mixing near and far objects, whose
    displacements differ. ``ridge`` keeps ``b`` at zero where the window holds one depth. (A
    model also linear in ``(u, v)`` measured worse: its extra terms cost more in variance than
    they gain in bias.)

    Args:
        flow: ``(2, H, W)`` per-pixel estimates. weight: ``(H, W)``. inverse_depth: ``(H, W)``.
    """
    q = inverse_depth
    w = weight + 1e-6
    s_w, s_q, s_qq = (_box(x[None], window)[0] for x in (w, w * q, w * q * q))
    s_f, s_qf = _box(w * flow, window), _box(w * q * flow, window)
    # centred normal equations of [1, q]: slope b, then intercept a = mean f − b · mean q
    mean_q, mean_f = s_q / s_w, s_f / s_w
    var_q = s_qq / s_w - mean_q**2
    b = (s_qf / s_w - mean_q * mean_f) / (var_q + ridge)
    return mean_f + b * (q - mean_q)


def _confidence(
    peak: torch.Tensor, curv_u: torch.Tensor, curv_v: torch.Tensor, signal: torch.Tensor, scale: float
) -> torch.Tensor:
    """``(H, W)`` in [0, 1]: the share of the window's LiDAR edge energy the peak aligns with image
    edges, times the peak's sharpness in its flattest direction (zero on a single straight edge,
    where the aperture problem leaves the displacement along the edge undetermined)."""
    norm = signal.clamp(min=1e-6)
    quality = (peak / norm).clamp(0, 1)
    sharpness = torch.minimum(curv_u, curv_v).clamp(min=0) / norm
    return quality * sharpness / (sharpness + scale)


class EdgeMatcher:
    """Training-free cross-modal matcher (see the module docstring)."""

    name = "edge"

    def __init__(self, config: EdgeMatcherConfig = EdgeMatcherConfig()):
        self.config = config

    def dense_flow(
        self, lidar: np.ndarray, image: np.ndarray, inverse_depth: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Coarse-to-fine search of the flow from the LiDAR field to the image field.

        Args:
            lidar, image: ``(2, H, W)`` orientation fields.
            inverse_depth: ``(H, W)`` of the LiDAR image, for the final local flow model.

        Returns:
            ``flow (2, H, W)`` as ``(du, dv)`` pixels, ``signal (H, W)`` the mean LiDAR edge
            strength in each window, ``confidence (H, W)`` in [0, 1].
        """
        cfg = self.config
        # zero-mean locally: a field constant over a window (ground seen at a grazing angle,
        # texture) correlates equally at every displacement and only flattens the peak
        lidar, image = (
            np.stack([c - cv2.GaussianBlur(c, (0, 0), cfg.highpass_px) for c in x]) for x in (lidar, image)
        )
        pyramid = [(lidar, image)]
        for _ in range(cfg.levels - 1):
            pyramid.append(tuple(_downsample(x) for x in pyramid[-1]))
        pyramid = [(torch.from_numpy(L), torch.from_numpy(I)) for L, I in pyramid]
        flow = torch.zeros(2, *pyramid[-1][0].shape[1:])
        for level in reversed(range(cfg.levels)):
            L, I = pyramid[level]
            if flow.shape[1:] != L.shape[1:]:
                flow = (
                    2 * F.interpolate(flow[None], size=L.shape[1:], mode="bilinear", align_corners=False)[0]
                )
            radius = cfg.search_radius if level == cfg.levels - 1 else cfg.refine_radius
            cost = _normalised_cost(L, _warp(I, flow), radius, cfg.window)
            offset, peak, curv_u, curv_v = _peak(cost, radius)
            signal = _box(L.norm(dim=0, keepdim=True), cfg.window)[0]
            confidence = _confidence(peak, curv_u, curv_v, signal, cfg.sharpness_scale)
            if level:
                # one flow per window, averaged with the confidence as weight: a window on a
                # single straight edge (the aperture problem) takes its flow from windows that
                # see corners, and the next level's window-wide cost is meaningful only where
                # the flow it warped with is constant over the window
                weight = confidence[None] + 1e-6
                flow = flow + _box(weight * offset, cfg.window) / _box(weight, cfg.window)
            else:
                flow = _depth_model_fit(
                    flow + offset, confidence, torch.from_numpy(inverse_depth), cfg.smooth_window
                )
        return flow.numpy(), signal.numpy(), confidence.numpy()

    def match(self, frame: Frame, T_cam_lidar: np.ndarray) -> Correspondences:
        """Correspondences of every visible point whose window carries enough LiDAR edge signal
        and whose flow peak is confident enough.

        Args:
            frame: image, scan and intrinsics.
            T_cam_lidar: ``(4, 4)`` the extrinsic to project with.
        """
        cfg = self.config
        view = working_view(frame, cfg.working_focal_px)
        size = view.image.shape[:2]
        scan = project_scan(frame.points, T_cam_lidar, view.K, size, Visibility(window=3))
        lidar, inverse_depth = lidar_field(frame.points, T_cam_lidar, view.K, size, cfg)
        flow, signal, confidence = self.dense_flow(lidar, image_edges(view.image, cfg), inverse_depth)
        r, c = np.rint(scan.uv[:, 1]).astype(int), np.rint(scan.uv[:, 0]).astype(int)
        keep = (signal[r, c] >= cfg.min_signal) & (confidence[r, c] >= cfg.min_confidence)
        index = scan.index[keep]
        uv = view.to_frame(scan.uv[keep])
        residual = flow[:, r[keep], c[keep]].T / view.scale
        points = frame.points[index, :3].astype(np.float64)
        return Correspondences(
            index.astype(np.int64),
            points,
            uv,
            uv + residual,
            confidence[r[keep], c[keep]].astype(np.float32),
            frame.image_size,
        )
