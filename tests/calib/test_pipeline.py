"""The library's four stages end to end: Calibrator and OnlineCalibrator on a synthetic world
whose true extrinsic is known."""

import json
import threading
from dataclasses import replace

import numpy as np
import pytest
import torch

from calib.errors import ConfigError, DataError
from calib.geometry import calibration_error, perturb, se3_exp
from calib.init.lidar_odometry import SequenceMotions
from calib.match.correspondences import match_frames
from calib.match.edge_matcher import EdgeMatcher
from calib.pipeline import Calibrator, OnlineCalibrator, select_frames
from calib.refine.passes import CalibrateConfig
from calib.results import SCHEMA_VERSION, CalibrationResult, OnlineEstimate
from calib.support.source import MapSupport, SupportSource, UniformSupport
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config

STILL = {"wind": {"amplitude_m": 0.0}, "timing": {"camera_offset_s": 0.0}}
FAST = CalibrateConfig(frames=3, passes=2, sampling={"per_frame": 1500}, online={"window": 3, "step": 2})


@pytest.fixture(scope="module")
def frames():
    synth = Synthesizer(load_synth_config("vineyard", small=True, **STILL), 7, seed=5)
    return [synth.render(i).frame for i in range(7)]


@pytest.fixture
def matched_configs(monkeypatch) -> list:
    """The EdgeMatcher configs of every match, in order (``EdgeMatcher.match`` recorded)."""
    configs = []
    match = EdgeMatcher.match

    def recording(self, frame, T_cam_lidar):
        configs.append(self.config)
        return match(self, frame, T_cam_lidar)

    monkeypatch.setattr(EdgeMatcher, "match", recording)
    return configs


def test_select_frames_spreads_evenly():
    assert select_frames(10, 3).tolist() == [0, 4, 9] or select_frames(10, 3).tolist() == [0, 5, 9]
    assert select_frames(2, 10).tolist() == [0, 1]
    with pytest.raises(DataError, match="no frames"):
        select_frames(0, 3)


def test_calibrator_undoes_a_known_perturbation(frames):
    T_ref = frames[0].calibration.T_cam_lidar
    T_init = perturb(T_ref, 10.0, 2.0, torch.Generator().manual_seed(0))
    result = Calibrator(config=FAST).calibrate(frames, T_init)
    assert isinstance(result, CalibrationResult)
    assert result.initial_error.translation_cm == pytest.approx(10.0)
    assert result.error.translation_cm < 2.5 and result.error.rotation_deg < 0.4
    assert result.covariance.shape == (6, 6) and result.support == "uniform"
    assert len(result.frame_indices) == 3 and result.correspondences > 100
    stored = json.loads(json.dumps(result.to_dict(), allow_nan=False))  # strict JSON
    assert stored["schema_version"] == SCHEMA_VERSION
    assert stored["error"]["translation_cm"] == pytest.approx(result.error.translation_cm)


def test_calibration_reports_the_cluster_robust_covariance_and_the_same_estimate(frames):
    """Image cells change what the result says of its uncertainty, never the estimate: errors
    shared within a cell make the sandwich wider than the independent-residual covariance."""
    T_ref = frames[0].calibration.T_cam_lidar
    T_init = perturb(T_ref, 5.0, 1.0, torch.Generator().manual_seed(1))
    independent, cells = (
        Calibrator(
            config=FAST.model_copy(
                update={"refine": FAST.refine.model_copy(update={"covariance_cell_deg": d})}
            )
        ).calibrate(frames, T_init)
        for d in (0.0, 10.0)
    )
    np.testing.assert_allclose(cells.T_cam_lidar, independent.T_cam_lidar, atol=1e-12)
    assert all(c > i for c, i in zip(cells.std, independent.std, strict=True))


