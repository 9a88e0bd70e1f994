"""Outlier rules of Stage 4 (calib/refine/outliers.py) and how refine_passes uses them: a frame of
wrong matches sits out, a pass that makes the matcher's residuals worse is undone."""

import threading

import numpy as np
import pytest
import torch
from pydantic import ValidationError

from calib.data.types import Calibration, Frame
from calib.errors import NumericalError
from calib.geometry import calibration_error, perturb
from calib.match.correspondences import Correspondences
from calib.refine.outliers import RAYLEIGH_MEDIAN, OutlierConfig, frame_outliers, near_points, trim_points
from calib.refine.passes import CalibrateConfig, _common_medians, refine_passes
from calib.support.source import UniformSupport

K = np.array([[500.0, 0, 320], [0, 500, 120], [0, 0, 1]])
T_TRUE = np.array([[0, -1, 0, 0.05], [0, 0, -1, -0.1], [1, 0, 0, 0.2], [0, 0, 0, 1.0]])  # LiDAR x forward


def test_near_points_known_answer():
    points = np.array([[1.0, 0, 0, 5], [0, 2.0, 0, 5], [0.3, 0.3, 0.3, 5]])
    assert near_points(points, 1.5).tolist() == [True, False, True]
    assert not near_points(points, 0.0).any()


def test_frame_outliers_known_answers():
    assert frame_outliers(np.array([1.0, 1.2, 0.9, 5.0]), 2.5, 3.0).tolist() == [False, False, False, True]
    assert not frame_outliers(np.array([1.0, 1.2, 0.9, 2.9]), 2.5, 3.0).any()  # under the floor
    assert not frame_outliers(np.array([1.0, 50.0]), 2.5, 3.0).any()  # two frames cannot outvote
    medians = np.array([1.0, 1.0, 1.0, 9.0, 9.0, 9.0])
    assert frame_outliers(medians, 2.5, 0.0).sum() <= len(medians) // 2


def test_trim_points_keeps_gaussian_residuals_and_drops_gross_ones():
    rng = np.random.default_rng(0)
    inliers = np.linalg.norm(rng.normal(0, 1.5, (5000, 2)), axis=1)
    assert np.median(inliers) / RAYLEIGH_MEDIAN == pytest.approx(1.5, rel=0.05)
    residual = np.concatenate([inliers, np.full(500, 40.0)])
    keep = trim_points(residual, 3.0, 2.0)
    assert not keep[5000:].any()
    assert keep[:5000].mean() > 0.98  # 3σ of a 2-D Gaussian norm passes 98.9 %
    assert trim_points(np.array([0.1, 0.1, 1.9]), 3.0, 2.0).all()  # within the floor
    assert trim_points(np.zeros(0), 3.0, 2.0).shape == (0,)


def test_outlier_config_is_validated():
    with pytest.raises(ValidationError):
        OutlierConfig(frame_factor=0.5)
    with pytest.raises(ValidationError):
        OutlierConfig(unknown=1)


def _frame(seed: int) -> Frame:
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(5, 30, 3000), rng.uniform(-8, 8, 3000), rng.uniform(-1.5, 3, 3000)])
    return Frame(
        image=np.zeros((240, 640, 3), np.uint8),
        points=np.column_stack([points, np.ones(3000)]).astype(np.float32),
        calibration=Calibration(K=K, T_cam_lidar=T_TRUE),
        name=f"f{seed}",
    )


def _project(points: np.ndarray, T: np.ndarray) -> np.ndarray:
    q = points @ T[:3, :3].T + T[:3, 3]
    return (q @ K.T)[:, :2] / q[:, 2:3]


