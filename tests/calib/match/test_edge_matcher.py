from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch

from calib.data import open_dataset
from calib.data.classes import RIGID_CLASSES
from calib.data.real_fixtures import AMZ_DRIVE, AMZ_DRIVE_MORE
from calib.data.types import Calibration, Frame
from calib.errors import DataError
from calib.geometry import perturb
from calib.match import edge_matcher
from calib.match.correspondences import Correspondences, match_frames
from calib.match.edge_matcher import (
    RIGID_TOL_M,
    EdgeMatcher,
    EdgeMatcherConfig,
    VirtualView,
    _box,
    _depth_model_fit,
    _nearest_seeds,
    _normalised_cost,
    _ray_elevation,
    _rigid_motion,
    _seed_box,
    _splat,
    _sums_box,
    lidar_edges,
    lidar_field,
)
from calib.projection import Visibility, project_points, project_scan, transform_points
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config
from calib.yaml_io import validate

STILL = {"wind": {"amplitude_m": 0.0}, "timing": {"camera_offset_s": 0.0}}


@pytest.fixture(scope="module")
def still_vineyard():
    """Two frames of a still vineyard at the small 624x188 (camera and LiDAR fire together)."""
    synth = Synthesizer(load_synth_config("vineyard", small=True, **STILL), 12, seed=3)
    return [synth.render(i).frame for i in (2, 9)]


def true_residual(frame, corr):
    uv, _ = project_points(
        transform_points(torch.as_tensor(frame.calibration.T_cam_lidar), torch.as_tensor(corr.points_lidar)),
        torch.as_tensor(frame.K),
    )
    return uv.numpy() - corr.uv


@pytest.mark.parametrize("k", [7, 61])  # 61: wider than the image, as the smoothing window at 90 px
def test_box_filter_is_the_mean_over_the_window_inside_the_image(k):
    x = np.random.default_rng(0).random((3, 20, 31)).astype(np.float32)
    r = k // 2
    padded = np.pad(x, ((0, 0), (r, r), (r, r)), constant_values=np.nan)
    expected = np.nanmean(
        np.lib.stride_tricks.sliding_window_view(padded, (k, k), axis=(1, 2)), axis=(-2, -1)
    )
    np.testing.assert_allclose(_box(x, k), expected, rtol=1e-5, atol=1e-6)


def test_depth_model_recovers_an_exact_translation_flow():
    rng = np.random.default_rng(0)
    q = rng.choice([1 / 4, 1 / 12, 1 / 30], (40, 60)).astype(np.float32)
    flow = np.stack([1.5 + 20 * q, -0.5 + 8 * q])  # rotation part + translation part / z
    fit = _depth_model_fit(flow, np.ones((40, 60), np.float32), q, 21, ridge=0.0)
    np.testing.assert_allclose(fit, flow, atol=1e-3, rtol=0)


def test_dense_flow_recovers_a_known_shift_of_a_textured_field():
    rng = np.random.default_rng(0)
    field = np.stack(
        [cv2.GaussianBlur(c, (0, 0), 1.5) for c in rng.normal(size=(2, 96, 160)).astype(np.float32)]
    )
    image = np.roll(np.roll(field, -3, 1), 5, 2)  # the LiDAR field at y appears in the image at y + (5, -3)
    flow, signal, confidence = EdgeMatcher().dense_flow(field, image, np.full((96, 160), 0.1, np.float32))
    inner = flow[:, 20:-20, 20:-20].reshape(2, -1)
    np.testing.assert_allclose(np.median(inner, axis=1), [5.0, -3.0], atol=0.05)
    assert flow.shape == (2, 96, 160) and signal.shape == confidence.shape == (96, 160)
    assert 0 <= confidence.min() and confidence.max() <= 1


def test_a_pixel_midway_between_two_seeds_gets_one_of_each():
    ids = np.full((5, 7), -1)
    ids[2, 1], ids[2, 3] = 10, 30
    first, second = _nearest_seeds(ids)
    assert (first[2, 2], second[2, 2]) in {(10, 30), (30, 10)}  # equidistant: one each way
    np.testing.assert_array_equal(first[:, :2], 10)  # elsewhere both agree
    np.testing.assert_array_equal(second[:, 4:], 30)