def test_matcher_pyramid_reaches_where_the_finest_level_cannot(frames):
    """From 10 cm / 4° (25 px at the small camera, twice the EdgeMatcher's reach) the dense passes
    alone stay off; run first at working focal lengths of 90 and 180 px they converge. A level at
    or above the matcher's own working focal length (360 px) is skipped."""
    T_ref = frames[0].calibration.T_cam_lidar
    T_init = perturb(T_ref, 10.0, 4.0, torch.Generator().manual_seed(0))
    errors, levels = {}, {}
    for pyramid in ((), (90.0, 180.0, 1000.0)):
        config = FAST.model_copy(
            update={
                "pyramid_focals_px": pyramid,
                "coarse": FAST.coarse.model_copy(update={"enabled": False}),
                "time_offset": FAST.time_offset.model_copy(update={"mode": "off"}),
            }
        )
        result = Calibrator(config=config).calibrate(frames, T_init)
        errors[pyramid], levels[pyramid] = result.error, [c for c in result.coarse if c["stage"] == "pyramid"]
    assert errors[()].rotation_deg > 1.0  # outside the finest level's reach
    with_pyramid = errors[(90.0, 180.0, 1000.0)]
    assert with_pyramid.translation_cm < 1.5 and with_pyramid.rotation_deg < 0.15
    assert [c["working_focal_px"] for c in levels[(90.0, 180.0, 1000.0)]] == [90.0, 180.0]
    assert all(c["passes"] >= 1 for c in levels[(90.0, 180.0, 1000.0)]) and levels[()] == []


def test_fine_intensity_weight_holds_from_fine_from_px_and_at_the_finest_level(frames, matched_configs):
    """``fine_intensity_weight`` replaces ``edge.intensity_weight`` at the finest level and at the
    pyramid levels from ``fine_from_px`` on; the probe and the coarser levels keep the edge's."""
    T_init = perturb(frames[0].calibration.T_cam_lidar, 5.0, 1.0, torch.Generator().manual_seed(5))
    config = FAST.model_copy(
        update={
            "passes": 1,
            "pyramid_focals_px": (90.0, 180.0),
            "probe_focal_px": 180.0,
            "fine_intensity_weight": 0.25,
            "fine_from_px": 180.0,
            "time_offset": FAST.time_offset.model_copy(update={"mode": "off"}),
        }
    )
    Calibrator(config=config).calibrate(frames, T_init)
    weights = {}
    for c in matched_configs:
        weights.setdefault(c.working_focal_px, set()).add(c.intensity_weight)
    assert weights == {90.0: {0.5}, 180.0: {0.5, 0.25}, 360.0: {0.25}}  # 180: the probe, then the level


def test_the_finest_passes_run_at_finest_focal_px_and_levels_near_it_are_skipped(frames, matched_configs):
    """``finest_focal_px`` moves the finest passes (not ``edge``, the other commands' matcher); a
    pyramid level or probe within 10 % of the finest level (here the camera's 360.8 px) runs at
    the finest level instead of repeating it."""
    T_init = perturb(frames[0].calibration.T_cam_lidar, 5.0, 1.0, torch.Generator().manual_seed(6))
    config = FAST.model_copy(
        update={
            "passes": 1,
            "finest_focal_px": 1000.0,
            "pyramid_focals_px": (90.0, 180.0, 340.0),
            "probe_focal_px": 340.0,
            "time_offset": FAST.time_offset.model_copy(update={"mode": "off"}),
        }
    )
    calibrator = Calibrator(config=config)
    result = calibrator.calibrate(frames, T_init)
    assert [c["working_focal_px"] for c in result.coarse if c["stage"] == "pyramid"] == [90.0, 180.0]
    focals = [c.working_focal_px for c in matched_configs]
    assert focals[0] == 1000.0 and focals[-1] == 1000.0 and 340.0 not in focals  # probe, finest
    assert calibrator.matcher.config.working_focal_px == 360.0
    # each level's matcher is made once, so its image views serve the next calibration too
    assert calibrator._level(fine=True)[0] is calibrator._level(fine=True)[0]


