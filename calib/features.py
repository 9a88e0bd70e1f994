"""Geometric features of a LiDAR scan that do not depend on the extrinsic."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from calib.data.types import Frame
from calib.geometry import perturb
from calib.projection import Visibility, measured, project_scan

__all__ = [
    "contour_alignment",
    "contour_check",
    "depth_discontinuities",
    "horizontal_gradient",
    "level_laser_gains",
    "RingProfile",
    "ring_spacing_deg",
    "ring_spacing_profile",
    "ring_stripes",
    "scan_lines",
]


def depth_discontinuities(
    points_lidar: np.ndarray,
    ring: np.ndarray | None = None,
    min_jump_m: float = 0.5,
    rel_jump: float = 0.1,
    max_azimuth_gap_deg: float = 1.0,
    max_elevation_gap_deg: float = 0.3,
    surface_tol: float = 0.05,
) -> tuple[np.ndarray, np.ndarray]:
    """Foreground points at range discontinuities between neighbouring returns of a scan line.

    Neighbours are consecutive points of a scan line: points sorted by ``(ring, azimuth)`` when
    ``ring`` is given, else taken in stored order (KITTI/Velodyne scans are stored ring by ring)
    and accepted as neighbours only when they are also close in azimuth and elevation. Of a
    neighbouring pair whose ranges differ by more than ``max(min_jump_m, rel_jump · nearer)``,
    the nearer point lies on an occluding contour, which the camera sees as an edge.
    Both points must continue a surface away from the jump (their outer neighbours' ranges
    within ``surface_tol``): isolated returns and foliage, which jump all the time, carry no
    clean image edge.

    Missing returns (:data:`~calib.projection.MISSING_RETURN_M`) are no surface: the returns on
    either side of one are neighbours.

    Args:
        points_lidar: ``(N, 3)`` or ``(N, 4)`` points.
        ring: ``(N,)`` laser index per point, optional.

    Returns:
        ``nearer (M,)`` and ``farther (M,)`` point indices of each discontinuity: the occluding
        contour seen by the camera lies between the two returns.
    """
    points_lidar = np.asarray(points_lidar)
    kept = np.flatnonzero(measured(points_lidar))
    if len(kept) < len(points_lidar):
        nearer, farther = depth_discontinuities(
            points_lidar[kept],
            None if ring is None else ring[kept],
            min_jump_m,
            rel_jump,
            max_azimuth_gap_deg,
            max_elevation_gap_deg,
            surface_tol,
        )
        return kept[nearer], kept[farther]
    xyz = np.asarray(points_lidar, dtype=np.float64)[:, :3]
    azimuth = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))
    horizontal = np.hypot(xyz[:, 0], xyz[:, 1])
    elevation = np.degrees(np.arctan2(xyz[:, 2], horizontal))
    rng = np.linalg.norm(xyz, axis=1)
    order = np.lexsort((azimuth, ring)) if ring is not None else np.arange(len(xyz))
    a, b = order[:-1], order[1:]
    d_az = np.abs((azimuth[b] - azimuth[a] + 180.0) % 360.0 - 180.0)
    neighbours = d_az < max_azimuth_gap_deg
    if ring is not None:
        neighbours &= ring[a] == ring[b]
    else:
        neighbours &= np.abs(elevation[b] - elevation[a]) < max_elevation_gap_deg
    closer = np.minimum(rng[a], rng[b])
    jump = neighbours & (np.abs(rng[a] - rng[b]) > np.maximum(min_jump_m, rel_jump * closer))
    # smooth[k]: order[k] and order[k + 1] are neighbours on one surface
    smooth = neighbours & (np.abs(rng[a] - rng[b]) <= surface_tol * closer)
    k = np.nonzero(jump)[0]
    a_nearer = rng[a[k]] < rng[b[k]]
    before = np.concatenate([[False], smooth])[k]  # order[k - 1] continues order[k]
    after = np.concatenate([smooth, [False]])[k + 1]  # order[k + 2] continues order[k + 1]
    keep = before & after
    nearer = np.where(a_nearer, a[k], b[k])[keep]
    farther = np.where(a_nearer, b[k], a[k])[keep]
    return nearer, farther


def _ring_gaps(
    points_lidar: np.ndarray, column_deg: float, same_ring_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """Elevation gaps (°) between vertically neighbouring returns of each azimuth column
    ``column_deg`` wide (closer than ``same_ring_deg``: one ring), and each gap's lower end (°);
    missing returns (:data:`~calib.projection.MISSING_RETURN_M`) left out."""
    xyz = np.asarray(points_lidar, np.float64)[:, :3]
    xyz = xyz[measured(xyz)]
    horizontal = np.hypot(xyz[:, 0], xyz[:, 1])
    column = np.floor(np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0])) / column_deg).astype(np.int64)
    elevation = np.degrees(np.arctan2(xyz[:, 2], horizontal))
    order = np.lexsort((elevation, column))
    c, e = column[order], elevation[order]
    gap = np.diff(e)
    between = (c[1:] == c[:-1]) & (gap >= same_ring_deg)
    return gap[between], e[:-1][between]


def _median_spacing(gap: np.ndarray) -> float:
    """Median of the ring gaps ``gap`` under 3° (a wider one is a missing return), 0 for none."""
    gap = gap[gap < 3.0]
    return float(np.median(gap)) if len(gap) else 0.0


def ring_spacing_deg(points_lidar: np.ndarray, column_deg: float = 0.4, same_ring_deg: float = 0.1) -> float:
    """Median elevation gap between vertically neighbouring rings of a spinning LiDAR's scan, in
    degrees (KITTI's HDL-64: 0.4; nuScenes' 32 rings: 1.33), 0 for fewer than two rings.

    Within each azimuth column ``column_deg`` wide, elevations closer than ``same_ring_deg`` count
    as one ring; gaps over 3° (a missing return) are left out.
    """
    return _median_spacing(_ring_gaps(points_lidar, column_deg, same_ring_deg)[0])


@dataclass(frozen=True)
class RingProfile:
    """The spacing between neighbouring rings of a spinning LiDAR along its elevation.

    Many scanners space their lasers unevenly: a Pandar64 (the PJLab rig) puts 0.17° between them
    from −6° to +2° and 1–6° above and below, so one median spacing would leave its outer rings
    far apart (:func:`ring_spacing_profile`).

    Attributes:
        elevation_deg: ``(B,)`` increasing elevations (°), the centres of the bins measured.
        spacing_deg: ``(B,)`` the median gap between rings around each.
        median_deg: :func:`ring_spacing_deg` of the scan.
    """

    elevation_deg: np.ndarray
    spacing_deg: np.ndarray
    median_deg: float

    def at(self, elevation_deg: np.ndarray | float) -> np.ndarray:
        """Spacing (°) at ``elevation_deg`` (any shape), linear between the bins and constant
        beyond them; 0 for a scan without two rings."""
        if len(self.elevation_deg) == 0:
            return np.zeros_like(np.asarray(elevation_deg, np.float64))
        return np.interp(elevation_deg, self.elevation_deg, self.spacing_deg)


def ring_spacing_profile(
    points_lidar: np.ndarray,
    column_deg: float = 0.4,
    same_ring_deg: float = 0.1,
    bin_deg: float = 0.5,
    max_gap_deg: float = 8.0,
    min_gaps: int = 20,
) -> RingProfile:
    """:class:`RingProfile` of a spinning LiDAR's scan: the gaps of :func:`ring_spacing_deg`
    (up to ``max_gap_deg``) in bins ``bin_deg`` wide, each gap counted in every bin it spans; the
    median of each bin that at least ``min_gaps`` span (a missing return doubles a gap now and
    then). A bin where dense rings end and sparse ones begin reads the sparse gap it lies in."""
    gap, lower = _ring_gaps(points_lidar, column_deg, same_ring_deg)
    median = _median_spacing(gap)
    keep = gap < max_gap_deg
    gap, lower = gap[keep], lower[keep]
    if len(gap) == 0:
        return RingProfile(np.zeros(0), np.zeros(0), median)
    first = np.floor(lower / bin_deg).astype(np.int64)
    spans = np.floor((lower + gap) / bin_deg).astype(np.int64) - first + 1
    index = np.repeat(first, spans) + np.arange(spans.sum()) - np.repeat(np.cumsum(spans) - spans, spans)
    spanned = np.repeat(gap, spans)
    order = np.argsort(index, kind="stable")
    bins, starts, counts = np.unique(index[order], return_index=True, return_counts=True)
    full = counts >= min_gaps
    if not full.any():
        return RingProfile(np.array([np.median(lower + 0.5 * gap)]), np.array([np.median(gap)]), median)
    spacing = np.array(
        [np.median(spanned[order[a : a + n]]) for a, n in zip(starts[full], counts[full], strict=True)]
    )
    return RingProfile((bins[full] + 0.5) * bin_deg, spacing, median)


def scan_lines(points_lidar: np.ndarray, min_lines: int = 8, backward_deg: float = 30.0) -> np.ndarray | None:
    """Scan-line (laser) index of every point of a scan stored line by line, as KITTI, nuScenes
    and most spinning-LiDAR drivers store it; ``None`` for a scan stored otherwise.

    A new line starts where the azimuth jumps back against the sweep by more than
    ``backward_deg``: at the seam behind the scanner, or at the edge of a scan cropped to the
    camera's view (a gap of missing returns jumps forward). The split is accepted when it gives
    at least ``min_lines`` lines whose median elevations step the same way from line to line (in
    nine steps of ten) by about the spacing between rings (half to twice it). A line's own
    elevations spread wider than that on real scanners (KITTI: 1° interquartile; the lasers sit
    off the scanner's centre, so near returns read high), so they cannot tell lines apart.
    Missing returns stored in place (:data:`~calib.projection.MISSING_RETURN_M`), whose azimuth
    about the centre is noise, neither start a line nor count in its elevation; each joins the
    line of the return stored before it.

    Args:
        points_lidar: ``(N, 3+)`` points in stored order.

    Returns:
        ``(N,)`` int64 line index in stored order, or ``None``.
    """
    xyz = np.asarray(points_lidar, np.float64)[:, :3]
    far = np.flatnonzero(measured(xyz))
    if len(far) < 2:
        return None
    azimuth = np.degrees(np.arctan2(xyz[far, 1], xyz[far, 0]))
    step = np.diff(azimuth)
    sweep = np.sign(np.median(step))
    starts = np.zeros(len(xyz), np.int64)
    starts[far[1:][sweep * step < -backward_deg]] = 1
    line = np.cumsum(starts)  # a near return joins the line of the return stored before it
    if line[-1] + 1 < min_lines:
        return None
    elevation = np.degrees(np.arctan2(xyz[far, 2], np.hypot(xyz[far, 0], xyz[far, 1])))
    bounds = np.concatenate([[0], np.cumsum(np.bincount(line[far]))])  # lines are contiguous runs
    medians = np.array([np.median(elevation[a:b]) for a, b in zip(bounds[:-1], bounds[1:], strict=True)])
    steps = np.diff(medians)
    same_way = max(np.mean(steps > 0), np.mean(steps < 0))
    ratio = np.median(np.abs(steps)) / max(ring_spacing_deg(xyz), 1e-6)
    return line if same_way >= 0.9 and 0.5 <= ratio <= 2.0 else None


def _lines_of(
    points: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]] | None:
    """A scan stored line by line as its returns' line index (:func:`scan_lines`), azimuth (°),
    range and log intensity, each ``(N,)``, and each line's returns with some intensity, by
    azimuth; ``None`` for a scan stored otherwise or without intensity."""
    line = scan_lines(points) if points.ndim == 2 and points.shape[1] > 3 else None
    if line is None:
        return None
    xyz = points[:, :3].astype(np.float64)
    azimuth = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))
    bright = (points[:, 3] > 0) & measured(points)
    bounds = np.concatenate([[0], np.cumsum(np.bincount(line))])  # lines are contiguous runs
    lines = []
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        members = np.arange(a, b)[bright[a:b]]
        lines.append(members[np.argsort(azimuth[members])])
    return line, azimuth, np.linalg.norm(xyz, axis=1), np.log(np.maximum(points[:, 3], 1e-6)), lines


def _same_surface_mates(
    upper: np.ndarray, lower: np.ndarray, azimuth: np.ndarray, rng: np.ndarray, max_gap_deg: float, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of returns of two neighbouring lines (indices sorted by azimuth) that meet one
    surface: each return of ``lower`` and its nearest in azimuth on ``upper``, kept where their
    azimuths lie within ``max_gap_deg`` and their ranges within ``tol`` of each other."""
    if len(upper) < 2 or not len(lower):
        return lower[:0], upper[:0]
    k = np.clip(np.searchsorted(azimuth[upper], azimuth[lower]), 1, len(upper) - 1)
    before, after = (np.abs(azimuth[upper[j]] - azimuth[lower]) for j in (k - 1, k))
    mate = upper[np.where(before < after, k - 1, k)]
    pair = (np.abs(azimuth[mate] - azimuth[lower]) < max_gap_deg) & (
        np.abs(rng[mate] - rng[lower]) < tol * rng[lower]
    )
    return lower[pair], mate[pair]


_GAP_DEG, _SURFACE_TOL, _MIN_PAIRS = 0.3, 0.05, 30
""":func:`level_laser_gains`' defaults, which :func:`ring_stripes` levels with too."""


def level_laser_gains(
    points_lidar: np.ndarray,
    max_azimuth_gap_deg: float = _GAP_DEG,
    surface_tol: float = _SURFACE_TOL,
    min_pairs: int = _MIN_PAIRS,
) -> np.ndarray:
    """The scan with each laser's intensity gain levelled to its neighbours'.

    The lasers of a spinning LiDAR answer the same surface with different intensities (KITTI's
    HDL-64: neighbouring rings differ by up to 30 %), which draws an intensity edge along every
    scan line. Such an edge follows the LiDAR's tilt, not the scene: on KITTI 2011_09_28 the
    matcher's residuals under the reference turned 0.30° about the optical axis (0.17° once
    levelled). Neighbouring lines (:func:`scan_lines`) meet the same surface at the same azimuth:
    the median log ratio of such pairs (azimuths within ``max_azimuth_gap_deg``, ranges within
    ``surface_tol``) is the ratio of the two gains, and the gains follow by chaining the ratios
    from line to line (a pair of lines with fewer than ``min_pairs`` pairs keeps its ratio at 1),
    less their linear trend over the lines. A line's median intensity would not do: neighbouring
    lines see different things (road, kerb, wall). Scans not stored line by line keep their
    values.

    Args:
        points_lidar: ``(N, 4)`` points with intensity in stored order (fewer columns: returned
            as they are).

    Returns:
        ``(N, 4)`` float32 copy with levelled intensity.
    """
    points = np.array(points_lidar, np.float32)
    scan = _lines_of(points)
    if scan is not None:
        points[:, 3] = _levelled(points, scan, max_azimuth_gap_deg, surface_tol, min_pairs)
    return points


def _levelled(
    points: np.ndarray,
    scan: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]],
    max_azimuth_gap_deg: float,
    surface_tol: float,
    min_pairs: int,
) -> np.ndarray:
    """``(N,)`` float32 intensity of ``points (N, 4)`` (float32) with each laser's gain levelled,
    from the scan's :func:`_lines_of` (:func:`level_laser_gains` has the method)."""
    line, azimuth, rng, log_intensity, lines = scan
    log_gain = [0.0]
    for upper, lower in zip(lines[:-1], lines[1:], strict=True):
        below, mate = _same_surface_mates(upper, lower, azimuth, rng, max_azimuth_gap_deg, surface_tol)
        ratio = (
            float(np.median(log_intensity[below] - log_intensity[mate])) if len(below) >= min_pairs else 0.0
        )
        log_gain.append(log_gain[-1] + ratio)
    # a trend across the lasers is the incidence angle (lower beams meet the ground more
    # steeply, so read brighter), not their gains: only the departures from a line are levelled
    k = np.arange(len(log_gain))
    log_gain = np.array(log_gain) - np.polyval(np.polyfit(k, log_gain, 1), k)
    return points[:, 3] * np.exp(-log_gain[line]).astype(np.float32)