def _boxes_frame(seed: int, mirror: bool) -> tuple[Frame, np.ndarray]:
    """Fronto-parallel boxes before a wall 40 m away, at KITTI's pixel scale, seen by a camera
    and a 64-ring LiDAR (0.2° azimuth steps) at one centre, so no parallax; optionally mirrored
    left to right (image, points and extrinsic)."""
    H, W, f, cx, cy = 375, 1242, 721.5, 609.6, 172.9
    rng = np.random.default_rng(seed)
    u0, v0 = rng.uniform(-50, W, 40), rng.uniform(-20, 0.6 * H, 40)
    boxes = np.column_stack([u0, u0 + rng.uniform(15, 150, 40), v0, v0 + rng.uniform(30, 200, 40)])
    depths, greys = rng.uniform(5, 20, 40), rng.uniform(0.4, 0.9, 40)
    order = np.argsort(-depths)  # far first: the near ones are drawn over them

    def scene(u, v):
        z, grey = np.full(u.shape, 40.0), np.full(u.shape, 0.2)
        for (a, b, c, d), zb, gb in zip(boxes[order], depths[order], greys[order], strict=True):
            inside = (u >= a) & (u < b) & (v >= c) & (v < d)
            z[inside], grey[inside] = zb, gb
        return z, grey

    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    grey = scene(u, v)[1] + rng.normal(0, 0.01, (H, W))
    image = np.repeat((np.clip(grey, 0, 1) * 255).astype(np.uint8)[..., None], 3, 2)
    elevation, azimuth = np.meshgrid(
        np.radians(np.arange(2.0, -25.0, -0.42)), np.radians(np.arange(60, -60, -0.2) + rng.uniform(0, 0.2))
    )
    R = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])  # LiDAR x forward, z up
    rays_lidar = np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], -1
    ).reshape(-1, 3)
    rays = rays_lidar @ R.T
    z = scene(f * rays[:, 0] / rays[:, 2] + cx, f * rays[:, 1] / rays[:, 2] + cy)[0]
    points = np.column_stack([rays / rays[:, 2:] * z[:, None] @ R, np.full(len(z), 0.5)]).astype(np.float32)
    T = np.eye(4)
    T[:3, :3] = R
    if mirror:
        image, cx = np.ascontiguousarray(image[:, ::-1]), W - 1 - cx
        points[:, 1] *= -1
        T[:3, :3] = np.diag([-1.0, 1, 1]) @ R @ np.diag([1.0, -1, 1])
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]])
    return Frame(
        image=image, points=points, calibration=Calibration(K=K, T_cam_lidar=T, image_size=(H, W))
    ), T


