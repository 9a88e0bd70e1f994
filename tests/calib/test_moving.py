from dataclasses import replace

import numpy as np
import pytest

from calib.data.types import Calibration, Frame
from calib.motion import ScanMotion
from calib.moving import MovingConfig, moving_points, seen_through, shadowed, without_moving


def _scan(origin=(0.0, 0.0), boxes=(), step_deg=0.2) -> tuple[np.ndarray, np.ndarray]:
    """A 32-ring scan from ``origin`` (x, y; metres) of a round room (radius 15 m around the
    world's origin, walls 6 m high, floor 1.7 m below the sensor) holding ``boxes``: each
    ``(x, y, half_size)``, an axis-aligned box from the floor up to 0.2 m above the sensor.
    Returns the points in the sensor frame and which hit a box."""
    el, az = np.meshgrid(np.radians(np.linspace(2.0, -15.0, 32)), np.radians(np.arange(-180, 180, step_deg)))
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
    o = np.array([*origin, 0.0])
    # the wall: |o_xy + t d_xy| = 15
    a, b = (d[:, :2] ** 2).sum(1), 2 * (d[:, :2] @ o[:2])
    wall = (-b + np.sqrt(b * b - 4 * a * (o[:2] @ o[:2] - 15.0**2))) / (2 * a)
    floor = np.where(d[:, 2] < 0, -1.7 / np.minimum(d[:, 2], -1e-9), np.inf)
    t, hit_box = np.minimum(wall, floor), np.zeros(len(d), bool)
    for x, y, h in boxes:  # slab test against [x±h] x [y±h] x [-1.7, 0.2]
        lo, hi = np.array([x - h, y - h, -1.7]) - o, np.array([x + h, y + h, 0.2]) - o
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = lo / d, hi / d
        near, far = np.nanmax(np.minimum(t1, t2), 1), np.nanmin(np.maximum(t1, t2), 1)
        hit = (near <= far) & (near > 0) & (near < t)
        t, hit_box = np.where(hit, near, t), hit_box | hit
    return d * t[:, None], hit_box


ABOVE_GROUND = -1.05
"""In these scans each 2 m cell's lowest return is the ground: under the box, its own lowest (the
rings reach 1.34 m down at 5 m), so it counts as an object from 0.25 m above that."""


def test_a_box_that_moved_is_seen_through_and_the_room_is_not():
    points, box = _scan(boxes=[(6.0, 0.0, 1.0)])
    before, _ = _scan(boxes=[(6.0, -3.0, 1.0)])  # the box 3 m to the side in the scans around
    after, _ = _scan(boxes=[(6.0, 3.0, 1.0)])
    through = seen_through(points, [before, after])
    assert through.shape == (len(points),)
    assert box.sum() > 100 and through[box].mean() > 0.95
    assert through[~box].mean() < 0.002
    moving = moving_points(points, [before, after])
    assert moving[box & (points[:, 2] > ABOVE_GROUND)].all() and not moving[~box].any()


def test_a_box_that_stayed_and_one_hidden_are_not_convicted():
    points, box = _scan(boxes=[(6.0, 0.0, 1.0)])
    assert not seen_through(points, [points.copy()]).any()
    # another scan that sees the box's place only behind something nearer knows nothing of it
    hidden, _ = _scan(boxes=[(3.0, 0.0, 1.2)])
    assert seen_through(points, [hidden])[box].mean() < 0.02
    assert not moving_points(points, [hidden]).any()
    assert not moving_points(points, []).any()


def test_a_static_room_seen_from_a_moving_sensor_stays():
    boxes = [(6.0, 0.0, 0.5), (4.0, 5.0, 0.3)]  # a pillar and a post, static
    points, _ = _scan(origin=(0.0, 0.0), boxes=boxes)
    others = []
    for dx in (-2.4, 2.4):  # the sensor 2.4 m back and ahead, its points carried here
        other, _ = _scan(origin=(dx, 0.0), boxes=boxes)
        others.append(other + [dx, 0.0, 0.0])
    assert seen_through(points, others).mean() < 0.005
    assert not moving_points(points, others).any()


@pytest.mark.parametrize("margin_m", [0.5, 12.0])
def test_a_larger_margin_convicts_less(margin_m):
    points, box = _scan(boxes=[(6.0, 0.0, 1.0)])
    before, _ = _scan(boxes=[(6.0, -3.0, 1.0)])
    share = seen_through(points, [before], MovingConfig(margin_m=margin_m))[box].mean()
    # the wall lies at most 10 m behind the box's face: a 12 m margin convicts none of it
    assert share > 0.9 if margin_m == 0.5 else share == 0