def test_pyramid_levels_at_or_above_the_cameras_focal_length_are_skipped(frames):
    """A working focal length above the camera's (360.8 px) leaves the image as it is, so a
    pyramid level between the two would be the finest level again."""
    T_init = perturb(frames[0].calibration.T_cam_lidar, 5.0, 1.0, torch.Generator().manual_seed(4))
    config = FAST.model_copy(
        update={
            "passes": 1,
            "edge": FAST.edge.model_copy(update={"working_focal_px": 1000.0}),
            "pyramid_focals_px": (90.0, 500.0),
            "coarse": FAST.coarse.model_copy(update={"enabled": False}),
            "time_offset": FAST.time_offset.model_copy(update={"mode": "off"}),
        }
    )
    result = Calibrator(config=config).calibrate(frames, T_init)
    assert [c["working_focal_px"] for c in result.coarse if c["stage"] == "pyramid"] == [90.0]


def test_one_frame_skips_the_pyramid_unless_allowed(frames):
    """The pyramid needs ``pyramid_min_frames`` frames: on one frame its coarse levels wander; only
    those from ``few_frames_from_px`` on still run there."""
    T_init = perturb(frames[0].calibration.T_cam_lidar, 5.0, 1.0, torch.Generator().manual_seed(1))
    stages = {}
    for least, few_from in ((2, None), (1, None), (2, 180.0)):
        config = FAST.model_copy(
            update={
                "frames": 1,
                "pyramid_focals_px": (90.0, 180.0),
                "pyramid_min_frames": least,
                "few_frames_from_px": few_from,
                "coarse": FAST.coarse.model_copy(update={"enabled": False}),
                "time_offset": FAST.time_offset.model_copy(update={"mode": "off"}),
            }
        )
        result = Calibrator(config=config).calibrate(frames[:1], T_init)
        stages[least, few_from] = [c["working_focal_px"] for c in result.coarse if c["stage"] == "pyramid"]
    assert stages == {(2, None): [], (1, None): [90.0, 180.0], (2, 180.0): [180.0]}


def test_the_probe_of_the_starts_runs_at_probe_focal_px(frames, matched_configs):
    """The one pass that chooses among the starts matches at ``probe_focal_px`` (default: the
    finest working focal length), then the pyramid and the finest passes follow."""
    T_init = perturb(frames[0].calibration.T_cam_lidar, 5.0, 1.0, torch.Generator().manual_seed(3))
    first = {}
    for probe in (None, 180.0):
        matched_configs.clear()
        config = FAST.model_copy(
            update={
                "passes": 1,
                "pyramid_focals_px": (90.0,),
                "probe_focal_px": probe,
                "time_offset": FAST.time_offset.model_copy(update={"mode": "off"}),
            }
        )
        result = Calibrator(config=config).calibrate(frames, T_init)
        focals = [c.working_focal_px for c in matched_configs]
        first[probe] = focals[0]
        assert focals[-1] == 360.0 and 90.0 in focals  # the pyramid, then the finest passes
        assert next(c for c in result.coarse if c["stage"] == "choice")
    assert first == {None: 360.0, 180.0: 180.0}