@pytest.mark.parametrize("inside", [False, True])
def test_the_cost_volume_at_the_image_border(inside):
    """A field against itself: away from the border the peak is at zero displacement. At the
    border the zero-padded cost (``border: zero``) leans outward, about 1.4 px in the outermost two
    rows and columns (a displaced window centred past the border reads an image RMS of 0 and
    wins); ``border: inside`` peaks at zero there too."""
    H, W, radius, window = 48, 64, 2, 15
    n = 2 * radius + 1
    leans = []
    for seed in range(4):
        rng = np.random.default_rng(seed)
        field = np.stack(
            [cv2.GaussianBlur(c, (0, 0), 1.5) for c in rng.normal(size=(2, H, W)).astype(np.float32)]
        )
        _, best, _ = _normalised_cost(field, field, radius, window, inside)
        dv, du = (best // n - radius).reshape(H, W), (best % n - radius).reshape(H, W)
        leans.append([-dv[:2].mean(), dv[-2:].mean(), -du[:, :2].mean(), du[:, -2:].mean()])
        far = window // 2 + radius  # windows that reach neither the border nor past it
        assert (dv[far:-far, far:-far] == 0).all() and (du[far:-far, far:-far] == 0).all()
        if inside:
            assert (dv == 0).all() and (du == 0).all()
    outward = np.mean(leans, axis=0)  # top, bottom, left, right
    if not inside:
        assert (outward > 1.0).all(), outward


def test_the_inside_border_reads_as_the_zero_one_away_from_the_border():
    rng = np.random.default_rng(5)
    lidar, image = rng.normal(size=(2, 2, 40, 60)).astype(np.float32)
    zero, _, _ = _normalised_cost(lidar, image, 2, 11, inside=False)
    inside, _, _ = _normalised_cost(lidar, image, 2, 11, inside=True)
    far = 11 // 2 + 2 + 2  # the window, the radius and the displacement reach no border sample
    np.testing.assert_allclose(inside[:, far:-far, far:-far], zero[:, far:-far, far:-far], rtol=1e-4)


def test_residuals_under_the_truth_lean_no_way_of_their_own():
    """A scene and its mirror image, without parallax: whatever the scene makes the residuals
    under the truth lean left, its mirror makes them lean right by as much, so half their sum is
    the matcher's own lean. Before the ties of the Voronoi fill were split it was -0.5 px (every
    LiDAR edge a fifth of a working pixel right of the image's)."""
    medians = [np.median(EdgeMatcher().match(*_boxes_frame(0, mirror)).residual[:, 0]) for mirror in (0, 1)]
    assert abs(sum(medians) / 2) < 0.1, medians


def test_the_field_drawn_on_its_seeds_box_is_the_field_of_the_whole_image(still_vineyard, monkeypatch):
    """The Voronoi fill and the gradients run on the box the seeds span (widened by the fill radius
    and the gradients' reach): the field equals the whole image's bit for bit, the inverse depth
    equals it inside the box. The camera turned 20° up, so the rows above the LiDAR's top ring
    fall outside the box."""
    frame = still_vineyard[0]
    up = np.radians(-20.0)
    T = frame.calibration.T_cam_lidar.copy()
    T[:3] = np.array([[1, 0, 0], [0, np.cos(up), -np.sin(up)], [0, np.sin(up), np.cos(up)]]) @ T[:3]
    scan = project_scan(frame.points, T, frame.K, frame.image_size, None)
    boxes = []

    def recorded(seeds, margin):
        boxes.append(_seed_box(seeds, margin))
        return boxes[-1]

    monkeypatch.setattr(edge_matcher, "_seed_box", recorded)
    field, inverse_depth = lidar_edges(scan, frame.points, T, frame.K)
    rows, cols = boxes[-1]
    H, W = frame.image_size
    assert rows.start > 0 and rows.stop - rows.start < H  # some rows left out
    monkeypatch.setattr(edge_matcher, "_seed_box", lambda seeds, margin: (slice(0, H), slice(0, W)))
    whole_field, whole_inverse_depth = lidar_edges(scan, frame.points, T, frame.K)
    np.testing.assert_array_equal(field, whole_field)
    np.testing.assert_array_equal(inverse_depth[rows, cols], whole_inverse_depth[rows, cols])
    assert np.abs(field[:, : rows.start]).max() == 0 and np.abs(field).max() > 0


@pytest.mark.parametrize("inside", [False, True])
def test_the_dense_flow_run_on_the_lidar_s_box_is_the_whole_image_s(inside, monkeypatch):
    """The full-size level runs on the box where a window sees the LiDAR, widened by what the sums
    read: there the signal and confidence equal the whole image's bit for bit and the flow to
    1e-4 px (the final fit no longer reads the pixels outside, which weigh 1e-6 each); outside,
    no signal. The field here leaves its top 70 rows and its left 50 columns empty."""
    rng = np.random.default_rng(1)
    image = np.stack(
        [cv2.GaussianBlur(c, (0, 0), 1.5) for c in rng.normal(size=(2, 200, 260)).astype(np.float32)]
    )
    field = np.roll(np.roll(image, 3, 1), -2, 2)
    field[:, :70], field[:, :, :50] = 0, 0
    inverse_depth = rng.uniform(0.05, 0.5, (200, 260)).astype(np.float32)
    matcher = EdgeMatcher(EdgeMatcherConfig(border="inside" if inside else "zero"))
    rows, cols = _sums_box(field, matcher.config.window, matcher.config.refine_radius)
    assert rows.start > 0 and cols.start > 0  # some of the image left out
    flow, signal, confidence = matcher.dense_flow(field, image, inverse_depth)
    monkeypatch.setattr(edge_matcher, "_sums_box", lambda lidar, window, radius: np.s_[:, :])
    whole_flow, whole_signal, whole_confidence = matcher.dense_flow(field, image, inverse_depth)
    np.testing.assert_array_equal(signal, whole_signal)
    np.testing.assert_array_equal(confidence, whole_confidence)
    seen = signal > 0
    assert 0.5 < seen.mean() < 0.9 and not seen[: rows.start].any() and not seen[:, : cols.start].any()
    np.testing.assert_allclose(flow[:, seen], whole_flow[:, seen], atol=1e-4, rtol=0)
    np.testing.assert_allclose(
        np.median(flow[:, seen], axis=1), [2.0, -3.0], atol=0.1
    )  # field at y is image at y + (2, -3)


def test_splatting_known_answers_at_and_beyond_the_border():
    """A value at a pixel centre lands on that pixel alone; one midway between four pixels leaves a
    quarter of itself on each (a pixel is divided by its weight only where that exceeds 1, so a
    pixel a sample only grazes stays faint); one half a pixel past the border keeps its inside
    half; one a pixel and more past it lands nowhere; two on one pixel centre average."""
    values = np.array([[1.0, 2.0, 4.0, 8.0, 16.0, 32.0]], np.float32)
    uv = np.array([[1.0, 1.0], [3.5, 2.5], [-0.5, 3.0], [-1.5, 0.0], [5.0, 5.0], [1.0, 1.0]])
    out = _splat(values, uv, (5, 6))
    assert out.shape == (1, 5, 6) and out.dtype == np.float32
    assert out[0, 1, 1] == pytest.approx((1 + 32) / 2)  # two at one centre: their mean
    np.testing.assert_allclose(out[0, 2:4, 3:5], 0.5)  # midway: a quarter of 2 on each
    assert out[0, 3, 0] == pytest.approx(2.0)  # half a pixel out: half of 4 inside
    assert np.count_nonzero(out) == 1 + 4 + 1  # the rest (and 8, 16 beyond the image) land nowhere


def test_ray_elevation_known_answers_and_remembered():
    """A camera looking along the LiDAR's x axis (KITTI's mounting): the principal point's ray is
    level, the ray a focal length above it 45° up; the same rotation and K give the same
    (read-only) array back."""
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]  # camera x = −LiDAR y, y = −z, z = x
    K = np.array([[100.0, 0, 60], [0, 100.0, 150], [0, 0, 1]])
    elevation = _ray_elevation(T, K, (200, 120))
    assert elevation.shape == (200, 120) and not elevation.flags.writeable
    assert elevation[150, 60] == pytest.approx(0, abs=1e-5)
    assert elevation[50, 60] == pytest.approx(45, abs=1e-4)
    assert elevation[150, 119] == pytest.approx(0, abs=1e-5)  # beside it: still level
    assert _ray_elevation(T.copy(), K.copy(), (200, 120)) is elevation
    T[:3, :3] = T[:3, :3] @ cv2.Rodrigues(np.array([0.0, np.radians(10), 0.0]))[0]  # turned 10° about y
    assert _ray_elevation(T, K, (200, 120)) is not elevation