class ScriptedMatcher:
    """Matches every frame perfectly toward ``T_TRUE``, except: frames in ``liars`` always point
    toward ``T_lie``, and the first ``lie_calls`` calls point toward ``T_lie`` everywhere."""

    name = "scripted"

    def __init__(self, T_lie: np.ndarray, liars: tuple[str, ...] = (), lie_calls: int = 0) -> None:
        self.T_lie, self.liars, self.lie_calls, self.calls = T_lie, liars, lie_calls, 0

    def match(self, frame: Frame, T_cam_lidar: np.ndarray) -> Correspondences:
        self.calls += 1
        lying = frame.name in self.liars or self.calls <= self.lie_calls
        points = frame.points[:, :3].astype(np.float64)
        uv = _project(points, T_cam_lidar)
        target = _project(points, self.T_lie if lying else T_TRUE)
        return Correspondences(
            np.arange(len(points)), points, uv, target, np.ones(len(points), np.float32), (240, 640)
        )


def test_a_frame_of_wrong_matches_sits_out():
    frames = [_frame(i) for i in range(5)]
    T_lie = perturb(T_TRUE, 5.0, 0.6, torch.Generator().manual_seed(1))  # inside the loss's reach
    T_init = perturb(T_TRUE, 5.0, 1.0, torch.Generator().manual_seed(2))
    config = CalibrateConfig(passes=4, sampling={"per_frame": 500})
    result = refine_passes(
        frames,
        T_init,
        ScriptedMatcher(T_lie, liars=("f3",)),
        UniformSupport(),
        config,
        np.random.default_rng(0),
    )
    error = calibration_error(result.T_cam_lidar, T_TRUE)
    assert error.translation_cm < 0.05 and error.rotation_deg < 0.005
    assert [3] in [p["frames_left_out"] for p in result.passes]
    # without the rules the liar pulls the shared estimate off: its residuals (a few pixels)
    # are inliers to the robust loss
    lenient = config.model_copy(update={"outliers": OutlierConfig(frame_factor=1000.0, point_sigmas=1000.0)})
    pulled = refine_passes(
        frames,
        T_init,
        ScriptedMatcher(T_lie, liars=("f3",)),
        UniformSupport(),
        lenient,
        np.random.default_rng(0),
    )
    pulled_error = calibration_error(pulled.T_cam_lidar, T_TRUE)
    assert pulled_error.rotation_deg > 0.02 and pulled_error.translation_cm > 0.2


def test_a_pass_that_makes_the_residuals_worse_is_undone():
    frames = [_frame(i) for i in range(3)]
    T_init = perturb(T_TRUE, 2.0, 0.5, torch.Generator().manual_seed(3))
    T_lie = perturb(T_init, 10.0, 2.0, torch.Generator().manual_seed(4))  # farther from the truth
    # every pass checked (the lie is farther than the matcher's reach a real check needs)
    config = CalibrateConfig(
        passes=3, sampling={"per_frame": 500}, halvings=0, check_below_px=100.0, halve_above=(0.0, 0.0)
    )
    matcher = ScriptedMatcher(T_lie, lie_calls=len(frames))  # the first pass is led astray
    result = refine_passes(frames, T_init, matcher, UniformSupport(), config, np.random.default_rng(0))
    assert np.allclose(result.T_cam_lidar, T_init)
    assert result.passes[0]["accepted"] is False
    assert result.passes[0]["alignment_after_px"] > result.passes[0]["alignment_px"]
    assert len(result.passes) == 1 and matcher.calls == 2 * len(frames)
    # backtracking: the step is halved until the residuals fall, and the next passes go on
    halving = config.model_copy(update={"halvings": 4})
    matcher = ScriptedMatcher(T_lie, lie_calls=len(frames))
    backed = refine_passes(frames, T_init, matcher, UniformSupport(), halving, np.random.default_rng(0))
    assert backed.passes[0]["accepted"] and backed.passes[0]["step"] < 1
    assert backed.passes[0]["alignment_after_px"] < backed.passes[0]["alignment_px"]
    assert calibration_error(backed.T_cam_lidar, T_TRUE).rotation_deg < 0.001
    # a pass smaller than `halve_above` is undone at once, without halvings
    small = halving.model_copy(update={"halve_above": (1000.0, 1000.0)})
    matcher = ScriptedMatcher(T_lie, lie_calls=len(frames))
    undone = refine_passes(frames, T_init, matcher, UniformSupport(), small, np.random.default_rng(0))
    assert np.allclose(undone.T_cam_lidar, T_init) and undone.passes[0]["accepted"] is False
    assert len(undone.passes) == 1 and matcher.calls == 2 * len(frames)
    # unchecked, the pass is kept
    unchecked = config.model_copy(update={"check_passes": False, "passes": 1})
    kept = refine_passes(
        frames,
        T_init,
        ScriptedMatcher(T_lie, lie_calls=3),
        UniformSupport(),
        unchecked,
        np.random.default_rng(0),
    )
    assert calibration_error(kept.T_cam_lidar, T_lie).rotation_deg < 0.001