def test_probe_frames_run_the_probe_on_a_subset(frames, monkeypatch):
    """``probe_frames`` gives the probe's pass that many of the frames, spread evenly (first and
    last); the pyramid and the finest passes go on from its choice on every frame."""
    seen = []
    match = EdgeMatcher.match

    def recording(self, frame, T_cam_lidar):
        seen.append((self.config.working_focal_px, id(frame)))
        return match(self, frame, T_cam_lidar)

    monkeypatch.setattr(EdgeMatcher, "match", recording)
    config = FAST.model_copy(
        update={
            "passes": 1,
            "pyramid_focals_px": (90.0,),
            "probe_focal_px": 180.0,
            "probe_frames": 2,
            "time_offset": FAST.time_offset.model_copy(update={"mode": "off"}),
        }
    )
    T_init = perturb(frames[0].calibration.T_cam_lidar, 5.0, 1.0, torch.Generator().manual_seed(3))
    result = Calibrator(config=config).calibrate(frames, T_init)
    picked = [id(frames[i]) for i in result.frame_indices]
    assert len(picked) == 3
    by_focal = {}
    for focal, frame in seen:
        by_focal.setdefault(focal, set()).add(frame)
    assert by_focal[180.0] == {picked[0], picked[-1]}  # the probe
    assert by_focal[90.0] == by_focal[360.0] == set(picked)  # the pyramid, the finest passes
    assert next(c for c in result.coarse if c["stage"] == "choice")


def test_a_pyramid_level_whose_answer_loses_matches_is_undone(frames, monkeypatch):
    """With ``level_min_share`` a pyramid level whose answer the matcher keeps fewer matches under
    than that share of those under its start is undone, and the next level goes on from its start:
    a 90 px level made to end 3° / 30 cm off (the vineyard's aliased rows), the matches under that
    answer counted by the level's own matcher, is undone and the calibration ends near the truth;
    without the rule it ends off. A level made to end at the truth gains matches and is kept. With
    ``matched_below_px`` the rule holds only at the levels working under it."""
    import calib.pipeline as pipeline
    from calib.refine.passes import _usable

    T_ref = frames[0].calibration.T_cam_lidar
    T_init = perturb(T_ref, 5.0, 1.0, torch.Generator().manual_seed(3))
    passes = pipeline.refine_passes

    def landing(T_end):
        def level(frames_, T, matcher, support, config, rng, alternatives=(), timing=None):
            result = passes(frames_, T, matcher, support, config, rng, alternatives, timing)
            if config.edge.working_focal_px == 90.0:  # the coarse level ends at T_end, matched there
                kept = sum(len(_usable(c, config.outliers)) for c in match_frames(matcher, frames_, T_end))
                last = {**result.passes[-1], "accepted": True, "matched_after": kept}
                result = replace(result, T_cam_lidar=T_end, passes=[*result.passes[:-1], last])
            return result

        return level

    def calibrated(share: float, below_px: float | None = None):
        config = FAST.model_copy(
            update={
                "pyramid_focals_px": (90.0,),
                "level_min_share": share,
                "matched_below_px": below_px,
                "time_offset": FAST.time_offset.model_copy(update={"mode": "off"}),
            }
        )
        result = Calibrator(config=config).calibrate(frames, T_init)
        return result, next(c for c in result.coarse if c["stage"] == "pyramid")

    monkeypatch.setattr(pipeline, "refine_passes", landing(T_ref))  # a level that finds the truth
    kept, level = calibrated(0.8)
    assert not level["undone"] and level["matched"][1] > level["matched"][0]
    assert kept.error.translation_cm < 1.5
    monkeypatch.setattr(pipeline, "refine_passes", landing(perturb(T_ref, 30.0, 3.0, torch.Generator())))
    (kept, level), (undone, judged) = calibrated(0.0), calibrated(0.8)
    assert kept.error.translation_cm > 10.0 and not level["undone"]  # the finest level cannot undo it
    assert judged["undone"] and judged["matched"][1] < 0.8 * judged["matched"][0]
    assert undone.error.translation_cm < 2.5 and undone.error.rotation_deg < 0.4
    # matched_below_px: the rule holds only at the levels working under it
    assert calibrated(0.8, below_px=180.0)[1]["undone"]
    assert not calibrated(0.8, below_px=90.0)[1]["undone"]