def test_the_seed_box_holds_every_seed_with_its_margin():
    seeds = np.zeros((40, 50), bool)
    seeds[20, 10] = seeds[30, 12] = seeds[25, 45] = True
    assert _seed_box(seeds, 3) == (slice(17, 34), slice(7, 49))
    assert _seed_box(seeds, 30) == (slice(0, 40), slice(0, 50))  # within the image
    assert _seed_box(np.zeros((4, 5), bool), 2) == (slice(0, 4), slice(0, 5))  # none: the whole image


def test_config_rejects_typos_and_even_windows():
    with pytest.raises(DataError, match="windw"):
        validate(EdgeMatcherConfig, {"windw": 9}, "maps.yaml")
    with pytest.raises(DataError, match="odd"):
        validate(EdgeMatcherConfig, {"window": 8}, "maps.yaml")


def test_correspondences_shapes_and_an_empty_scan(still_vineyard):
    frame = still_vineyard[0]
    corr = EdgeMatcher().match(frame, frame.calibration.T_cam_lidar)
    assert isinstance(corr, Correspondences) and len(corr) > 1000
    assert corr.uv.shape == corr.uv_matched.shape == (len(corr), 2) and corr.image_size == (188, 624)
    np.testing.assert_allclose(corr.points_lidar, frame.points[corr.index, :3])
    empty = replace(frame, points=frame.points[:0])  # the module's frames stay as rendered
    assert len(EdgeMatcher().match(empty, frame.calibration.T_cam_lidar)) == 0


def test_missing_returns_stored_in_place_change_no_match(still_vineyard):
    """A fifth of the returns again as missing ones stored in place ((0, 0, 0) with no intensity),
    the LiDAR's centre in view (a camera 1 m behind it): the same correspondences, bit for bit, at
    the returns' own indices (before, each missing return was a match on the centre's pixel)."""
    frame = still_vineyard[0]
    T = frame.calibration.T_cam_lidar.copy()
    T[2, 3] += 1.0
    at = np.flatnonzero(np.random.default_rng(4).random(len(frame.points) + 1) < 0.2)
    at = at[at <= len(frame.points)]
    stored = np.insert(frame.points, at, 0.0, axis=0)
    kept = np.flatnonzero(np.abs(stored[:, :3]).sum(1) > 0)
    expected = EdgeMatcher().match(frame, T)
    corr = EdgeMatcher().match(replace(frame, points=stored), T)
    assert len(expected) > 100
    np.testing.assert_array_equal(corr.index, kept[expected.index])
    np.testing.assert_array_equal(corr.uv_matched, expected.uv_matched)