def test_a_pass_is_undone_only_when_it_raises_the_median_by_more_than_the_tolerance():
    frames = [_frame(i) for i in range(3)]
    T_init = perturb(T_TRUE, 2.0, 0.5, torch.Generator().manual_seed(3))
    T_lie = perturb(T_init, 10.0, 2.0, torch.Generator().manual_seed(4))
    config = CalibrateConfig(
        passes=1, sampling={"per_frame": 500}, halvings=0, check_below_px=100.0, halve_above=(0.0, 0.0)
    )

    def led_astray(tolerance: float):  # the first pass is led toward T_lie, then checked
        tolerant = config.model_copy(update={"check_tolerance": tolerance})
        matcher = ScriptedMatcher(T_lie, lie_calls=len(frames))
        return refine_passes(frames, T_init, matcher, UniformSupport(), tolerant, np.random.default_rng(0))

    undone = led_astray(0.0)
    before, after = undone.passes[0]["alignment_px"], undone.passes[0]["alignment_after_px"]
    assert not undone.passes[0]["accepted"] and after > before
    rise = after / before - 1
    for tolerance, kept in ((0.9 * rise, False), (1.1 * rise, True)):
        result = led_astray(tolerance)
        assert result.passes[0]["accepted"] is kept
        assert calibration_error(result.T_cam_lidar, T_lie if kept else T_init).rotation_deg < 0.001


class GainingMatcher(ScriptedMatcher):
    """A :class:`ScriptedMatcher` that keeps only the first ``first_points`` points of each frame
    in its first ``lie_calls`` calls (led astray), and every point after them."""

    def __init__(self, T_lie: np.ndarray, lie_calls: int, first_points: int) -> None:
        super().__init__(T_lie, lie_calls=lie_calls)
        self.first_points = first_points

    def match(self, frame: Frame, T_cam_lidar: np.ndarray) -> Correspondences:
        early = self.calls < self.lie_calls
        corr = super().match(frame, T_cam_lidar)
        n = self.first_points if early else len(corr)
        return Correspondences(
            corr.index[:n],
            corr.points_lidar[:n],
            corr.uv[:n],
            corr.uv_matched[:n],
            corr.confidence[:n],
            corr.image_size,
        )


def test_a_pass_that_raises_the_median_but_matches_more_is_kept_with_check_gain():
    """``check_gain``: a checked pass whose median rose is kept where the matching after it keeps
    more than ``1 + check_gain`` times the matches of the one before (2000 -> 3000 points a frame
    here: kept from a gain of 0.3, undone at 0.6 and without the rule), and only where the matcher
    works under ``matched_below_px``."""
    frames = [_frame(i) for i in range(3)]
    T_init = perturb(T_TRUE, 2.0, 0.5, torch.Generator().manual_seed(3))
    T_lie = perturb(T_init, 10.0, 2.0, torch.Generator().manual_seed(4))
    config = CalibrateConfig(
        passes=1, sampling={"per_frame": 500}, halvings=0, check_below_px=100.0, halve_above=(0.0, 0.0)
    )

    def led_astray(gain: float | None, below_px: float | None = None):  # led toward T_lie, then checked
        gaining = config.model_copy(update={"check_gain": gain, "matched_below_px": below_px})
        matcher = GainingMatcher(T_lie, lie_calls=len(frames), first_points=2000)
        return refine_passes(frames, T_init, matcher, UniformSupport(), gaining, np.random.default_rng(0))

    for gain, kept in ((None, False), (0.6, False), (0.3, True)):
        result = led_astray(gain)
        step = result.passes[0]
        assert step["alignment_after_px"] > step["alignment_px"]  # the median rose
        assert (step["matched"], step["matched_after"]) == (6000, 9000)
        assert step["accepted"] is kept
        assert calibration_error(result.T_cam_lidar, T_lie if kept else T_init).rotation_deg < 0.001
        assert result.matched == (6000, 9000 if kept else 6000)
    # matched_below_px: the rule holds only where the matcher works under that focal length
    working = config.edge.working_focal_px
    assert led_astray(0.3, below_px=working + 1.0).passes[0]["accepted"]
    assert not led_astray(0.3, below_px=working).passes[0]["accepted"]


