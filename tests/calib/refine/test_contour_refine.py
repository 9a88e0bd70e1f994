"""``calib.refine.contour_refine`` and ``calib.refine.global_search``: on a synthetic world at
KITTI's pixel scale the score that only rises, the bounds, staying at the truth; known answers on
the six real KITTI raw frames (10° brought under 4° by the global search, 2° / 10 cm under 0.4° by
the contour refinement). Neither undoes a 2° error on this synthetic urban world: its scans give
few contours (about 170 / 80 / 10 samples per frame) and the contour score there is higher 7° away
than at the truth (0.32 against 0.25 at σ = 1°), so the known answers are on real frames."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from calib.data import Frame, open_dataset
from calib.data.real_fixtures import AMZ_DRIVE, AMZ_DRIVE_MORE
from calib.geometry import calibration_error, perturb
from calib.match.edge_alignment import EdgeAlignment
from calib.pipeline import Calibrator
from calib.refine.contour_refine import ContourRefineConfig, contour_refine
from calib.refine.global_search import GlobalSearchConfig, _Climb, _climb, global_search
from calib.refine.passes import CalibrateConfig
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config

KITTI_SCALE = {"width": 1242, "height": 375, "fx": 721.5, "fy": 721.5, "cx": 609.6, "cy": 172.9}
STILL_AIR = {"wind": {"amplitude_m": 0.0}, "timing": {"camera_offset_s": 0.0}}
STILL = {**STILL_AIR, "camera": KITTI_SCALE}


@pytest.fixture(scope="module")
def urban() -> list[Frame]:
    synth = Synthesizer(load_synth_config("urban", small=True, **STILL), 3, seed=11)
    return [synth.render(i).frame for i in range(3)]


def test_contour_refine_only_raises_the_score(urban):
    T_ref = urban[0].calibration.T_cam_lidar
    T_init = perturb(T_ref, 5.0, 2.0, torch.Generator().manual_seed(1))
    result = contour_refine(urban, T_init, ContourRefineConfig())
    assert len(result.levels) == len(ContourRefineConfig().sigmas_deg)
    assert all(level["score_after"] >= level["score_before"] for level in result.levels)
    assert result.T_cam_lidar.shape == (4, 4)


def test_contour_refine_keeps_each_level_within_its_bounds(urban):
    T_ref = urban[0].calibration.T_cam_lidar
    T_init = perturb(T_ref, 5.0, 2.0, torch.Generator().manual_seed(3))
    config = ContourRefineConfig(sigmas_deg=(1.0,), max_rotation_deg=0.2, max_translation_m=0.01)
    moved = calibration_error(contour_refine(urban, T_init, config).T_cam_lidar, T_init)
    # box bounds per axis: at most √3 times the bound in length
    assert moved.rotation_deg <= 0.2 * np.sqrt(3) + 1e-6 and moved.translation_cm <= 1.0 * np.sqrt(3) + 1e-4


def test_at_the_truth_it_stays(urban):
    T_ref = urban[0].calibration.T_cam_lidar
    error = calibration_error(contour_refine(urban, T_ref).T_cam_lidar, T_ref)
    assert error.rotation_deg < 0.15 and error.translation_cm < 5.0


def test_global_search_only_raises_the_score(urban):
    T_ref = urban[0].calibration.T_cam_lidar
    T_init = perturb(T_ref, 10.0, 5.0, torch.Generator().manual_seed(2))
    result = global_search(urban, T_init, GlobalSearchConfig(enabled=True))
    assert all(level["score_after"] >= level["score_before"] for level in result.levels)
    assert [level["sigma_px"] for level in result.levels] == pytest.approx(
        [s * 721.5 / 721.0 for s in GlobalSearchConfig().sigmas_px]
    )


@pytest.fixture(scope="module")
def vineyard() -> list[Frame]:
    """Four frames of the synthetic vineyard at its real scale (960x540, f = 527), still air and
    no time offset: contours 1-4 m away, a fifth of the urban world's depth."""
    synth = Synthesizer(load_synth_config("vineyard", **STILL_AIR), 4, seed=5)
    return [synth.render(i).frame for i in range(4)]


