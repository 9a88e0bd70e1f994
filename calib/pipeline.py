"""The method, in its four stages (DESIGN.md):

1. an initial extrinsic ``T⁰`` (given, or from motion: :mod:`calib.init`);
2. cross-modal residuals: a matcher gives each projected LiDAR point its image-plane residual
   (:mod:`calib.match`);
3. a support map of where those residuals are reliable (:mod:`calib.support`; offline maps, or a
   learned predictor that ``supportnet`` plugs in through :class:`~calib.support.source.SupportSource`);
4. support-guided sampling and the weighted SE(3) refinement, in passes (:mod:`calib.refine`).

:class:`Calibrator` runs them on a sequence; :class:`OnlineCalibrator` runs Stages 2–4 window by
window on a stream and fuses the windows into a running estimate with a drift alarm.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from collections.abc import Sequence as FrameList
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from functools import partial

import numpy as np

from calib.data.extrinsic_file import rigid_problem
from calib.data.rig import unknown_reference
from calib.data.types import Frame, Sequence
from calib.errors import ConfigError, DataError
from calib.init.lidar_odometry import SequenceMotions
from calib.init.motion_init import Stage1Config, Stage1Result, initial_calibration, load_stage1_config
from calib.match.correspondences import Matcher
from calib.match.edge_matcher import EdgeMatcher
from calib.motion import ScanMotion, mean_twist
from calib.moving import without_moving
from calib.observability import weak_directions
from calib.refine.contour_refine import contour_refine
from calib.refine.frame_selection import contour_information, select_informative
from calib.refine.global_search import global_search
from calib.refine.passes import (
    CalibrateConfig,
    PassesResult,
    ScanTiming,
    load_calibrate_config,
    matched_rules_hold,
    point_times,
    refine_passes,
    scan_timing,
    sweep_model,
)
from calib.refine.tracking import OnlineState, departure, departure_covariance, extrinsic_of
from calib.results import CalibrationResult, OnlineEstimate
from calib.support.source import SupportSource, UniformSupport

__all__ = ["Calibrator", "OnlineCalibrator", "camera_time", "default_matcher", "select_frames"]

NEAR_FINEST = 0.9
"""A pyramid level (or the probe) at or above this share of the finest working focal length would
repeat the finest level (a 624x188 camera's 360.8 px against a 360 px level): it runs there instead."""


def select_frames(n: int, count: int) -> np.ndarray:
    """``min(count, n)`` frame positions spread evenly over ``range(n)`` (first and last included)."""
    if n < 1:
        raise DataError("sequence", "has no frames")
    return np.unique(np.linspace(0, n - 1, min(count, n)).round().astype(int))


def default_matcher(config: CalibrateConfig) -> Matcher:
    """The config's Stage 2 matcher when ``calib`` can build it alone (the EdgeMatcher); the
    learned flow matcher comes from ``supportnet`` (``supportnet.Calibrator`` builds it)."""
    if config.matcher != "edge":
        raise ConfigError(
            "matcher", f"{config.matcher!r} is a learned matcher: pass matcher= or use supportnet"
        )
    return EdgeMatcher(config.edge)


def _spread(
    frames: list[Frame], timing: ScanTiming | None, count: int | None
) -> tuple[list[Frame], ScanTiming | None]:
    """``count`` of ``frames`` spread evenly (:func:`select_frames`; ``None``: all of them) and
    their part of ``timing``."""
    some = select_frames(len(frames), count or len(frames))
    return [frames[i] for i in some], None if timing is None else timing.of_frames(some)


def _passes_entry(stage: str, passes: list[dict], **extra: float) -> dict:
    """A coarse stage's passes as a line in ``result.coarse``: how many it ran and the median
    residual (its matcher's working px) before its first and after its last accepted one."""
    accepted = [p for p in passes if p.get("accepted", True)]
    return {
        "stage": stage,
        **extra,
        "passes": len(passes),
        "alignment_px": passes[0].get("alignment_px") if passes else None,
        "alignment_after_px": accepted[-1].get("alignment_after_px") if accepted else None,
    }


class _Laps:
    """Seconds per stage of one calibration: each call closes the stage run since the last (and
    tells ``on_stage`` its name and seconds)."""

    def __init__(self, on_stage: Callable[[str, float], None] | None = None) -> None:
        self.seconds: dict[str, float] = {}
        self._on_stage = on_stage
        self._start = self._last = time.perf_counter()

    def __call__(self, stage: str) -> None:
        now = time.perf_counter()
        self.seconds[stage] = now - self._last
        self._last = now
        if self._on_stage is not None:
            self._on_stage(stage, self.seconds[stage])

    @property
    def total_s(self) -> float:
        return time.perf_counter() - self._start


def camera_time(
    config: CalibrateConfig,
    seq: Sequence | FrameList[Frame],
    picks: list[int],
    frames: list[Frame],
    known: Mapping[int, ScanMotion] | SequenceMotions | str | None,
    initial_s: float | None = None,
    restarts: bool = True,
    offset_known: bool = True,
) -> tuple[ScanTiming | None, str, list[Frame], list[int]]:
    """How the used ``frames`` (those at ``picks`` of ``seq``) move to the camera's time:
    ``known`` motions, else LiDAR odometry around each (remembered by ``known`` where it is a
    :class:`SequenceMotions` of ``seq``); or ``None`` and why the points stay as measured.
    ``δt`` starts at ``initial_s`` where given, else at the config's (``restarts``: restarting
    from where it settles, :func:`~calib.refine.passes.scan_timing`). Where ``δt`` is estimated,
    held at anything but 0, or not ``offset_known`` (an online window's running guess), the
    frames lose the points that the scans before and after them show moving
    (``outliers.moving``): returned with how many each lost."""
    cfg = config.time_offset
    none = [0] * len(frames)
    if cfg.mode == "off":
        return None, "not modelled (time_offset.mode: off): points as measured", frames, none
    if isinstance(known, str):
        return None, f"not modelled, points as measured: {known}", frames, none
    if isinstance(known, Mapping):
        missing = [i for i in picks if i not in known]
        if missing:
            raise DataError("motions", f"have no motion for the frames at positions {missing}")
        motions = [known[i] for i in picks]
    else:
        memo = known or SequenceMotions(seq, cfg.neighbours, cfg.deskew_rounds)
        settings = (memo.neighbours, memo.deskew_rounds)
        if memo.seq is not seq or settings != (cfg.neighbours, cfg.deskew_rounds):
            raise ConfigError(
                "motions",
                "is a SequenceMotions of another sequence or other time_offset.neighbours / deskew_rounds",
            )
        motions, why = memo(picks)
        if motions is None:
            return None, f"not modelled, points as measured: {why}", frames, none
    initial_s = cfg.initial_s if initial_s is None else initial_s
    timing, note = scan_timing(frames, motions, cfg, initial_s, restarts=restarts)
    moving, lost = config.outliers.moving, none
    # a moving car seen δt later pulls δt where it is fitted, and the extrinsic where δt is held
    # at a value that is not 0 or not known (an online window's first guess of 0); held at a
    # known 0, the cars the camera saw at the scan's time are evidence like a wall's (README)
    if moving.enabled and (timing.estimate or timing.offset_s != 0.0 or not offset_known):
        times = partial(point_times, sweep=sweep_model(cfg))
        frames, masks = without_moving(seq, picks, frames, timing.stamp, motions, moving, times)
        timing = replace(timing, stamp=[q[~m] for q, m in zip(timing.stamp, masks, strict=True)])
        lost = [int(m.sum()) for m in masks]
    return timing, note, frames, lost


class Calibrator:
    """Calibrate a sequence: Stage 1 (or a given ``T_init``), then Stages 2–4 in passes.

    Args:
        support: Stage 3, the support source (default: uniform sampling).
        matcher: Stage 2 (default: the config's EdgeMatcher).
        config: Stages 2–4 (default: the packaged ``calibrate.yaml``).
        stage1: Stage 1 from motion, used when ``calibrate`` gets no ``T_init`` (default: the
            packaged ``init_calib.yaml``).
        coarse_matcher: the matcher of ``config.flow_coarse_passes`` (the learned flow matcher,
            which ``supportnet.Calibrator`` builds); needed only where those are on.
    """

    def __init__(
        self,
        support: SupportSource | None = None,
        matcher: Matcher | None = None,
        config: CalibrateConfig | None = None,
        stage1: Stage1Config | None = None,
        coarse_matcher: Matcher | None = None,
    ) -> None:
        self.config = config if config is not None else load_calibrate_config()
        self.support = support if support is not None else UniformSupport()
        self.matcher = matcher if matcher is not None else default_matcher(self.config)
        self._stage1 = stage1
        if self.config.flow_coarse_passes and coarse_matcher is None:
            raise ConfigError(
                "flow_coarse_passes",
                "needs the learned flow matcher: use supportnet.Calibrator, or pass coarse_matcher=",
            )
        self.coarse_matcher = coarse_matcher
        self._levels: dict[tuple, tuple[Matcher, CalibrateConfig]] = {}  # by what _level changed

    def initial_extrinsic(self, seq: Sequence) -> np.ndarray:
        """Stage 1: ``T⁰ (4, 4)`` from the sequence's motion (raises when motion cannot tell)."""
        return self._stage1_result(seq).T_cam_lidar

    def _stage1_result(self, seq: Sequence) -> Stage1Result:
        return initial_calibration(seq, self._stage1 if self._stage1 is not None else load_stage1_config())

    def _pick_frames(self, seq: Sequence | FrameList[Frame], T_init: np.ndarray) -> tuple[list[int], dict]:
        """Positions of the frames Stage 4 uses (``config.selection``) and the frames loaded to
        choose them, by position."""
        count, selection = self.config.frames, self.config.selection
        if selection.method == "spread" or len(seq) <= count:
            return [int(i) for i in select_frames(len(seq), count)], {}
        candidates = [int(i) for i in select_frames(len(seq), count * selection.candidates)]
        loaded = {i: seq[i] for i in candidates}
        informations = [
            contour_information(f.points, T_init, f.K, f.image_size, f.calibration.T_cam_rig)
            for f in loaded.values()
        ]
        return [candidates[j] for j in select_informative(informations, count)], loaded

    def _level(self, focal: float | None = None, fine: bool = False) -> tuple[Matcher, CalibrateConfig]:
        """The matcher and config of one level: the edge matcher at working focal length ``focal``
        (``None``: the finest level's, ``config.finest_focal_px`` or its own) and, ``fine``, with
        ``config.fine_intensity_weight`` where set (sharing this one's scan features); this
        calibrator's own where that changes nothing."""
        if not isinstance(self.matcher, EdgeMatcher):
            return self.matcher, self.config
        update: dict = {}
        focal = focal if focal is not None else self.config.finest_focal_px
        if focal is not None and focal != self.matcher.config.working_focal_px:
            update["working_focal_px"] = focal
        if fine and self.config.fine_intensity_weight is not None:
            update["intensity_weight"] = self.config.fine_intensity_weight
        if not update:
            return self.matcher, self.config
        key = tuple(sorted(update.items()))
        if key not in self._levels:  # kept: its image views serve the next calibration too
            edge = self.matcher.config.model_copy(update=update)
            self._levels[key] = self.matcher.with_config(edge), self.config.model_copy(update={"edge": edge})
        return self._levels[key]

    def _finest_focal(self, frames: list[Frame]) -> float:
        """The finest level's working focal length on ``frames``: ``config.finest_focal_px`` (or
        the matcher's), or the camera's own where that is shorter (images are never resampled up).
        A level (or the probe) from :data:`NEAR_FINEST` of it up would repeat it."""
        finest = self.config.finest_focal_px or self.matcher.config.working_focal_px
        return min(finest, min(float(f.K[0, 0]) for f in frames))

    def _pyramid_focals(self, frames: list[Frame]) -> list[float]:
        """The coarser working focal lengths the edge matcher's passes run at first on ``frames``
        (none for another matcher): those of ``config.pyramid_focals_px`` under
        :data:`NEAR_FINEST` of the finest level's; on fewer than ``config.pyramid_min_frames``
        frames only those from ``config.few_frames_from_px`` on (none where unset)."""
        if not isinstance(self.matcher, EdgeMatcher):
            return []
        below = NEAR_FINEST * self._finest_focal(frames)
        few = len(frames) < self.config.pyramid_min_frames
        return [
            f
            for f in self.config.pyramid_focals_px
            if f < below and (not few or _from(f, self.config.few_frames_from_px))
        ]

    def calibrate(
        self,
        seq: Sequence | FrameList[Frame],
        T_init: np.ndarray | None = None,
        seed: int | tuple[int, ...] = 0,
        motions: Mapping[int, ScanMotion] | SequenceMotions | str | None = None,
        on_stage: Callable[[str, float], None] | None = None,
    ) -> CalibrationResult:
        """Calibrate ``seq`` (a :class:`Sequence`, a list of frames sharing one ``K``, or a list of
        the frames of a rig's cameras, :mod:`calib.data.rig`: ``T_init`` and the answer are then
        ``T_rig_lidar``).

        Args:
            seq: the data; ``config.frames`` of its frames are used (``config.selection``:
                spread evenly, or the most informative of ``candidates`` times as many).
            T_init: ``(4, 4)`` initial ``T_cam_lidar``; ``None``: Stage 1 from motion.
            seed: of the correspondence sampling (an int or a tuple, as numpy seeds take).
            motions: the LiDAR's motion around each frame by position (from an INS, a simulator's
                trajectory), used for the time offset instead of LiDAR odometry; a
                :class:`SequenceMotions` of ``seq`` (odometry run once for many calls); or a string
                saying why there is none (nothing is tried).
            on_stage: called with each stage's name and seconds as it ends (a progress display).
        """
        lap = _Laps(on_stage)
        if T_init is None:
            if not isinstance(seq, Sequence):
                raise DataError("T_init", "Stage 1 needs a Sequence (with time stamps); give T_init")
            stage1 = self._stage1_result(seq)  # Stage 1
            T_init, stage1_offset = stage1.T_cam_lidar, stage1.time_offset_s
            lap("stage 1")
        else:
            stage1_offset = None
        T_init = _checked_extrinsic(T_init, "T_init")
        picks, loaded = self._pick_frames(seq, T_init)
        frames = [loaded[i] if i in loaded else seq[i] for i in picks]
        lap("frames")
        if frames[0].calibration.T_cam_rig is not None and not isinstance(motions, str):
            # a rig's frames follow each other camera by camera, not scan by scan: no odometry
            motions = "a rig's cameras (the time offset is modelled for one camera)"
        timing, timing_note, frames, moving = camera_time(
            self.config, seq, picks, frames, motions, stage1_offset
        )
        lap("motion and moving points")
        # the coarse stages see the points at the camera's time under the initial δt
        seen = frames if timing is None else timing.frames_at(frames, timing.offset_s)
        coarse_starts: dict[str, np.ndarray] = {}  # other starts for the passes, by origin
        coarse: list[dict] = []
        rng = np.random.default_rng(seed)
        held = None if timing is None else replace(timing, estimate=False, restarts_s=())
        # the global search (torch) runs beside the learned matcher's passes (onnxruntime): both
        # start from the initial extrinsic and share nothing; or (`coarse.start: flow`) after them,
        # from their answer; or (`both`) from the initial extrinsic beside them, their answer
        # joining it when they end
        start = self.config.coarse.start if self.config.flow_coarse_passes else "initial"
        kinds = self.config.coarse.scores if self.config.coarse.enabled else ()
        flow, handoff = None, Future()

        def flow_passes() -> PassesResult:  # the learned matcher's passes from the initial extrinsic
            # pooled matchings (`pool_matchings`) average the finest level's noise; a coarser
            # answer only starts the next level
            flow_config = self.config.model_copy(
                update={"passes": self.config.flow_coarse_passes, "pool_matchings": 1}
            )
            try:
                result = refine_passes(
                    some, T_init, self.coarse_matcher, self.support, flow_config, rng, timing=some_timing
                )
            except BaseException as error:  # the searches waiting on it end too
                handoff.set_exception(error)
                raise
            handoff.set_result(result.T_cam_lidar)
            return result

        def submit_search(kind: str, T_start: np.ndarray) -> Future:  # Stage 4, coarse: beyond the matcher
            later = handoff.result if start == "both" else None
            return background.submit(global_search, seen, T_start, self.config.coarse, kind, later)

        some, some_timing = _spread(frames, held, self.config.flow_coarse_frames)
        # each search of `both` waits for the passes' answer: one worker per edge map
        with ThreadPoolExecutor(len(kinds) if start == "both" and kinds else 1) as background:
            if start == "flow":
                flow = flow_passes()
            searches = [(kind, submit_search(kind, flow.T_cam_lidar if flow else T_init)) for kind in kinds]
            if self.config.flow_coarse_passes and flow is None:
                flow = flow_passes()
            for kind, search in searches:  # the starts in the order they always had: the global ones first
                result = search.result()
                coarse_starts[f"global ({kind})"] = result.T_cam_lidar
                coarse += [{"stage": "global", "score": kind, **level} for level in result.levels]
        if searches or flow is not None:
            both = "flow, then global" if start == "flow" else "global and flow, side by side"
            lap(both if searches and flow else "global" if searches else "flow")
        if self.config.contour.enabled:  # then the contour score over all six parameters at once
            refined = {}
            for origin, T_start in (coarse_starts or {"initial": T_init}).items():
                climb = contour_refine(seen, T_start, self.config.contour)
                coarse += [{"stage": "contour", "from": origin, **level} for level in climb.levels]
                refined[f"{origin}, contour"] = climb.T_cam_lidar
            coarse_starts = refined
            lap("contour")
        if flow is not None:
            coarse_starts["flow"] = flow.T_cam_lidar
            coarse.append(_passes_entry("flow", flow.passes, frames=len(some)))
        T_start, alternatives, probed = T_init, list(coarse_starts.values()), None
        pyramid = self._pyramid_focals(frames)
        if pyramid and alternatives:
            # the start is chosen by one pass at the finest level (or `probe_focal_px`), where a
            # wrong start ends its pass worse aligned than the right one; at 90 px it often ends
            # as well aligned
            probe = self.config.probe_focal_px
            coarser = probe is not None and probe < NEAR_FINEST * self._finest_focal(frames)
            matcher, config = self._level(probe if coarser else None)
            one_pass = config.model_copy(update={"passes": 1, "pool_matchings": 1})
            some, some_timing = _spread(frames, held, self.config.probe_frames)
            probed = refine_passes(
                some, T_start, matcher, self.support, one_pass, rng, alternatives, some_timing
            )
            T_start, alternatives = probed.T_cam_lidar, []
            lap("probe")
        restarted = None  # the passes that ran the δt restarts, where a pyramid level did
        timed_from = self.config.time_offset.from_px
        for focal in pyramid:  # the edge matcher coarse to fine, δt held until `time_offset.from_px`
            matcher, level_config = self._level(focal, _from(focal, self.config.fine_from_px))
            timed = timing is not None and _from(focal, timed_from)
            level_config = level_config.model_copy(update={"pool_matchings": 1})
            level = refine_passes(
                frames, T_start, matcher, self.support, level_config, rng, timing=timing if timed else held
            )
            # an aliased answer (the vineyard's rows at 90 px) loses matched points, the truth gains them
            kept_from, kept = level.matched
            undone = matched_rules_hold(self.config, focal) and kept < self.config.level_min_share * kept_from
            if not undone:
                T_start = level.T_cam_lidar
                if timed:  # the finer levels go on from its δt, without restarts
                    restarted = restarted or level
                    timing = replace(timing, offset_s=level.time_offset_s, restarts_s=())
            coarse.append(
                {
                    **_passes_entry("pyramid", level.passes, working_focal_px=focal),
                    "matched": [kept_from, kept],
                    "undone": undone,
                }
            )
            lap(f"pyramid {focal:g} px")
        finest, finest_config = self._level(fine=True)
        passes = refine_passes(  # Stages 2 (matcher), 3 (support) and 4 (SGIS + Eq. 4), in passes
            frames,
            T_start,
            finest,
            self.support,
            finest_config,
            rng,
            alternatives=alternatives,
            timing=timing,
        )
        lap("finest")
        probed = probed if probed is not None else passes
        if timing is not None and not timing_note:
            timing_note = (
                f"estimated from the motion of {len(frames)} frames"
                if passes.time_offset_std_s is not None
                else f"held at {timing.offset_s:g} s: on these frames its standard deviation passes "
                f"{timing.max_std_s:g} s (too little motion, or too uniform to tell it from a translation)"
                if timing.estimate
                else f"held at {timing.offset_s:g} s (time_offset.mode: fixed); points moved to it"
            )
            timing_note += "".join(
                f"; restarted at δt {1e3 * r['time_offset_from_s']:.1f} ms (median residual "
                f"{r['alignment_px']:.2f} px against the settled {r['alignment_before_px']:.2f} px)"
                for r in (restarted or passes).time_offset_restarts
                if r["taken"]
            )
        if coarse_starts:  # the passes went on from the start whose first pass ended best aligned
            origins = ["initial", *coarse_starts]
            coarse.append(
                {
                    "stage": "choice",
                    "kept": origins[probed.start],
                    "alignment_after_first_pass_px": dict(
                        zip(origins, probed.probe_alignments_px, strict=True)
                    ),
                    "correspondences_after_first_pass": dict(
                        zip(origins, probed.probe_correspondences, strict=True)
                    ),
                }
            )
        covariance = passes.reported_covariance
        covariance_t, covariance_r = covariance[:3, :3], covariance[3:, 3:]
        weak = weak_directions(
            covariance_t,
            covariance_r,
            passes.T_cam_lidar[:3, :3],
            self.config.weak_std_cm,
            self.config.weak_std_deg,
        )
        return CalibrationResult(
            T_cam_lidar=passes.T_cam_lidar,
            initial_T_cam_lidar=T_init,
            reference_T_cam_lidar=unknown_reference(frames[0].calibration),
            covariance=covariance,
            support=self.support.name,
            frame_indices=[int(i) for i in picks],
            correspondences=passes.correspondences,
            runtime_s=lap.total_s,
            passes=passes.passes,
            coarse=coarse,
            weak_directions=weak,
            time_offset_s=passes.time_offset_s,
            time_offset_std_s=passes.time_offset_std_s,
            time_offset_note=timing_note,
            time_offset_reference_s=_stamp_offset(frames),
            moving_points=moving,
            stage_seconds=lap.seconds,
        )


class OnlineCalibrator:
    """Stages 2–4 on a stream, window by window (``config.online.window`` frames, a new window
    every ``config.online.step``), fused by a Kalman filter with a random-walk mount
    (:mod:`calib.refine.tracking`) into a running estimate with its covariance and a drift alarm.

    Args:
        T_init: ``(4, 4)`` where the running estimate starts.
        support, matcher, config: as :class:`Calibrator`.
        T_file: the calibration on file that drift is measured against (default: the first
            frame's own calibration, else ``T_init``).
        seed: of the correspondence sampling.
    """

    def __init__(
        self,
        T_init: np.ndarray,
        support: SupportSource | None = None,
        matcher: Matcher | None = None,
        config: CalibrateConfig | None = None,
        T_file: np.ndarray | None = None,
        seed: int = 0,
    ) -> None:
        self.config = config if config is not None else load_calibrate_config()
        self.support = support if support is not None else UniformSupport()
        self.matcher = matcher if matcher is not None else default_matcher(self.config)
        self.T_init = _checked_extrinsic(T_init, "T_init")
        self.T_file = None if T_file is None else _checked_extrinsic(T_file, "T_file")
        self._rng = np.random.default_rng(seed)
        self._state: OnlineState | None = None
        self._buffer: list[Frame] = []
        self._history: list[Frame] = []  # the frames just before the window
        self._pushed = 0
        self._next_start = 0
        self._windows = 0
        self._last_time_s: float | None = None  # the last window's middle frame's stamp

    @property
    def T_cam_lidar(self) -> np.ndarray:
        """``(4, 4)`` the running estimate (``T_init`` before the first window closes)."""
        if self._state is None:
            return self.T_init
        return extrinsic_of(self._state.x, self.T_file)

    def push(self, frame: Frame) -> OnlineEstimate | None:
        """Add the next frame of the stream; an :class:`OnlineEstimate` when it closes a window,
        else ``None``.

        Raises:
            DataError: a rig's camera's frame (``T_cam_rig``): online calibration has one camera.
        """
        if frame.calibration.T_cam_rig is not None:
            raise DataError(frame.name or "frame", "is a rig's camera's: online calibration takes one camera")
        online = self.config.online
        position = self._pushed
        self._pushed += 1
        if self.T_file is None:
            T = frame.calibration.T_cam_lidar
            self.T_file = self.T_init if T is None else np.asarray(T, np.float64)
        if self._state is None:
            self._state = OnlineState.start(
                self.T_init, self.T_file, online, self.config.time_offset.initial_s
            )
        if position >= self._next_start:
            self._buffer.append(frame)
        else:
            self._remember([frame])
        if len(self._buffer) < online.window:
            return None
        first = self._next_start
        middle = self._buffer[online.window // 2]
        elapsed = None
        if middle.timestamp is not None and self._last_time_s is not None:
            elapsed = middle.timestamp - self._last_time_s
        self._last_time_s = middle.timestamp
        timing, frames = self._window_timing(self._state.predicted_time_offset_s(elapsed))
        passes = refine_passes(
            frames, self.T_cam_lidar, self.matcher, self.support, self.config, self._rng, timing=timing
        )
        fitted = passes.time_offset_std_s is not None
        taken = self._state.update(
            departure(passes.T_cam_lidar, self.T_file),
            departure_covariance(passes.covariance, passes.T_cam_lidar),
            # where δt may move (estimated, not fixed), what each window's fit says of it (a
            # straight one: with the extrinsic)
            mean_twist(timing.motions)
            if timing is not None and self.config.time_offset.mode == "estimate"
            else None,
            passes.time_offset_s or 0.0,
            passes.time_offset_s if fitted else None,
            passes.time_offset_std_s,
            elapsed,
        )
        estimate = OnlineEstimate(
            window=self._windows,
            first_frame=first,
            last_frame=first + online.window - 1,
            time_s=float(middle.timestamp if middle.timestamp is not None else first + online.window // 2),
            T_cam_lidar=self.T_cam_lidar,
            window_T_cam_lidar=passes.T_cam_lidar,
            covariance=self._state.P.copy(),
            drift=self._state.drift,
            correspondences=passes.correspondences,
            reference_T_cam_lidar=self.T_file,
            time_offset_s=self._state.time_offset_s,
            time_offset_std_s=self._state.time_offset_std_s,
            window_time_offset_s=passes.time_offset_s if fitted else None,
            window_time_offset_taken=taken,
            time_offset_rate=self._state.time_offset_rate,
        )
        self._windows += 1
        self._next_start += online.step
        self._remember(self._buffer[: online.step])
        self._buffer = self._buffer[online.step :]
        return estimate

    def _remember(self, frames: list[Frame]) -> None:
        """Keep the last ``time_offset.neighbours`` frames before the window: the odometry around
        its first scans starts there (KISS-ICP misreads the speed over its first few scans)."""
        keep = self.config.time_offset.neighbours
        self._history = (self._history + frames)[-keep:] if keep else []

    def _window_timing(self, time_offset_s: float) -> tuple[ScanTiming | None, list[Frame]]:
        """How the window's frames move to ``time_offset_s`` (the running ``δt`` carried to the
        window at its rate), fitted where their motion tells it
        (:func:`camera_time` with the scans before the window and within it as the odometry's),
        and the frames less their moving points (held or fitted: the running ``δt`` is a guess)."""
        context = [*self._history, *self._buffer]
        picks = list(range(len(self._history), len(context)))
        # no δt restarts: the running estimate is tracked across windows; a guess, not a known δt
        timing, _, frames, _ = camera_time(
            self.config,
            context,
            picks,
            self._buffer,
            None,
            time_offset_s,
            restarts=False,
            offset_known=False,
        )
        return timing, frames


def _from(focal: float, floor: float | None) -> bool:
    """Whether a level at working focal length ``focal`` is at or above ``floor`` (a config's
    ``*_from_px``; ``None``: no level is)."""
    return floor is not None and focal >= floor


def _stamp_offset(frames: list[Frame]) -> float | None:
    """Camera stamp minus LiDAR stamp when every frame has both and they agree (a synthetic
    world's true offset; on a real rig what its clocks claim), else ``None``."""
    offsets = [
        f.timestamp - f.lidar_timestamp
        for f in frames
        if f.timestamp is not None and f.lidar_timestamp is not None
    ]
    if len(offsets) != len(frames) or np.ptp(offsets) > 1e-6:
        return None
    return float(np.mean(offsets))


def _checked_extrinsic(T: np.ndarray, name: str) -> np.ndarray:
    """``T`` as a float64 ``(4, 4)`` rigid transform, or a one-line error naming ``name``."""
    T = np.asarray(T, np.float64)
    problem = rigid_problem(T)
    if problem is not None:
        raise DataError(name, problem)
    return T