def test_a_pass_too_small_to_judge_settles_its_level_without_a_check():
    frames = [_frame(i) for i in range(3)]
    T_init = perturb(T_TRUE, 2.0, 0.5, torch.Generator().manual_seed(3))
    config = CalibrateConfig(passes=5, sampling={"per_frame": 500}, check_below_px=100.0)
    # checked: the first pass lands on the truth, the second moves it by nothing (settled by
    # min_update) once the matching after it says so: three matchings
    matcher = ScriptedMatcher(T_TRUE)
    checked = refine_passes(frames, T_init, matcher, UniformSupport(), config, np.random.default_rng(0))
    assert matcher.calls == 3 * len(frames) and "settled" not in checked.passes[-1]
    # with settle_px the second pass (well under 0.1 px) settles unchecked: two matchings
    settling = config.model_copy(update={"settle_px": 0.1})
    matcher = ScriptedMatcher(T_TRUE)
    settled = refine_passes(frames, T_init, matcher, UniformSupport(), settling, np.random.default_rng(0))
    assert matcher.calls == 2 * len(frames)
    assert [p.get("settled", False) for p in settled.passes] == [False, True]
    assert settled.passes[0]["update_px"] > 1.0 > 0.1 > settled.passes[1]["update_px"]
    assert calibration_error(settled.T_cam_lidar, checked.T_cam_lidar).rotation_deg < 1e-4
    # a step under settle_px is kept unchecked, even one a check would have undone
    T_lie = perturb(T_init, 0.01, 0.005, torch.Generator().manual_seed(4))  # 0.04 px away
    matcher = ScriptedMatcher(T_lie, lie_calls=len(frames))
    kept = refine_passes(frames, T_init, matcher, UniformSupport(), settling, np.random.default_rng(0))
    assert matcher.calls == len(frames) and kept.passes[0]["settled"]
    assert calibration_error(kept.T_cam_lidar, T_lie).rotation_deg < 1e-4
    matcher = ScriptedMatcher(T_lie, lie_calls=len(frames))
    undone = refine_passes(frames, T_init, matcher, UniformSupport(), config, np.random.default_rng(0))
    assert not undone.passes[0]["accepted"] and np.allclose(undone.T_cam_lidar, T_init)


def test_no_matching_follows_a_last_pass_that_no_matching_could_check():
    """A pass that starts beyond the matcher's reach (``check_below_px``) is not checked, so when
    it is the last, the matching after it would change nothing and is not made."""
    frames = [_frame(i) for i in range(3)]
    T_init = perturb(T_TRUE, 10.0, 3.0, torch.Generator().manual_seed(5))  # tens of pixels off
    far = CalibrateConfig(passes=1, sampling={"per_frame": 500})
    matcher = ScriptedMatcher(T_TRUE)
    result = refine_passes(frames, T_init, matcher, UniformSupport(), far, np.random.default_rng(0))
    assert result.passes[0]["alignment_px"] > far.check_below_px * K[0, 0] / far.edge.working_focal_px
    assert matcher.calls == len(frames) and "alignment_after_px" not in result.passes[0]
    assert calibration_error(result.T_cam_lidar, T_TRUE).rotation_deg < 0.01
    # within reach the last pass is checked, so matched after
    near = far.model_copy(update={"check_below_px": 100.0})
    matcher = ScriptedMatcher(T_TRUE)
    checked = refine_passes(frames, T_init, matcher, UniformSupport(), near, np.random.default_rng(0))
    assert matcher.calls == 2 * len(frames) and "alignment_after_px" in checked.passes[0]
    assert np.allclose(checked.T_cam_lidar, result.T_cam_lidar)