def test_an_object_half_seen_through_moves_as_a_whole():
    points, box = _scan(boxes=[(6.0, 0.0, 1.0)])
    nudged, _ = _scan(boxes=[(6.0, 1.2, 1.0)])  # moved 1.2 m: the other scan sees through its left part
    assert 0.3 < seen_through(points, [nudged])[box].mean() < 0.8
    object_ = box & (points[:, 2] > ABOVE_GROUND)
    assert moving_points(points, [nudged])[object_].all()  # the cluster's verdict
    assert not moving_points(points, [nudged], MovingConfig(object_share=0.9))[object_].any()


def _directions_deg(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return (
        np.degrees(np.arctan2(points[:, 1], points[:, 0])),
        np.degrees(np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1]))),
    )


def test_the_shadow_takes_what_lies_beside_and_behind_a_moving_thing():
    # a box 5-7 m ahead (its near face spans azimuths within ±11.3°) before the 15 m wall, and a
    # post 3 m ahead, nearer than the box, at azimuths -12.5° to -14.5°
    points, box = _scan(boxes=[(6.0, 0.0, 1.0), (3.0, -0.72, 0.05)])
    azimuth, elevation = _directions_deg(points)
    post = box & (azimuth < -12.0)
    box &= ~post
    assert not shadowed(points, box, MovingConfig(shadow_deg=0.0)).any()
    shadow = shadowed(points, box, MovingConfig(shadow_deg=2.0))
    assert not shadow[box].any() and not shadow[post].any()  # the thing itself, and what is nearer
    wall = np.linalg.norm(points[:, :2], axis=1) > 14.0
    beside = wall & (azimuth > 11.8) & (azimuth < 12.8)
    far = wall & (np.abs(azimuth) > 14.5)
    assert beside.sum() > 20 and shadow[beside].all()  # 0.5-1.5° past the box's edge: within 2°
    assert far.sum() > 1000 and not shadow[far].any()  # 3.2° past it or more: outside


def _frames(box_y: list[float]) -> list[Frame]:
    """Scans 0.1 s apart of a still sensor, a box at ``y = box_y[k]`` in scan ``k``; labels 1 on
    the box, 0 elsewhere."""
    frames = []
    for k, y in enumerate(box_y):
        points, box = _scan(boxes=[(6.0, y, 1.0)])
        frames.append(
            Frame(
                image=np.zeros((100, 100, 3), np.uint8),
                points=np.column_stack([points, np.ones(len(points))]).astype(np.float32),
                calibration=Calibration(
                    K=np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]]), T_cam_lidar=np.eye(4)
                ),
                index=k,
                timestamp=0.1 * k,
                labels=box.astype(np.uint16),
            )
        )
    return frames


def test_without_moving_drops_them_from_the_frames_that_have_scans_around():
    seq = _frames([-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0])  # the box drives 10 m/s across
    config = MovingConfig(scans_apart=3, shadow_deg=0.0)  # the detector alone
    picks = [3, 0]
    frames = [seq[i] for i in picks]
    stamps = [f.points[:, :3].astype(np.float64) for f in frames]  # a still sensor: as measured
    kept, masks = without_moving(seq, picks, frames, stamps, [ScanMotion.still()] * 2, config, lambda f: None)
    lost = [int(m.sum()) for m in masks]
    box = seq[3].labels == 1
    assert (box & (seq[3].points[:, 2] > ABOVE_GROUND)).sum() <= lost[0] <= box.sum()
    assert len(kept[0].points) == len(seq[3].points) - lost[0]
    assert kept[0].labels.sum() == box.sum() - lost[0]  # labels follow their points
    # frame 0 has scan 3 after it (its box 3 m away): it loses its box too
    box = seq[0].labels == 1
    assert (box & (seq[0].points[:, 2] > ABOVE_GROUND)).sum() <= lost[1] <= box.sum()
    # the packaged shadow adds the top of the box's foot (in the ground band no cluster holds)
    # and static points beside it, within a degree of its azimuths
    _, shadowed_masks = without_moving(
        seq, picks, frames, stamps, [ScanMotion.still()] * 2, MovingConfig(scans_apart=3), lambda f: None
    )
    extra = shadowed_masks[0] & ~masks[0]
    azimuth = np.degrees(np.arctan2(seq[3].points[:, 1], seq[3].points[:, 0]))
    assert (shadowed_masks[0] >= masks[0]).all() and extra.sum() > 50
    box = seq[3].labels == 1
    assert (extra & box).sum() > 50 and (extra & ~box).sum() > 50
    assert (np.abs(azimuth[extra]) < 11.3 + 1.0).all()
    # without stamps a frame keeps its points
    unstamped = [replace(f, timestamp=None) for f in seq]
    stamps = [unstamped[3].points[:, :3].astype(np.float64)]
    _, masks = without_moving(
        unstamped, [3], [unstamped[3]], stamps, [ScanMotion.still()], config, lambda f: None
    )
    assert [int(m.sum()) for m in masks] == [0]