def test_residuals_recover_a_known_perturbation_on_rigid_points(still_vineyard):
    """1° about a random axis moves points by about 6 px at this focal length (360 px)."""
    errors, moved = [], []
    for k, frame in enumerate(still_vineyard):
        T_wrong = perturb(frame.calibration.T_cam_lidar, 1.0, 1.0, torch.Generator().manual_seed(k))
        corr = EdgeMatcher().match(frame, T_wrong)
        rigid = np.isin(frame.labels[corr.index], list(RIGID_CLASSES))
        truth = true_residual(frame, corr)[rigid]
        errors.append(np.linalg.norm(corr.residual[rigid] - truth, axis=1))
        moved.append(np.linalg.norm(truth, axis=1))
    errors, moved = np.concatenate(errors), np.concatenate(moved)
    assert np.median(moved) > 4.0
    # measured over 8 still frames at 1°: 0.43 px vineyard, 0.39 px urban
    assert np.median(errors) < 0.5


@pytest.mark.realdata
def test_real_kitti_residuals_point_back_toward_the_reference(realdata):
    with open_dataset(realdata / AMZ_DRIVE) as seq:
        frame = seq[0]
    T_wrong = perturb(frame.calibration.T_cam_lidar, 0.0, 1.0, torch.Generator().manual_seed(0))
    corr = EdgeMatcher().match(frame, T_wrong)
    truth = true_residual(frame, corr)
    cosine = np.sum(truth * corr.residual, 1) / (
        np.linalg.norm(truth, axis=1) * np.linalg.norm(corr.residual, axis=1)
    )
    assert np.mean(cosine > 0) > 0.8
    assert np.median(np.linalg.norm(corr.residual - truth, axis=1)) < 0.6 * np.median(
        np.linalg.norm(truth, axis=1)
    )


def _roll_deg(uv: np.ndarray, residual: np.ndarray, K: np.ndarray) -> float:
    """Least-squares rotation about the optical axis of a residual field ``residual (N, 2)`` at
    ``uv (N, 2)``, in degrees, fitted with a constant shift: ``r ≈ (a, b) + ω (−(v − c_y), u − c_x)``
    (without the shift, a constant residual leaks into ``ω`` where the points' centre is off the
    principal point)."""
    u, v = uv[:, 0] - K[0, 2], uv[:, 1] - K[1, 2]
    ones, zeros = np.ones_like(u), np.zeros_like(u)
    A = np.concatenate([np.column_stack([ones, zeros, -v]), np.column_stack([zeros, ones, u])])
    a, b, omega = np.linalg.lstsq(A, np.concatenate([residual[:, 0], residual[:, 1]]), rcond=None)[0]
    return float(np.degrees(omega))


@pytest.mark.realdata
def test_real_kitti_residuals_under_the_reference_turn_less_once_laser_gains_are_levelled(realdata):
    """KITTI 2011_09_28's six frames under their reference: the residual field turned 0.30° about
    the optical axis in every frame, from intensity edges along the HDL-64's scan lines (its
    lasers' gains differ); mutual information of intensity and reflectance puts the reference
    within 0.1° of its own peak there. Levelling the gains takes the turn under 0.2°."""
    frames = []
    for folder in (AMZ_DRIVE, AMZ_DRIVE_MORE):
        with open_dataset(realdata / folder) as seq:
            frames += [seq[i] for i in range(len(seq))]
    assert len(frames) == 6

    def roll(config):
        fields = [EdgeMatcher(config).match(f, f.calibration.T_cam_lidar) for f in frames]
        uv, residual = (np.concatenate([getattr(c, name) for c in fields]) for name in ("uv", "residual"))
        return _roll_deg(uv, residual, frames[0].K)

    levelled, raw = roll(EdgeMatcherConfig()), roll(EdgeMatcherConfig(level_laser_gains=False))
    assert raw > 0.25
    assert abs(levelled) < 0.2 and abs(levelled) < 0.7 * raw