class ShedsFar:
    """Honest toward ``T_TRUE``, but what it keeps depends on the pose: more than 1 cm off it keeps
    only the points nearer than 15 m; nearer the truth it keeps all, and those farther than 15 m
    it matches 3 px off (far edges it confuses)."""

    name = "sheds far"

    def __init__(self) -> None:
        self.calls = 0

    def match(self, frame: Frame, T_cam_lidar: np.ndarray) -> Correspondences:
        self.calls += 1
        points = frame.points[:, :3].astype(np.float64)
        far = points[:, 0] >= 15.0
        target = _project(points, T_TRUE)
        if calibration_error(T_cam_lidar, T_TRUE).translation_cm > 1.0:
            keep = ~far
        else:
            keep = np.ones(len(points), bool)
            target[far, 0] += 3.0
        index = np.flatnonzero(keep)
        return Correspondences(
            index,
            points[index],
            _project(points[index], T_cam_lidar),
            target[index],
            np.ones(len(index), np.float32),
            (240, 640),
        )


def test_common_medians_compare_the_points_both_matchings_keep():
    def corr(index, residual_px):
        index = np.asarray(index)
        uv = np.zeros((len(index), 2))
        return Correspondences(
            index,
            np.ones((len(index), 3)),
            uv,
            uv + [[r, 0.0] for r in residual_px],
            np.ones(len(index)),
            (9, 9),
        )

    before = [corr([0, 1, 2, 3], [1.0, 2.0, 3.0, 4.0]), corr([5, 6], [6.0, 7.0])]
    after = [corr([3, 1, 9], [0.5, 0.5, 0.1]), corr([6], [1.0])]  # keeps 1, 3 and 6 of before's
    assert _common_medians(before, after) == [4.0, 0.5]  # medians of (2, 4, 7) and (0.5, 0.5, 1)


def test_a_pass_is_checked_on_the_points_both_matchings_keep():
    """A good pass whose matching after it keeps points the one before it had shed (and matches
    them badly) reads as worse over all points and is undone; over the points both keep it
    reads as better and stays (``check_on: common``)."""
    frames = [_frame(i) for i in range(3)]
    T_init = T_TRUE.copy()
    T_init[0, 3] += 0.05  # 5 cm sideways
    config = CalibrateConfig(
        passes=1, sampling={"per_frame": 500}, halvings=0, check_below_px=100.0, halve_above=(0.0, 0.0)
    )
    over_all = refine_passes(frames, T_init, ShedsFar(), UniformSupport(), config, np.random.default_rng(0))
    assert not over_all.passes[0]["accepted"] and np.allclose(over_all.T_cam_lidar, T_init)
    assert over_all.passes[0]["alignment_after_px"] > over_all.passes[0]["alignment_px"]
    common = config.model_copy(update={"check_on": "common"})
    kept = refine_passes(frames, T_init, ShedsFar(), UniformSupport(), common, np.random.default_rng(0))
    before_px, after_px = kept.passes[0]["common_px"]
    assert kept.passes[0]["accepted"] and after_px < 0.01 < 1.0 < before_px
    assert calibration_error(kept.T_cam_lidar, T_TRUE).translation_cm < 0.01


def test_points_near_the_lidar_are_not_used():
    frame = _frame(0)
    frame.points[:200, :3] = frame.points[:200, :3] / np.linalg.norm(
        frame.points[:200, :3], axis=1, keepdims=True
    )
    config = CalibrateConfig(passes=1, sampling={"per_frame": 10000}, check_passes=False)
    T_lie = perturb(T_TRUE, 30.0, 3.0, torch.Generator().manual_seed(1))
    result = refine_passes(
        [frame], T_TRUE, ScriptedMatcher(T_lie), UniformSupport(), config, np.random.default_rng(0)
    )
    assert result.passes[0]["correspondences"] + result.passes[0]["trimmed"] == 3000 - 200