def test_passes_count_the_matches_under_the_start_and_the_answer(frames):
    """Each pass records how many matches the matching it started from kept and, where a matching
    checked it, the one after it (the next pass's start); ``matched`` reads the start's and the
    answer's, the answer being the last pass's start where that pass was undone."""
    from calib.refine.passes import PassesResult, refine_passes

    T_ref = frames[0].calibration.T_cam_lidar
    T_init = perturb(T_ref, 5.0, 1.0, torch.Generator().manual_seed(3))
    config = FAST.model_copy(update={"passes": 3, "settle_px": 0.0})
    result = refine_passes(
        frames[:3], T_init, EdgeMatcher(FAST.edge), UniformSupport(), config, np.random.default_rng(0)
    )
    steps = result.passes
    assert all(p["matched"] > 0 for p in steps)
    for before, after in zip(steps, steps[1:], strict=False):  # an accepted pass's matching starts the next
        assert before["accepted"] and before["matched_after"] == after["matched"]
    start, answer = result.matched
    assert start == steps[0]["matched"]
    assert answer == (steps[-1]["matched_after"] if steps[-1]["accepted"] else steps[-1]["matched"])
    eye = np.eye(4)
    made = [
        {"matched": 10, "accepted": True, "matched_after": 12},
        {"matched": 12, "accepted": False, "matched_after": 5},
    ]
    assert PassesResult(eye, np.eye(6), made, 1).matched == (10, 12)  # undone: its start's matching
    made[1] = {"matched": 12, "accepted": True, "settled": True}
    assert PassesResult(eye, np.eye(6), made, 1).matched == (10, 12)  # settled unchecked: its start's
    made[1] = {"matched": 12, "accepted": True, "matched_after": 20}
    assert PassesResult(eye, np.eye(6), made, 1).matched == (10, 20)
    assert PassesResult(eye, np.eye(6), [], 1).matched == (0, 0)  # no passes: nothing to undo


class _Recording:
    """A matcher that records the extrinsics it is asked about (the EdgeMatcher underneath)."""

    name = "recording"

    def __init__(self) -> None:
        self.inner, self.asked, self.frames = EdgeMatcher(FAST.edge), [], []

    def match(self, frame, T_cam_lidar):
        self.asked.append(np.array(T_cam_lidar))
        self.frames.append(frame)
        return self.inner.match(frame, T_cam_lidar)


def test_flow_coarse_passes_add_a_start_from_the_coarse_matcher(frames):
    """``flow_coarse_passes`` runs that many passes of the coarse matcher from the initial
    extrinsic; where they end is one more start, so the probe weighs four starts; without a coarse
    matcher the config is refused."""
    config = FAST.model_copy(update={"flow_coarse_passes": 1, "pyramid_focals_px": ()})
    with pytest.raises(ConfigError, match="flow_coarse_passes"):
        Calibrator(config=config)
    T_ref = frames[0].calibration.T_cam_lidar
    T_init = perturb(T_ref, 5.0, 1.0, torch.Generator().manual_seed(2))
    coarse = _Recording()
    result = Calibrator(config=config, coarse_matcher=coarse).calibrate(frames, T_init)
    assert np.allclose(coarse.asked[0], T_init)  # from the initial extrinsic
    flow = [c for c in result.coarse if c["stage"] == "flow"]
    assert len(flow) == 1 and flow[0]["passes"] == 1
    choice = next(c for c in result.coarse if c["stage"] == "choice")
    assert set(choice["alignment_after_first_pass_px"]) == {
        "initial",
        "global (magnitude)",
        "global (orientation)",
        "flow",
    }
    assert result.error.translation_cm < 2.5 and result.error.rotation_deg < 0.4
    # the seconds of each stage, in the order they ran, within the calibration's own (the global
    # search runs beside the coarse matcher's passes: they share nothing)
    stages = list(result.stage_seconds)
    assert stages == ["frames", "motion and moving points", "global and flow, side by side", "finest"]
    assert all(s >= 0 for s in result.stage_seconds.values())
    assert sum(result.stage_seconds.values()) <= result.runtime_s
    assert result.to_dict()["stage_seconds"] == result.stage_seconds