def _board_scan() -> np.ndarray:
    """A LiDAR scan (x forward, y left, z up) of a 1 m wide board 5 m ahead (y in ±0.5 m, z in
    ±2 m) in front of a wall 20 m ahead: each ray's first hit."""
    azimuth, elevation = np.meshgrid(np.radians(np.arange(-30, 30, 0.2)), np.radians(np.arange(-8, 5, 0.4)))
    d = np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], -1
    )
    d = d.reshape(-1, 3)
    t_board = 5.0 / d[:, 0]
    on_board = (np.abs(d[:, 1] * t_board) < 0.5) & (np.abs(d[:, 2] * t_board) < 2.0)
    t = np.where(on_board, t_board, 20.0 / d[:, 0])
    return np.column_stack([d * t[:, None], np.ones(len(d))]).astype(np.float32)


@pytest.mark.parametrize("carry", ["nearer", "own"])
def test_lidar_field_has_no_parallax_halo(carry):
    # camera 27 cm ahead of and 30 cm left of the LiDAR: the parallax opens a strip of wall left
    # of the board that the camera sees and the LiDAR does not (about 15 px here)
    R = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ np.array([0.27, 0.3, 0.0])
    K = np.array([[360.0, 0, 320], [0, 360, 100], [0, 0, 1]])
    points = _board_scan()
    edge_u = 320 + 360 * (-(0.5 - 0.3) / (5 - 0.27))  # the board's left edge in the camera
    u = np.arange(640, dtype=float)
    near, strip = np.abs(u - edge_u) < 3, (u > edge_u - 25) & (u < edge_u - 3)

    def profile(field: np.ndarray) -> np.ndarray:
        return np.abs(field[:, 90:110]).sum((0, 1))  # rows across the board's middle

    field, _ = lidar_field(points, T, K, (200, 640), EdgeMatcherConfig(carry=carry))
    new = profile(field)
    assert abs((new * u)[near].sum() / new[near].sum() - edge_u) < 1.0
    assert new[strip].max() < 0.05 * new[near].max()
    # drawn in the camera, the strip's far border is an edge of its own, where the image has none
    scan = project_scan(points, T, K, (200, 640), Visibility(window=3))
    old = profile(lidar_edges(scan, points, T, K)[0])
    assert old[strip].max() > 0.5 * old[near].max()


def _ground_scan(height_m: float) -> np.ndarray:
    """A LiDAR scan of flat ground ``height_m`` below the LiDAR, rings 0.4° apart, with a bright
    stripe (intensity 1 against 0.2) from 5 to 6 m ahead."""
    azimuth, elevation = np.meshgrid(np.radians(np.arange(-30, 30, 0.2)), np.radians(np.arange(-25, -5, 0.4)))
    d = np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], -1
    )
    d = d.reshape(-1, 3)
    points = d * (height_m / -d[:, 2:])
    intensity = np.where((points[:, 0] > 5.0) & (points[:, 0] < 6.0), 1.0, 0.2)
    return np.column_stack([points, intensity]).astype(np.float32)


@pytest.mark.parametrize(("carry", "error_px"), [("nearer", (-0.8, -0.4)), ("own", (-0.1, 0.1))])
def test_ground_seen_at_a_slant_is_carried_at_its_own_depth(carry, error_px):
    """The stripe's near edge, drawn at the LiDAR 1.7 m above the ground and carried into a camera
    35 cm below it, lands where the ground point on its ray projects: carried at the largest
    inverse depth within 3 px (2.5 % nearer there) it lands 0.66 px up, at its own within 0.1 px."""
    R = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])
    K = np.array([[360.0, 0, 320], [0, 360, -20], [0, 0, 1]])  # the horizon above the image
    T_cam_lidar = np.eye(4)
    T_cam_lidar[:3, :3] = R
    T_cam_lidar[:3, 3] = -R @ np.array([0.0, 0.0, -0.35])
    config = EdgeMatcherConfig(carry=carry, level_laser_gains=False)
    view = VirtualView.draw(_ground_scan(1.7), R, K, (200, 640), config)

    def row(field: np.ndarray, rows: slice) -> float:
        profile = np.abs(field[:, rows, 280:360]).sum((0, 2))
        return float((profile * np.arange(rows.start, rows.stop)).sum() / profile.sum())

    at_lidar = np.eye(4)
    at_lidar[:3, :3] = R
    v_lidar = row(view.seen_from(at_lidar, K)[0], slice(90, 115))  # the stripe's near edge, 5 m ahead
    ahead_m = 1.7 * 360 / (v_lidar + 20)  # where its ray meets the ground
    v_camera = -20 + 360 * (1.7 - 0.35) / ahead_m
    carried = row(view.seen_from(T_cam_lidar, K)[0], slice(int(v_camera) - 8, int(v_camera) + 9))
    assert error_px[0] < carried - v_camera < error_px[1]