class BlindAt(ScriptedMatcher):
    """Perfect matches toward ``T_TRUE``, except none at all under ``T_blind``."""

    def __init__(self, T_blind: np.ndarray) -> None:
        super().__init__(T_TRUE)
        self.T_blind = T_blind

    def match(self, frame: Frame, T_cam_lidar: np.ndarray) -> Correspondences:
        if np.allclose(T_cam_lidar, self.T_blind):
            empty = np.zeros((0, 2))
            return Correspondences(
                np.zeros(0, int), np.zeros((0, 3)), empty, empty, np.zeros(0, np.float32), (240, 640)
            )
        return super().match(frame, T_cam_lidar)


@pytest.mark.parametrize("blind_start", [1, 0])
def test_a_start_where_the_matcher_finds_nothing_is_passed_over(blind_start):
    """Whichever start is blind (an alternative, or the initial extrinsic itself), the passes go on
    from the other; with no other start the refinement raises."""
    frames = [_frame(i) for i in range(3)]
    T_seeing = perturb(T_TRUE, 5.0, 1.0, torch.Generator().manual_seed(2))
    T_blind = perturb(T_TRUE, 50.0, 10.0, torch.Generator().manual_seed(3))
    starts = [T_seeing, T_blind] if blind_start == 1 else [T_blind, T_seeing]
    config = CalibrateConfig(passes=2, sampling={"per_frame": 500})
    matcher, rng = BlindAt(T_blind), np.random.default_rng(0)
    result = refine_passes(frames, starts[0], matcher, UniformSupport(), config, rng, alternatives=starts[1:])
    assert result.start == 1 - blind_start and result.probe_alignments_px[blind_start] is None
    assert result.probe_alignments_px[1 - blind_start] < 0.1
    assert calibration_error(result.T_cam_lidar, T_TRUE).rotation_deg < 0.01
    with pytest.raises(NumericalError, match="correspondences"):
        refine_passes(frames, T_blind, matcher, UniformSupport(), config, rng)


class FewAt(ScriptedMatcher):
    """Under ``T_few`` (and wherever a pass from it lands) only 20 points match, all perfectly
    toward ``T_few``; elsewhere every point matches toward ``T_TRUE`` with 1 px of noise."""

    def __init__(self, T_few: np.ndarray) -> None:
        super().__init__(T_TRUE)
        self.T_few = T_few

    def match(self, frame: Frame, T_cam_lidar: np.ndarray) -> Correspondences:
        points = frame.points[:, :3].astype(np.float64)
        uv = _project(points, T_cam_lidar)
        if calibration_error(T_cam_lidar, self.T_few).rotation_deg < 0.5:
            keep = np.arange(20)
            target = _project(points, self.T_few)
        else:
            keep = np.arange(len(points))
            noise = np.random.default_rng(int(frame.name[1:])).normal(0, 1.0, (len(points), 2))
            target = _project(points, T_TRUE) + noise
        return Correspondences(
            keep, points[keep], uv[keep], target[keep], np.ones(len(keep), np.float32), (240, 640)
        )


PROBE = {"passes": 1, "sampling": {"per_frame": 500}, "check_passes": False}


def test_a_start_matched_by_few_points_is_not_kept_for_its_low_residual():
    frames = [_frame(i) for i in range(3)]
    T_init = perturb(T_TRUE, 5.0, 1.0, torch.Generator().manual_seed(2))
    T_few = perturb(T_TRUE, 50.0, 10.0, torch.Generator().manual_seed(3))
    lured = refine_passes(
        frames,
        T_init,
        FewAt(T_few),
        UniformSupport(),
        CalibrateConfig(**PROBE, coarse_min_share=0.0),
        np.random.default_rng(0),
        [T_few],
    )
    assert lured.start == 1  # 20 perfect matches beat 3000 noisy ones on the median alone
    result = refine_passes(  # the packaged share, 0.5
        frames,
        T_init,
        FewAt(T_few),
        UniformSupport(),
        CalibrateConfig(**PROBE),
        np.random.default_rng(0),
        [T_few],
    )
    assert result.start == 0
    assert calibration_error(result.T_cam_lidar, T_TRUE).rotation_deg < 0.05