@pytest.mark.parametrize("start", ["initial", "flow", "both"])
def test_the_global_search_starts_where_coarse_start_says(frames, monkeypatch, start):
    """``coarse.start``: the global search climbs from the initial extrinsic, from the answer of
    the coarse matcher's passes (then run first), which stays a start of its own, or from both
    (the passes' answer joining the search begun beside them)."""
    import calib.pipeline

    searched_from, answers = [], []
    search, passes = calib.pipeline.global_search, calib.pipeline.refine_passes

    def recorded_search(frames_, T_start, config, kind, later=None):
        def recorded_later():  # the starts that join the search once the coarse passes end
            more = later()
            searched_from[index] = np.stack([T_start, more])
            return more

        index = len(searched_from)
        searched_from.append(np.array(T_start))
        return search(frames_, T_start, config, kind, later and recorded_later)

    def recorded_passes(*args, **kwargs):
        result = passes(*args, **kwargs)
        answers.append(result.T_cam_lidar)
        return result

    monkeypatch.setattr(calib.pipeline, "global_search", recorded_search)
    monkeypatch.setattr(calib.pipeline, "refine_passes", recorded_passes)
    config = FAST.model_copy(
        update={
            "flow_coarse_passes": 1,
            "pyramid_focals_px": (),
            "coarse": FAST.coarse.model_copy(update={"start": start}),
        }
    )
    T_init = perturb(frames[0].calibration.T_cam_lidar, 5.0, 1.0, torch.Generator().manual_seed(2))
    coarse = _Recording()
    result = Calibrator(config=config, coarse_matcher=coarse).calibrate(frames, T_init)
    assert np.allclose(coarse.asked[0], T_init)  # the coarse passes from the initial either way
    flow_answer = answers[0]  # the first passes run are the coarse matcher's
    assert calibration_error(flow_answer, T_init).translation_cm > 0.1  # they moved
    assert len(searched_from) == len(config.coarse.scores)
    expected = {"initial": T_init, "flow": flow_answer, "both": np.stack([T_init, flow_answer])}[start]
    assert all(T.shape == expected.shape and np.allclose(T, expected) for T in searched_from)
    assert "flow" in next(c for c in result.coarse if c["stage"] == "choice")["alignment_after_first_pass_px"]
    stage = "flow, then global" if start == "flow" else "global and flow, side by side"
    assert stage in result.stage_seconds


def test_a_failing_coarse_matcher_ends_the_searches_waiting_for_it(frames):
    """``coarse.start: both``: the searches begun beside the coarse passes wait for their answer;
    when the passes raise, the calibration raises that error instead of waiting for ever."""

    class Failing(_Recording):
        def match(self, frame, T_cam_lidar):
            raise RuntimeError("the coarse matcher broke")

    coarse = FAST.coarse.model_copy(update={"start": "both"})
    config = FAST.model_copy(update={"flow_coarse_passes": 1, "pyramid_focals_px": (), "coarse": coarse})
    raised = []

    def calibrate() -> None:
        try:
            Calibrator(config=config, coarse_matcher=Failing()).calibrate(
                frames, frames[0].calibration.T_cam_lidar
            )
        except RuntimeError as error:
            raised.append(str(error))

    worker = threading.Thread(target=calibrate, daemon=True)
    worker.start()
    worker.join(timeout=120)
    assert not worker.is_alive(), "the calibration still waits for the failed passes"
    assert raised == ["the coarse matcher broke"]