def ring_stripes(points_lidar: np.ndarray, surface_tol: float = 0.05, min_pairs: int = 100) -> float | None:
    """How striped along its scan lines a scan's intensity stays once each laser's gain is
    levelled (:func:`level_laser_gains`): the median ``|Δ log intensity|`` between neighbouring
    lines on one surface over that between neighbouring returns along a line on one surface.

    About 1 where the lasers differ by a gain alone (the texture between two rings, 0.4° apart,
    differs a little more than between returns 0.2° apart; rings farther apart read higher from
    the texture alone: nuScenes' 32, 1.3° apart, about 11); more where their differences vary
    with range or brightness, which levelling one gain per laser leaves as stripes (the matcher's
    intensity edges along the rings, which follow the LiDAR's tilt). Two returns meet one surface
    where their azimuths lie less than 1.5 of the scan's median azimuth steps apart and their
    ranges within ``surface_tol`` of each other. ``None`` for a scan not stored line by line,
    without intensity, or with fewer than ``min_pairs`` pairs of either kind.

    Args:
        points_lidar: ``(N, 4)`` points with intensity in stored order.
    """
    points = np.array(points_lidar, np.float32)
    scan = _lines_of(points)  # the lines, azimuths and ranges stay as levelling leaves them
    if scan is None:
        return None
    _, azimuth, rng, _, lines = scan
    levelled = _levelled(points, scan, _GAP_DEG, _SURFACE_TOL, _MIN_PAIRS)
    log_intensity = np.log(np.maximum(levelled, 1e-6))
    steps = np.concatenate([np.diff(azimuth[run]) for run in lines])
    gap = 1.5 * float(np.median(steps[steps > 0])) if (steps > 0).any() else 0.0
    across = [
        log_intensity[below] - log_intensity[mate]
        for upper, lower in zip(lines[:-1], lines[1:], strict=True)
        for below, mate in [_same_surface_mates(upper, lower, azimuth, rng, gap, surface_tol)]
    ]
    along = [
        log_intensity[run[1:][near]] - log_intensity[run[:-1][near]]
        for run in lines
        for near in [
            (np.abs(np.diff(azimuth[run])) < gap) & (np.abs(np.diff(rng[run])) < surface_tol * rng[run[1:]])
        ]
    ]
    across, along = np.abs(np.concatenate(across)), np.abs(np.concatenate(along))
    if min(len(across), len(along)) < min_pairs or np.median(along) <= 0:
        return None
    return float(np.median(across) / np.median(along))