def test_an_initial_extrinsic_matched_by_few_points_gives_way_to_a_start_matched_by_many():
    """The initial extrinsic is a prior, but not when its pass leaves the matcher a few lucky
    points: a coarse answer matched by 150x as many, at 1 px of noise, is taken instead (under
    the margin rule alone the initial's near-zero median would keep it)."""
    frames = [_frame(i) for i in range(3)]
    T_few = perturb(T_TRUE, 50.0, 10.0, torch.Generator().manual_seed(3))
    T_coarse = perturb(T_TRUE, 5.0, 1.0, torch.Generator().manual_seed(2))
    config = CalibrateConfig(**PROBE)
    result = refine_passes(
        frames, T_few, FewAt(T_few), UniformSupport(), config, np.random.default_rng(0), [T_coarse]
    )
    assert result.start == 1
    assert result.probe_correspondences == [60, 9000]  # 20 lucky points in each of 3 frames
    assert calibration_error(result.T_cam_lidar, T_TRUE).rotation_deg < 0.05
    kept = refine_passes(  # with no share asked of the initial, its 20 perfect matches win
        frames,
        T_few,
        FewAt(T_few),
        UniformSupport(),
        config.model_copy(update={"coarse_min_share": 0.0}),
        np.random.default_rng(0),
        [T_coarse],
    )
    assert kept.start == 0


