"""The time offset in Stage 4's passes: points deskewed and moved to the camera's time, δt fitted
with the extrinsic where the motion tells it apart, held where it does not."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from calib.data.types import Frame
from calib.geometry import calibration_error, perturb
from calib.init.lidar_odometry import scan_motions
from calib.match.correspondences import Correspondences
from calib.motion import ScanMotion
from calib.refine.passes import CalibrateConfig, ScanTiming, refine_passes
from calib.support.source import UniformSupport
from tests.calib.refine.test_outliers import T_TRUE, _frame, _project

TRUE_OFFSET_S = 0.020


def _moving(k: int, still: bool = False) -> ScanMotion:
    """Scan ``k``'s motion: each a different speed and turn rate (or, ``still``, one straight
    constant 8 m/s for all)."""
    if still:
        return ScanMotion(np.array([8.0, 0, 0, 0, 0, 0]), np.array([8.0, 0, 0, 0, 0, 0]))
    v, w = 4.0 + 3.0 * k, 0.4 * (k - 2)
    return ScanMotion(np.array([v, 0, 0, 0, 0, w]), np.array([v + 0.5, 0.1, 0, 0, 0.01, w]))


def _timed_frames(still: bool = False) -> tuple[list[Frame], list[ScanMotion]]:
    """Frames whose points were measured over a sweep (times ±50 ms), each in the LiDAR frame
    of its own time; the camera exposes ``TRUE_OFFSET_S`` after the stamp."""
    frames, motions = [], []
    for k in range(5):
        frame, motion = _frame(k), _moving(k, still)
        times = np.random.default_rng(k).uniform(-0.05, 0.05, len(frame.points))
        stamp = frame.points[:, :3].astype(np.float64)  # where the points are at the stamp
        measured = np.stack([motion.at(q[None], t)[0] for q, t in zip(stamp, times, strict=True)])
        points = np.column_stack([measured, frame.points[:, 3]]).astype(np.float32)
        frames.append(replace(frame, points=points, point_times=times))
        motions.append(motion)
    return frames, motions


class TimedMatcher:
    """Matches every point perfectly: its pixel is where the true extrinsic projects it at the
    camera's true time, ``offset_s`` after the stamp (each frame's points arrive moved to the
    current δt, in order)."""

    name = "timed"

    def __init__(
        self, frames: list[Frame], motions: list[ScanMotion], offset_s: float = TRUE_OFFSET_S
    ) -> None:
        self.truth = {
            f.name: _project(
                m.at(m.deskew(f.points[:, :3].astype(np.float64), f.point_times), offset_s), T_TRUE
            )
            for f, m in zip(frames, motions, strict=True)
        }

    def match(self, frame: Frame, T_cam_lidar: np.ndarray) -> Correspondences:
        points = frame.points[:, :3].astype(np.float64)
        return Correspondences(
            np.arange(len(points)),
            points,
            _project(points, T_cam_lidar),
            self.truth[frame.name],
            np.ones(len(points), np.float32),
            (240, 640),
        )


def _run(frames, motions, timing, offset_s=TRUE_OFFSET_S):
    T_init = perturb(T_TRUE, 5.0, 1.0, torch.Generator().manual_seed(2))
    config = CalibrateConfig(passes=4, sampling={"per_frame": 1000})
    return refine_passes(
        frames,
        T_init,
        TimedMatcher(frames, motions, offset_s),
        UniformSupport(),
        config,
        np.random.default_rng(0),
        timing=timing,
    )


def test_passes_recover_a_20ms_offset_from_deskewed_moving_scans():
    frames, motions = _timed_frames()
    result = _run(frames, motions, ScanTiming.of(frames, motions, 0.0, estimate=True))
    error = calibration_error(result.T_cam_lidar, T_TRUE)
    assert abs(result.time_offset_s - TRUE_OFFSET_S) < 2e-4
    assert error.translation_cm < 0.1 and error.rotation_deg < 0.01
    assert result.time_offset_std_s is not None and all("time_offset_s" in p for p in result.passes)


def test_delta_t_restarts_are_probed_once_settled_and_kept_out_where_no_better():
    """A 45 ms offset, reached from 0 (the matcher is exact): the restarts at the settled δt
    ± 25 ms are each probed with one pass, recorded, and not taken (they cannot end better
    aligned than the truth); the answer stays at the truth."""
    frames, motions = _timed_frames()
    timing = ScanTiming.of(frames, motions, 0.0, estimate=True, restarts_s=(-0.025, 0.025))
    result = _run(frames, motions, timing, offset_s=0.045)
    assert abs(result.time_offset_s - 0.045) < 2e-4
    assert calibration_error(result.T_cam_lidar, T_TRUE).translation_cm < 0.1
    restarts = result.time_offset_restarts
    assert [round(r["time_offset_from_s"] - result.time_offset_s, 3) for r in restarts] == [-0.025, 0.025]
    assert not any(r["taken"] for r in restarts) and not any(p.get("restart") for p in result.passes)
    held = ScanTiming.of(frames, motions, 0.0, estimate=False, restarts_s=(-0.025, 0.025))
    assert held.restarts_s == ()  # a held δt has nothing to restart


def test_a_timing_of_some_frames_moves_those_frames_as_the_whole_one_does():
    """``ScanTiming.of_frames``: the subset keeps its frames' motions and deskewed points in
    order, and every setting; the frames it moves land where the whole timing moves them."""
    frames, motions = _timed_frames()
    timing = ScanTiming.of(frames, motions, 0.01, estimate=True, restarts_s=(-0.025, 0.025))
    some = timing.of_frames([0, 2])
    assert some.motions == [timing.motions[0], timing.motions[2]]
    assert replace(some, motions=timing.motions, stamp=timing.stamp) == timing
    moved = some.frames_at([frames[0], frames[2]], 0.02)
    whole = timing.frames_at(frames, 0.02)
    assert np.array_equal(moved[1].points, whole[2].points)


def test_without_the_time_model_the_same_data_biases_the_extrinsic():
    frames, motions = _timed_frames()
    result = _run(frames, motions, None)
    assert calibration_error(result.T_cam_lidar, T_TRUE).translation_cm > 3.0
    assert result.time_offset_s is None


def test_one_straight_constant_motion_for_all_frames_holds_the_offset():
    """δt · v is then a translation along v: not observable, so held at the start and said so."""
    frames, motions = _timed_frames(still=True)
    result = _run(frames, motions, ScanTiming.of(frames, motions, 0.0, estimate=True, max_std_s=0.002))
    assert result.time_offset_s == 0.0 and result.time_offset_std_s is None


def test_scan_motions_say_why_they_cannot_be_had():
    frames = [_frame(k) for k in range(3)]
    assert scan_motions(frames[:1], [0]) == (None, "a single frame shows no motion")
    motions, why = scan_motions(frames, [1])
    assert motions is None and "no time stamps" in why
    spaced = [replace(f, timestamp=10.0 * k) for k, f in enumerate(frames)]
    motions, why = scan_motions(spaced, [1])
    assert motions is None and "not consecutive" in why


def test_known_motions_must_cover_every_used_frame():
    from calib.errors import DataError
    from calib.pipeline import Calibrator
    from calib.refine.passes import load_calibrate_config

    base = load_calibrate_config()
    config = base.model_copy(
        update={
            "time_offset": base.time_offset.model_copy(update={"mode": "estimate"}),
            "flow_coarse_passes": 0,  # calib's Calibrator has no learned matcher
        }
    )
    frames = [_frame(k) for k in range(3)]
    with pytest.raises(DataError, match=r"no motion for the frames at positions \[1, 2\]"):
        Calibrator(config=config).calibrate(frames, T_TRUE, motions={0: ScanMotion.still()})


def test_the_pyramid_level_at_time_offset_from_px_runs_the_restarts(monkeypatch):
    """δt is held on the pyramid's coarser levels, estimated from ``time_offset.from_px`` on with
    the restarts at the first such level (within its reach), and the finest passes go on from its
    δt without them."""
    import calib.pipeline as pipeline
    from calib.refine.passes import PassesResult

    calls = []

    def recording(frames, T_init, matcher, support, config, rng, alternatives=(), timing=None):
        calls.append((config.edge.working_focal_px, timing.estimate, timing.restarts_s, timing.offset_s))
        return PassesResult(T_init, np.eye(6) * 1e-6, [], 100, time_offset_s=0.004 * len(calls))

    monkeypatch.setattr(pipeline, "refine_passes", recording)
    base = CalibrateConfig(frames=5)
    config = base.model_copy(
        update={
            "finest_focal_px": 1000.0,
            "pyramid_focals_px": (90.0, 180.0),
            "coarse": base.coarse.model_copy(update={"enabled": False}),
            "time_offset": base.time_offset.model_copy(update={"from_px": 180.0}),
        }
    )
    frames, motions = _timed_frames()
    frames = [replace(f, timestamp=0.1 * k, lidar_timestamp=0.1 * k) for k, f in enumerate(frames)]
    pipeline.Calibrator(config=config).calibrate(frames, T_TRUE, motions=dict(enumerate(motions)))
    restarts = tuple(ms / 1e3 for ms in base.time_offset.restarts_ms)
    assert calls == [
        (90.0, False, (), 0.0),  # held
        (180.0, True, restarts, 0.0),  # estimated, with the restarts
        (1000.0, True, (), 0.008),  # from the 180 px level's δt, without them
    ]