def test_translation_steps_from_the_contours_depth_reach_the_vineyards_truth(vineyard):
    """Known answer: from 10 cm / 2° off, steps sized at the contours' median depth (2 m) climb to
    within 2 cm / 0.4° of the truth; sized at urban's 10 m a translation step moves the vineyard's
    contours five times as far as a rotation step, and the climb stops farther from it."""
    T_ref = vineyard[0].calibration.T_cam_lidar
    T_init = perturb(T_ref, 10.0, 2.0, torch.Generator().manual_seed(4))
    score = EdgeAlignment(vineyard)
    assert 1.0 < score.median_depth(torch.as_tensor(T_ref)) < 3.5
    errors = {
        depth: calibration_error(
            global_search(vineyard, T_init, GlobalSearchConfig(depth_m=depth)).T_cam_lidar, T_ref
        )
        for depth in (None, 10.0)
    }
    assert errors[None].translation_cm < 2.0 and errors[None].rotation_deg < 0.4
    assert errors[10.0].translation_cm > 2 * errors[None].translation_cm


def test_climbs_scored_together_end_where_each_alone_ends(urban):
    """The pattern search scores the moves of all its climbs in one call; each climb must still
    end exactly where it ends alone (its own steps, depth, origin, halvings and stop)."""
    T_ref = torch.as_tensor(urban[0].calibration.T_cam_lidar)
    config = GlobalSearchConfig(max_iterations=6, max_translation_m=0.1)
    score = EdgeAlignment(urban, config.contour_points, view=(T_ref.numpy(), config.view_margin_deg))
    starts = [
        torch.as_tensor(perturb(T_ref.numpy(), 8.0, 1.5, torch.Generator().manual_seed(s))) for s in (5, 6, 7)
    ]
    sigma, rotation = 4.0, 4.0 / 721.5

    def begun() -> list[_Climb]:  # the third climb from its own start, at half the depth
        origins, depths = (T_ref, T_ref, starts[2]), (10.0, 10.0, 5.0)
        return [
            _Climb(T, float(score(T, sigma)[0]), origin, depth)
            for T, origin, depth in zip(starts, origins, depths, strict=True)
        ]

    together = begun()
    _climb(score, sigma, together, rotation, config)
    alone = []
    for climb in begun():
        _climb(score, sigma, [climb], rotation, config)
        alone.append(climb)
    for a, b, first in zip(together, alone, begun(), strict=True):
        assert torch.allclose(a.T, b.T, atol=1e-12) and a.best == pytest.approx(b.best, abs=1e-12)
        assert a.best >= first.best  # a move is taken only when the score rises
        assert float((torch.linalg.inv(a.origin) @ a.T)[:3, 3].norm()) <= config.max_translation_m
    assert any(not torch.equal(a.T, first.T) for a, first in zip(together, begun(), strict=True))


def test_a_search_from_two_starts_is_at_least_as_good_as_from_either(urban):
    """Known answer: searched from the truth and a start 8 cm / 1.5° away together (the contour
    points drawn in the truth's view, as its search alone draws them), the answer scores at least
    as well at the finest scale as the truth's search alone, and stays at the truth."""
    T_ref = urban[0].calibration.T_cam_lidar
    T_far = perturb(T_ref, 8.0, 1.5, torch.Generator().manual_seed(5))
    config = GlobalSearchConfig(max_iterations=6, grid=3)
    both = global_search(urban, np.stack([T_ref, T_far]), config).T_cam_lidar
    alone = global_search(urban, T_ref, config).T_cam_lidar
    view = (T_ref, config.view_margin_deg)
    score = EdgeAlignment(urban, config.contour_points, view=view, surround=config.surround)
    sigma = config.sigmas_px[-1] * float(urban[0].K[0, 0]) / 721.0
    assert (
        float(score(torch.as_tensor(both), sigma)[0]) >= float(score(torch.as_tensor(alone), sigma)[0]) - 1e-6
    )
    error = calibration_error(both, T_ref)
    assert error.translation_cm < 1.0 and error.rotation_deg < 0.1


def test_starts_given_later_join_the_search_as_if_given_at_once(urban):
    """``later``: starts handed over once the first start's grid is scored end the search exactly
    where the two given together end."""
    T_ref = urban[0].calibration.T_cam_lidar
    T_a, T_b = (perturb(T_ref, 8.0, 1.5, torch.Generator().manual_seed(s)) for s in (5, 6))
    config = GlobalSearchConfig(max_iterations=4, grid=3)
    together = global_search(urban, np.stack([T_a, T_b]), config)
    asked = []
    later = global_search(urban, T_a, config, later=lambda: asked.append(1) or T_b)
    assert asked == [1]
    assert np.allclose(later.T_cam_lidar, together.T_cam_lidar, atol=1e-12)
    assert later.levels == together.levels