def _without_shadow(**time_offset):
    """A seven-frame calibrate config with no moving car's shadow left out and ``time_offset``'s
    keys set."""
    from calib.refine.passes import CalibrateConfig

    base = CalibrateConfig(frames=7)
    return base.model_copy(
        update={
            "outliers": base.outliers.model_copy(
                update={"moving": base.outliers.moving.model_copy(update={"shadow_deg": 0.0})}
            ),
            "time_offset": base.time_offset.model_copy(update=time_offset),
        }
    )


@pytest.mark.parametrize(("mode", "initial_s"), [("estimate", 0.0), ("fixed", 0.0), ("fixed", 0.02)])
def test_the_calibrator_leaves_them_out_where_the_time_offset_is_estimated_or_not_0(
    monkeypatch, mode, initial_s
):
    import calib.pipeline as pipeline
    from calib.refine.passes import PassesResult

    seen = []

    def recording(frames, T_init, matcher, support, config, rng, alternatives=(), timing=None):
        seen.append([len(f.points) for f in frames])
        return PassesResult(T_init, np.eye(6) * 1e-6, [], 100, time_offset_s=timing.offset_s)

    monkeypatch.setattr(pipeline, "refine_passes", recording)
    config = _without_shadow(mode=mode, initial_s=initial_s, min_speed_spread_mps=1e-9, restarts_ms=())
    config = config.model_copy(
        update={
            "finest_focal_px": 100.0,
            "pyramid_focals_px": (),
            "coarse": config.coarse.model_copy(update={"enabled": False}),
        }
    )
    seq = _frames([-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0])
    # the sensor stands (its speeds differ by micrometres a second: enough to tell δt apart)
    motions = {
        k: ScanMotion(np.array([1e-6 * k, 0, 0, 0, 0, 0]), np.array([1e-6 * k, 0, 0, 0, 0, 0]))
        for k in range(7)
    }
    result = pipeline.Calibrator(config=config).calibrate(seq, np.eye(4), motions=motions)
    upper = [int(((f.labels == 1) & (f.points[:, 2] > ABOVE_GROUND)).sum()) for f in seq]
    boxes = [int((f.labels == 1).sum()) for f in seq]
    if mode == "fixed" and initial_s == 0:  # the cars the camera saw at the scan's time stay
        assert result.moving_points == [0] * 7 and seen[0] == [len(f.points) for f in seq]
    else:  # every frame has a scan 3 apart on one side at least, its box 3 m away
        assert all(u <= lost <= b for u, lost, b in zip(upper, result.moving_points, boxes, strict=True))
        assert seen[0] == [len(f.points) - lost for f, lost in zip(seq, result.moving_points, strict=True)]
        assert result.to_dict()["moving_points"] == result.moving_points


@pytest.mark.parametrize("offset_known", [True, False])
def test_an_online_window_leaves_them_out_at_its_first_guess_of_0(offset_known):
    from calib.pipeline import camera_time

    config = _without_shadow(mode="fixed", initial_s=0.0)
    seq = _frames([-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0])
    still = {k: ScanMotion.still() for k in range(7)}
    timing, _, frames, lost = camera_time(
        config, seq, [3], [seq[3]], still, restarts=False, offset_known=offset_known
    )
    assert timing is not None and not timing.estimate and timing.offset_s == 0.0
    box = int((seq[3].labels == 1).sum())
    if offset_known:  # a known 0: the cars the camera saw at the scan's time stay
        assert lost == [0] and len(frames[0].points) == len(seq[3].points)
    else:
        assert 0 < lost[0] <= box and len(frames[0].points) == len(seq[3].points) - lost[0]