def horizontal_gradient(image: np.ndarray, reference_width: int = 1242) -> np.ndarray:
    """``|∂I/∂u|`` of the grey image, smoothed at a scale proportional to its width, in [0, 1].

    Discontinuities found along near-horizontal scan lines mark near-vertical contours, whose
    image gradient is horizontal; the horizontal component ignores texture edges across the
    scan lines. The smoothing is 1 px at KITTI's width and grows with resolution (a contour
    lies up to half a beam step from its return). Normalised by the 99th percentile.

    Args:
        image: ``(H, W, 3)`` uint8 RGB.

    Returns:
        ``(H, W)`` float32.
    """
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
    grey = cv2.GaussianBlur(grey, (0, 0), image.shape[1] / reference_width)
    gx = np.abs(cv2.Sobel(grey, cv2.CV_32F, 1, 0))
    return np.clip(gx / max(float(np.percentile(gx, 99)), 1e-6), 0.0, 1.0)


def contour_alignment(
    edge_map: np.ndarray,
    points_lidar: np.ndarray,
    contour_index: np.ndarray,
    T_cam_lidar: np.ndarray,
    K: np.ndarray,
    visibility: Visibility = Visibility(),
) -> float:
    """Mean of ``edge_map`` at the visible projected contour points.

    A correct extrinsic puts LiDAR occluding contours on image edges, so with
    ``edge_map = horizontal_gradient(image)`` this score peaks at the true calibration (a
    target-free sanity check of conventions and of a calibration).

    Args:
        edge_map: ``(H, W)`` edge strength, e.g. :func:`horizontal_gradient` of the image.
        points_lidar: ``(N, 4)`` scan.
        contour_index: indices of contour points (``nearer`` of :func:`depth_discontinuities`).
    """
    projected = project_scan(points_lidar, T_cam_lidar, K, edge_map.shape[:2], visibility)
    on_contour = np.isin(projected.index, contour_index)
    if not on_contour.any():
        return 0.0
    pixels = np.round(projected.uv[on_contour]).astype(int)
    return float(edge_map[pixels[:, 1], pixels[:, 0]].mean())


PERTURBATIONS = 8
"""How many seeded 1° rotations :func:`contour_check` compares the reference with."""


def contour_check(frame: Frame, ring: np.ndarray | None, seed: int = 0) -> dict:
    """Contour alignment under the reference and under ``PERTURBATIONS`` seeded 1° rotations."""
    T = frame.calibration.T_cam_lidar
    contour, _ = depth_discontinuities(frame.points, ring)
    generator = torch.Generator().manual_seed(seed)
    edges = horizontal_gradient(frame.image)
    reference = contour_alignment(edges, frame.points, contour, T, frame.K)
    perturbed = [
        contour_alignment(edges, frame.points, contour, perturb(T, 0.0, 1.0, generator), frame.K)
        for _ in range(PERTURBATIONS)
    ]
    return {
        "contour_points": len(contour),
        "reference": reference,
        "perturbed_mean": float(np.mean(perturbed)),
        "perturbed_max": float(np.max(perturbed)),
        "ratio": reference / float(np.mean(perturbed)),
    }