def test_the_calibrator_records_both_coarse_stages(urban):
    T_ref = urban[0].calibration.T_cam_lidar
    T_init = perturb(T_ref, 5.0, 2.0, torch.Generator().manual_seed(4))
    config = CalibrateConfig(
        frames=3,
        passes=1,
        coarse={"enabled": False},
        contour={"enabled": True, "sigmas_deg": (1.0, 0.5)},
        pyramid_focals_px=(),  # the starts are chosen at the finest level (the pyramid: test_pipeline)
    )
    result = Calibrator(config=config).calibrate(urban, T_init)
    assert [level["stage"] for level in result.coarse] == ["contour", "contour", "choice"]
    assert all(level["score_after"] >= level["score_before"] for level in result.coarse[:2])
    choice = result.coarse[2]  # the passes went on from the better-aligned of the two starts
    after, counts = choice["alignment_after_first_pass_px"], choice["correspondences_after_first_pass"]
    # of those that kept coarse_min_share of the most correspondences any start kept
    least = config.coarse_min_share * max(counts.values())
    eligible = {origin: px for origin, px in after.items() if counts[origin] >= least}
    others = {origin: px for origin, px in eligible.items() if origin != "initial"}
    best = min(others, key=others.get, default=None)
    # another start than the initial is taken only where it ends clearly better aligned
    taken = best is not None and (
        "initial" not in eligible or others[best] <= config.coarse_margin * eligible["initial"]
    )
    assert choice["kept"] == (best if taken else "initial")
    assert len(result.passes) == 1


def test_the_calibrator_searches_with_each_edge_map(urban):
    T_ref = urban[0].calibration.T_cam_lidar
    T_init = perturb(T_ref, 5.0, 2.0, torch.Generator().manual_seed(4))
    config = CalibrateConfig(frames=3, passes=1, coarse={"sigmas_px": (16.0, 8.0)}, pyramid_focals_px=())
    result = Calibrator(config=config).calibrate(urban, T_init)
    stages = [(level["stage"], level.get("score")) for level in result.coarse]
    assert stages == [("global", "magnitude")] * 2 + [("global", "orientation")] * 2 + [("choice", None)]
    after = result.coarse[-1]["alignment_after_first_pass_px"]
    assert list(after) == ["initial", "global (magnitude)", "global (orientation)"]
    assert result.coarse[-1]["kept"] in after


def test_with_the_pyramid_the_start_is_still_chosen_at_the_finest_level(urban):
    """At 90 px a wrong start can end its first pass as well aligned as the right one (KITTI from
    10°), so the starts are probed at the finest level before the pyramid: the choice, its
    alignments included, is the one made without the pyramid."""
    T_init = perturb(urban[0].calibration.T_cam_lidar, 5.0, 2.0, torch.Generator().manual_seed(4))
    choices = {}
    for pyramid in ((), (90.0, 180.0)):
        coarse = {"sigmas_px": (16.0, 8.0)}
        config = CalibrateConfig(frames=3, passes=1, coarse=coarse, pyramid_focals_px=pyramid)
        result = Calibrator(config=config).calibrate(urban, T_init)
        stages = [level["stage"] for level in result.coarse]
        assert stages == ["global"] * 4 + ["pyramid"] * len(pyramid) + ["choice"]
        choices[pyramid] = result.coarse[-1]
    assert choices[(90.0, 180.0)] == choices[()]


@pytest.fixture(scope="module")
def kitti_raw(realdata) -> tuple[list[Frame], np.ndarray]:
    """The six real KITTI raw 2011_09_28 frames (grey camera 0) and their reference."""
    frames = []
    for folder in (AMZ_DRIVE, AMZ_DRIVE_MORE):
        with open_dataset(realdata / folder, camera="0") as seq:
            frames += list(seq)
            T_ref = seq.calibration.T_cam_lidar
    return frames, T_ref


@pytest.mark.realdata
def test_real_kitti_raw_global_search_brings_ten_degrees_under_four(kitti_raw):
    frames, T_ref = kitti_raw
    T_init = perturb(T_ref, 50.0, 10.0, torch.Generator().manual_seed(7))
    result = global_search(frames, T_init, GlobalSearchConfig(enabled=True))
    assert calibration_error(result.T_cam_lidar, T_ref).rotation_deg < 4.0  # measured 0.95-3.1° (5 draws)


@pytest.mark.realdata
def test_real_kitti_raw_two_degrees_ten_cm_comes_under_half_a_degree(kitti_raw):
    frames, T_ref = kitti_raw
    generator = torch.Generator().manual_seed(7)
    for _ in range(2):
        T_init = perturb(T_ref, 10.0, 2.0, generator)
        error = calibration_error(contour_refine(frames, T_init).T_cam_lidar, T_ref)
        # measured: 8.0 cm / 0.26° from every start (the score's optimum on these six frames)
        assert error.rotation_deg < 0.4 and error.translation_cm < 12.0