def _board_camera(phase: float = 0.0) -> tuple[np.ndarray, np.ndarray, float]:
    """``T_cam_lidar`` of a camera 27 cm ahead of and 30 cm left of the LiDAR, ``K`` of a
    640x200 image whose principal point lies ``phase`` px right of and below (320, 100), and
    the column of :func:`_board_scan`'s left edge in it."""
    R = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ np.array([0.27, 0.3, 0.0])
    K = np.array([[360.0, 0, 320 + phase], [0, 360, 100 + phase], [0, 0, 1]])
    return T, K, K[0, 2] + 360 * (-(0.5 - 0.3) / (5 - 0.27))


def _edge_column(field: np.ndarray, edge_u: float) -> float:
    """The centroid of ``field``'s strength within 3 px of column ``edge_u``, over rows 90-110."""
    u = np.arange(field.shape[2], dtype=float)
    profile, near = np.abs(field[:, 90:110]).sum((0, 1)), np.abs(u - edge_u) < 3
    return float((profile * u)[near].sum() / profile[near].sum())


@pytest.mark.parametrize(("supersample", "spread_px"), [(1, (0.5, 0.8)), (4, (0.0, 0.2))])
def test_supersampled_edges_follow_the_grid_s_phase(supersample, spread_px):
    """A return is drawn at the pixel it falls in, so an edge's position jumps with the grid's
    sub-pixel phase (0.66 px here over eight phases); drawn at four phases and averaged, it
    follows the phase to within 0.2 px."""
    errors = []
    for phase in np.arange(0, 1, 0.125):
        T, K, edge_u = _board_camera(phase)
        config = EdgeMatcherConfig(supersample=supersample)
        field, _ = VirtualView.draw(_board_scan(), T[:3, :3], K, (200, 640), config).seen_from(T, K)
        errors.append(_edge_column(field, edge_u) - edge_u)
    assert spread_px[0] <= np.ptp(errors) <= spread_px[1]
    assert np.abs(errors).max() < 0.5


def test_a_view_drawn_under_another_orientation_is_carried_to_this_one():
    """Drawn 0.5° (3 px) away and carried, the board's edge lies where it lies in the camera
    (within the 0.2 px a four-phase drawing leaves), as in a view drawn under the orientation
    itself, and the two fields agree."""
    T, K, edge_u = _board_camera()
    turned = T.copy()
    turned[:3, :3] = cv2.Rodrigues(np.radians([0.0, 0.5, 0.0]))[0] @ T[:3, :3]
    config = EdgeMatcherConfig(supersample=4)
    carried, inverse_carried = VirtualView.draw(
        _board_scan(), turned[:3, :3], K, (200, 640), config
    ).seen_from(T, K)
    direct, inverse_direct = lidar_field(_board_scan(), T, K, (200, 640), config)
    assert abs(_edge_column(carried, edge_u) - edge_u) < 0.2
    assert abs(_edge_column(direct, edge_u) - edge_u) < 0.2
    inner = (slice(None), slice(20, 180), slice(20, 620))
    agreement = (carried * direct)[inner].sum() / np.sqrt(
        (carried**2)[inner].sum() * (direct**2)[inner].sum()
    )
    assert agreement > 0.8
    assert np.mean(np.abs(inverse_carried - inverse_direct)[20:180, 20:620] < 1e-3) > 0.98


def test_a_rigid_motion_between_two_copies_of_a_scan_is_found_and_a_bent_one_is_not():
    rng = np.random.default_rng(0)
    before = rng.uniform(-20, 20, (5000, 3))
    motion = np.eye(4)
    motion[:3, :3] = cv2.Rodrigues(np.array([0.01, -0.02, 0.03]))[0]
    motion[:3, 3] = [0.1, -0.05, 0.02]
    after = before @ motion[:3, :3].T + motion[:3, 3]
    np.testing.assert_allclose(_rigid_motion(before, after), motion, atol=1e-9)
    np.testing.assert_array_equal(_rigid_motion(before, before), np.eye(4))
    bent = after.copy()
    bent[123] += [0.0, 0.0, 3 * RIGID_TOL_M]
    assert _rigid_motion(before, bent) is None
    assert _rigid_motion(before, after[1:]) is None