class FewerFarOff(ScriptedMatcher):
    """Within 1° of ``T_TRUE`` every point matches toward it with ``near_px`` of noise; farther off
    only 60 % of them match, toward ``T_far``, with 1.2 px (an alias: fewer edges line up)."""

    def __init__(self, T_far: np.ndarray, near_px: float) -> None:
        super().__init__(T_far)
        self.near_px = near_px

    def match(self, frame: Frame, T_cam_lidar: np.ndarray) -> Correspondences:
        points = frame.points[:, :3].astype(np.float64)
        near = calibration_error(T_cam_lidar, T_TRUE).rotation_deg < 1.0
        keep = np.arange(len(points) if near else 3 * len(points) // 5)
        rng = np.random.default_rng(int(frame.name[1:]))
        noise = rng.normal(0, self.near_px if near else 1.2, (len(points), 2))[keep]
        target = _project(points[keep], T_TRUE if near else self.T_lie) + noise
        return Correspondences(
            keep,
            points[keep],
            _project(points[keep], T_cam_lidar),
            target,
            np.ones(len(keep), np.float32),
            (240, 640),
        )


def test_a_start_matched_by_many_more_points_at_a_lower_median_is_taken_with_coarse_gain():
    """``coarse_gain``: the initial extrinsic, far off, ends its first pass at 1.2 px of noise
    matched by 1800 points a frame; a coarse answer near the truth at 0.8 px matched by 3000, not
    clearly enough for ``coarse_margin`` (0.67x the median; nor ruled out by ``coarse_min_share``)
    but 1.67x the points: taken from a gain of 0.5, not at 0.8 nor without the rule, nor where its
    median is the higher (1.5 px of noise)."""
    frames = [_frame(i) for i in range(3)]
    T_far = perturb(T_TRUE, 30.0, 5.0, torch.Generator().manual_seed(5))
    T_init = perturb(T_far, 2.0, 0.5, torch.Generator().manual_seed(6))
    T_coarse = perturb(T_TRUE, 2.0, 0.3, torch.Generator().manual_seed(7))

    def probe(gain: float | None, near_px: float = 0.8):
        config = CalibrateConfig(**PROBE, coarse_gain=gain)
        matcher = FewerFarOff(T_far, near_px)
        return refine_passes(
            frames, T_init, matcher, UniformSupport(), config, np.random.default_rng(0), [T_coarse]
        )

    kept = probe(None)
    assert kept.probe_correspondences == [5400, 9000]
    assert 0.5 < kept.probe_alignments_px[1] / kept.probe_alignments_px[0] < 1.0  # not clearly better
    assert kept.start == 0 and calibration_error(kept.T_cam_lidar, T_far).rotation_deg < 0.1
    assert probe(0.8).start == 0
    taken = probe(0.5)
    assert taken.start == 1 and calibration_error(taken.T_cam_lidar, T_TRUE).rotation_deg < 0.1
    assert probe(0.5, near_px=1.5).start == 0  # more points, but the higher median


class NoisyRounds:
    """Each round of matchings (one call per frame; frames match on threads) points every frame
    toward its own ``T_k``, ``T_TRUE`` moved 1 cm in a random direction: the noise a real matching carries,
    whole, from round to round."""

    name = "noisy rounds"

    def __init__(self, frames: int, seed: int) -> None:
        self.frames, self.calls, self.rounds = frames, 0, []
        self.generator, self.lock = torch.Generator().manual_seed(seed), threading.Lock()

    def match(self, frame: Frame, T_cam_lidar: np.ndarray) -> Correspondences:
        with self.lock:
            if self.calls % self.frames == 0:
                self.rounds.append(perturb(T_TRUE, 1.0, 0.0, self.generator))
            self.calls, T_k = self.calls + 1, self.rounds[-1]
        points = frame.points[:, :3].astype(np.float64)
        return Correspondences(
            np.arange(len(points)),
            points,
            _project(points, T_cam_lidar),
            _project(points, T_k),
            np.ones(len(points), np.float32),
            (240, 640),
        )


def test_the_pooled_fit_averages_the_noise_of_the_last_matchings():
    """A pass's answer is its one matching's ``T_k``; the fit pooling the last three matchings lands
    on the mean of their ``T_k`` (within 0.1 cm), closer to the truth: over eight seeds the median
    error falls by about √3 (asserted to 0.75x), for the one matching after the last pass."""
    frames = [_frame(i) for i in range(3)]
    T_init = perturb(T_TRUE, 5.0, 0.5, torch.Generator().manual_seed(7))  # beyond pool_within
    config = CalibrateConfig(passes=4, check_passes=False, sampling={"per_frame": 500})
    pooled_config = config.model_copy(update={"pool_matchings": 3})
    single, pooled = [], []
    for seed in range(8):
        plain, matcher = NoisyRounds(3, seed), NoisyRounds(3, seed)
        last = refine_passes(frames, T_init, plain, UniformSupport(), config, np.random.default_rng(0))
        mean = refine_passes(
            frames, T_init, matcher, UniformSupport(), pooled_config, np.random.default_rng(0)
        )
        assert len(mean.passes) == len(last.passes) + 1 and mean.passes[-1]["pooled_matchings"] == 3
        # one matching more: the one after the last pass, which the pooled fit reads and a plain
        # run without checks no longer makes
        assert matcher.calls == plain.calls + len(frames)
        single.append(calibration_error(last.T_cam_lidar, T_TRUE).translation_cm)
        pooled.append(calibration_error(mean.T_cam_lidar, T_TRUE).translation_cm)
        mean_translation = np.mean([T_k[:3, 3] for T_k in matcher.rounds[-3:]], axis=0)
        assert np.linalg.norm(mean.T_cam_lidar[:3, 3] - mean_translation) < 1e-3
    assert np.median(pooled) < 0.75 * np.median(single)
    # matchings farther than pool_within are not pooled: with a tiny one the answer is the last pass's
    tight = pooled_config.model_copy(update={"pool_within": (0.001, 0.0001)})
    alone = refine_passes(
        frames, T_init, NoisyRounds(3, 0), UniformSupport(), tight, np.random.default_rng(0)
    )
    first = refine_passes(
        frames, T_init, NoisyRounds(3, 0), UniformSupport(), config, np.random.default_rng(0)
    )
    np.testing.assert_allclose(alone.T_cam_lidar, first.T_cam_lidar)