def test_flow_coarse_frames_run_those_passes_on_a_subset(frames):
    """``flow_coarse_frames`` gives the coarse matcher's passes that many frames, spread evenly
    (first and last); the probe still weighs their answer on every frame."""
    config = FAST.model_copy(
        update={
            "flow_coarse_passes": 1,
            "flow_coarse_frames": 2,
            "pyramid_focals_px": (),
            "time_offset": FAST.time_offset.model_copy(update={"mode": "off"}),
        }
    )
    T_init = perturb(frames[0].calibration.T_cam_lidar, 5.0, 1.0, torch.Generator().manual_seed(2))
    coarse = _Recording()
    result = Calibrator(config=config, coarse_matcher=coarse).calibrate(frames, T_init)
    picked = [frames[i] for i in result.frame_indices]
    assert len(picked) > 2
    assert {id(f) for f in coarse.frames} == {id(picked[0]), id(picked[-1])}
    flow = next(c for c in result.coarse if c["stage"] == "flow")
    assert flow["frames"] == 2
    assert "flow" in next(c for c in result.coarse if c["stage"] == "choice")["alignment_after_first_pass_px"]


def test_a_map_support_source_is_used_and_checked(frames):
    assert isinstance(UniformSupport(), SupportSource)
    wrong = MapSupport("offline:x", np.ones((3, 3), np.float32))
    T = frames[0].calibration.T_cam_lidar
    with pytest.raises(DataError, match="map is"):
        Calibrator(support=wrong, config=FAST).calibrate(frames, T)


def test_without_reference_the_error_is_none(frames):
    result = Calibrator(config=FAST).calibrate(frames, frames[0].calibration.T_cam_lidar)
    bare = CalibrationResult(**{**result.__dict__, "reference_T_cam_lidar": None})
    assert bare.error is None and bare.to_dict()["error"] is None


def test_motions_of_another_sequence_or_other_settings_are_refused(frames):
    T = frames[0].calibration.T_cam_lidar
    calibrator = Calibrator(config=FAST)  # δt estimated: the motions are asked for
    with pytest.raises(ConfigError, match="SequenceMotions of another sequence"):
        calibrator.calibrate(frames, T, motions=SequenceMotions(list(frames)))
    with pytest.raises(ConfigError, match="neighbours"):
        calibrator.calibrate(
            frames, T, motions=SequenceMotions(frames, neighbours=FAST.time_offset.neighbours + 1)
        )


def test_bad_extrinsics_and_learned_matchers_are_refused(frames):
    with pytest.raises(DataError, match="T_init"):
        Calibrator(config=FAST).calibrate(frames, np.eye(3))
    with pytest.raises(DataError, match="not orthonormal"):
        Calibrator(config=FAST).calibrate(frames, np.diag([2.0, 1, 1, 1]))
    with pytest.raises(ConfigError, match="learned matcher"):
        Calibrator(config=CalibrateConfig(matcher="flow"))


def test_online_calibrator_closes_windows_and_tracks(frames, monkeypatch):
    """Windows of 3 frames every 2, tracked; the filter takes each window's independent-residual
    covariance, the one its measurement floor was set for, not the cluster-robust one a
    calibration reports, moved to the LiDAR frame its departure lives in."""
    import calib.pipeline
    from calib.refine.tracking import OnlineState, departure_covariance

    windows, fed = [], []
    refine_passes, update = calib.pipeline.refine_passes, OnlineState.update

    def passes_recorded(*args, **kwargs):
        windows.append(refine_passes(*args, **kwargs))
        return windows[-1]

    def update_recorded(self, z, R, *args, **kwargs):
        fed.append(R)
        return update(self, z, R, *args, **kwargs)

    monkeypatch.setattr(calib.pipeline, "refine_passes", passes_recorded)
    monkeypatch.setattr(OnlineState, "update", update_recorded)
    T_ref = frames[0].calibration.T_cam_lidar
    T_init = perturb(T_ref, 5.0, 1.0, torch.Generator().manual_seed(1))
    online = OnlineCalibrator(T_init, config=FAST)
    estimates = [online.push(f) for f in frames]
    assert len(fed) == len(windows) == 3
    for R, window in zip(fed, windows, strict=True):
        np.testing.assert_array_equal(R, departure_covariance(window.covariance, window.T_cam_lidar))
        assert window.cell_covariance is not None
        assert not np.allclose(window.cell_covariance, window.covariance)
    closed = [e for e in estimates if e is not None]
    # windows of 3 frames every 2: [0-2], [2-4], [4-6]
    assert [(e.first_frame, e.last_frame) for e in closed] == [(0, 2), (2, 4), (4, 6)]
    assert estimates[2] is closed[0] and estimates[0] is None
    assert all(isinstance(e, OnlineEstimate) for e in closed)
    last = closed[-1]
    assert calibration_error(last.T_cam_lidar, T_ref).rotation_deg < 0.5
    assert np.allclose(online.T_cam_lidar, last.T_cam_lidar)
    json.dumps(last.to_dict(), allow_nan=False)