def test_a_matcher_draws_a_scan_once_while_only_the_translation_changes(still_vineyard):
    """The virtual view does not depend on the translation: matched under a moved translation
    with the view kept (``redraw_px`` > 0), the answer equals a matcher's that draws anew; a
    turn past ``redraw_px`` draws again."""
    frame = still_vineyard[1]
    T = frame.calibration.T_cam_lidar
    moved = T.copy()
    moved[:3, 3] += [0.02, -0.03, 0.05]
    keeping = EdgeMatcher(EdgeMatcherConfig(redraw_px=4.0))
    keeping.match(frame, T)
    again, fresh = (
        keeping.match(frame, moved),
        EdgeMatcher(EdgeMatcherConfig(redraw_px=0.0)).match(frame, moved),
    )
    np.testing.assert_array_equal(again.index, fresh.index)
    np.testing.assert_array_equal(again.uv_matched, fresh.uv_matched)
    assert [len(views) for views in keeping._views.values()] == [1]
    turned = moved.copy()
    turned[:3, :3] = cv2.Rodrigues(np.radians([0.0, 2.0, 0.0]))[0] @ moved[:3, :3]  # 12 px at f = 360
    keeping.match(frame, turned)
    assert [len(views) for views in keeping._views.values()] == [2]


def _wall_scan(elevations_deg: np.ndarray) -> np.ndarray:
    """A wall 10 m ahead of the LiDAR seen by rings at ``elevations_deg``, 0.2° apart in azimuth."""
    azimuth, elevation = np.meshgrid(np.radians(np.arange(-30, 30, 0.2)), np.radians(elevations_deg))
    d = np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], -1
    )
    d = d.reshape(-1, 3)
    return np.column_stack([d * (10.0 / d[:, :1]), np.ones(len(d))]).astype(np.float32)


@pytest.mark.parametrize(
    "elevations",
    [
        -15 + 1.33 * np.arange(20),  # nuScenes' 32 rings, 1.33° apart
        # a Pandar64 (the PJLab rig): 0.17° apart around the horizon, 1° below it (its median
        # spacing, 0.17°, left sky between the outer rings)
        np.concatenate([-15 + 1.0 * np.arange(9), -6 + 0.167 * np.arange(48)]),
    ],
)
def test_sparse_rings_do_not_read_as_sky_between_them(elevations):
    """A wall seen by rings far apart: the field inside it stays empty (a fill radius smaller than
    the spacing left sky between the rings, an edge on every ring)."""
    T = np.eye(4)
    T[:3, :3] = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])
    K = np.array([[360.0, 0, 320], [0, 360, 100], [0, 0, 1]])
    field, _ = lidar_field(_wall_scan(elevations), T, K, (200, 640))
    inside = np.abs(field[:, 45:160, 130:510]).sum(0)  # within the wall (u 112-528, v 35-196)
    assert inside.max() < 0.05


def test_a_matcher_reused_answers_as_a_new_one_and_keeps_a_moved_scans_features(still_vineyard):
    """The image edges and scan features a matcher keeps are the ones a new matcher computes: the
    same frames matched again, from several threads, give what a fresh matcher gives. A scan moved
    by a few centimetres (as a time offset moves it) keeps the features computed where it was
    first seen; matched so, it differs from a fresh match only where the ring spacing read from
    the moved points differs (a fraction of a percent of the points)."""
    T = perturb(still_vineyard[0].calibration.T_cam_lidar, 2.0, 0.5, torch.Generator().manual_seed(1))
    reused = EdgeMatcher()
    in_threads = match_frames(reused, still_vineyard, T)
    for frame, threaded in zip(still_vineyard, in_threads, strict=True):
        fresh, again = EdgeMatcher().match(frame, T), reused.match(frame, T)
        for corr in (again, threaded):
            np.testing.assert_array_equal(fresh.index, corr.index)
            np.testing.assert_allclose(fresh.uv_matched, corr.uv_matched, atol=1e-4)
    shift = np.array([0.03, -0.02, 0.01, 0.0], np.float32)
    frame = still_vineyard[1]  # (an earlier test empties the first frame's scan)
    moved = replace(frame, points=frame.points + shift)
    features = reused.scan_features(moved.points)
    assert features is reused.scan_features(frame.points)
    assert (
        reused.with_config(EdgeMatcherConfig(working_focal_px=180.0)).scan_features(moved.points) is features
    )
    fresh, again = EdgeMatcher().match(moved, T), reused.match(moved, T)
    common, i, j = np.intersect1d(fresh.index, again.index, return_indices=True)
    assert len(common) > 0.99 * max(len(fresh), len(again))
    assert np.median(np.linalg.norm(fresh.uv_matched[i] - again.uv_matched[j], axis=1)) < 0.01