def test_matchings_are_pooled_at_the_finest_level_alone(frames, monkeypatch):
    """``pool_matchings`` averages the finest level's noise; the learned matcher's passes, the probe
    and the pyramid's levels only start the next stage and end on their last pass."""
    import calib.pipeline

    pooled, refine_passes = [], calib.pipeline.refine_passes

    def recording(frames, T, matcher, support, config, *args, **kwargs):
        pooled.append(config.pool_matchings)
        return refine_passes(frames, T, matcher, support, config, *args, **kwargs)

    monkeypatch.setattr(calib.pipeline, "refine_passes", recording)
    config = FAST.model_copy(update={"pool_matchings": 3, "pyramid_focals_px": (90.0, 180.0)})
    T_ref = frames[0].calibration.T_cam_lidar
    result = Calibrator(config=config).calibrate(
        frames, perturb(T_ref, 5.0, 1.0, torch.Generator().manual_seed(0))
    )
    assert len(pooled) >= 3 and pooled[-1] == 3 and set(pooled[:-1]) == {1}
    assert result.error.translation_cm < 2.5 and result.error.rotation_deg < 0.4


def test_a_rig_is_calibrated_through_its_cameras(frames):
    """Known answer: the frames as cameras of a rig whose frame is turned 90° and moved 1 m from
    the camera's (``T_cam_rig``): the calibration undoes 10 cm / 2° of ``T_rig_lidar`` as it
    does of ``T_cam_lidar`` above, each frame matched under ``T_cam_rig · T``; its reference is
    ``T_rig_lidar``. A rig's camera beside a camera on its own is refused."""
    T_ref = frames[0].calibration.T_cam_lidar
    T_rig_lidar = (
        se3_exp(torch.tensor([1.0, 0.2, -0.3, 0.0, 1.5708, 0.1], dtype=torch.float64)).numpy() @ T_ref
    )
    T_cam_rig = T_ref @ np.linalg.inv(T_rig_lidar)
    rig = [replace(f, calibration=replace(f.calibration, T_cam_rig=T_cam_rig)) for f in frames]
    under = match_frames(EdgeMatcher(FAST.edge), rig[:1], T_rig_lidar)[0]
    alone = EdgeMatcher(FAST.edge).match(frames[0], T_ref)
    np.testing.assert_allclose(under.uv, alone.uv, atol=1e-6)
    T_init = perturb(T_rig_lidar, 10.0, 2.0, torch.Generator().manual_seed(0))
    result = Calibrator(config=FAST).calibrate(rig, T_init)
    np.testing.assert_allclose(result.reference_T_cam_lidar, T_rig_lidar, atol=1e-9)
    assert result.initial_error.translation_cm == pytest.approx(10.0)
    assert result.error.translation_cm < 2.5 and result.error.rotation_deg < 0.4
    with pytest.raises(DataError, match="rig"):
        Calibrator(config=FAST).calibrate([rig[0], *frames[1:]], T_init)
    with pytest.raises(DataError, match="online calibration takes one camera"):
        OnlineCalibrator(T_init, config=FAST).push(rig[0])
