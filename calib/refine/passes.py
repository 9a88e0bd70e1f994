"""Stage 4 as passes: match with the current estimate, sample, refine, repeat (CMRNext runs its
matcher three times; each pass starts from the last estimate)."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import torch
from annotated_types import Ge, Le
from pydantic import BaseModel, ConfigDict, Field, NonNegativeFloat, PositiveFloat

from calib.data.rig import rig_poses
from calib.data.types import Frame
from calib.errors import DataError, NumericalError
from calib.geometry import calibration_error, se3_exp, se3_log
from calib.match.correspondences import Correspondences, Matcher, match_frames
from calib.match.edge_matcher import EdgeMatcherConfig
from calib.motion import ScanMotion, sweep_times, twist_spread
from calib.projection import pixel_lookup
from calib.refine.contour_refine import ContourRefineConfig
from calib.refine.frame_selection import FrameSelectionConfig
from calib.refine.global_search import GlobalSearchConfig
from calib.refine.outliers import OutlierConfig, frame_outliers, near_points, trim_points
from calib.refine.sgis import depth_strata, stratified_support_sample, support_sample, uniform_sample
from calib.refine.solver import RefineConfig, Refinement, TimeModel, refine_extrinsic
from calib.refine.tracking import OnlineConfig
from calib.support.source import SupportSource
from calib.yaml_io import load_config

__all__ = [
    "CalibrateConfig",
    "PassesResult",
    "SamplingConfig",
    "ScanTiming",
    "TimeOffsetConfig",
    "draw",
    "point_times",
    "refine_passes",
    "scan_timing",
    "sweep_model",
]


class SamplingConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    per_frame: int = Field(2000, ge=6, description="correspondences drawn from each frame per pass")
    floor: float = Field(0.01, ge=0, description="added to every support value (zero stays possible)")
    weight_by_support: bool = Field(True, description="weight each drawn residual by s_i too (Eq. 4)")
    depth_strata: int = Field(
        1,
        ge=1,
        description="SGIS within this many depth quantiles of the frame's matches, each given the share "
        "uniform sampling gives it and its Eq. 4 weights scaled to mean 1 (calib/refine/sgis.py): the "
        "support chooses among points of like depth, the near ones keep their hold on the translation "
        "(1: Eq. 3 over all, the paper's SGIS)",
    )


class TimeOffsetConfig(BaseModel):
    """The camera–LiDAR time offset ``δt`` (camera time minus LiDAR stamp) and deskewing, both
    from the LiDAR's motion around each used frame (KISS-ICP over its neighbouring scans)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    mode: Literal["off", "fixed", "estimate"] = Field(
        "estimate",
        description="off: points as measured; fixed: deskewed and moved to initial_s after each "
        "stamp; estimate: from there δt is fitted as a seventh parameter where the frames' motion "
        "varies enough to tell it from a translation (else held at initial_s, and said so). Needs "
        "consecutive time-stamped scans around the used frames (LiDAR odometry); without them the "
        "points stay as measured, and the result says why. Online, each window's scans are their "
        "own odometry neighbours and δt is tracked across windows (online.time_offset_*)",
    )
    initial_s: float = Field(0.0, ge=-1, le=1, description="δt to start from (estimate) or to hold (fixed)")
    max_std_s: float = Field(
        0.002,
        gt=0,
        description="a fitted δt whose standard deviation passes this is not observable on these "
        "frames (too little motion, or too uniform to tell from a translation): it is held at initial_s",
    )
    min_speed_spread_mps: float = Field(
        2.0,
        gt=0,
        description="δt is estimated only when the used frames' velocities spread this much (RMS) "
        "or their turn rates min_turn_spread_radps: a motion common to all frames makes δt a "
        "fixed transform. High, because short-window odometry misreads speed (up to 1.5 m/s on "
        "the synthetic street) while it reads turn rates within 0.01 rad/s",
    )
    min_turn_spread_radps: float = Field(0.1, gt=0, description="see min_speed_spread_mps")
    restarts_ms: tuple[Annotated[float, Ge(-1000), Le(1000)], ...] = Field(
        (-25.0, 25.0),
        description="where δt is estimated, once the passes settle one more pass runs from the "
        "settled extrinsic with δt moved by each of these (ms), and the passes go on from there "
        "where it ends better aligned (restart_margin): the joint fit can settle where the "
        "extrinsic absorbs the offset (the vineyard's 20 ms in a turn is a 1.2° rotation, with δt "
        "near 1 ms), and from the settled extrinsic a moved δt finds the way out. Empty: none",
    )
    restart_margin: float = Field(
        0.95,
        gt=0,
        le=1,
        description="a restart is taken when its pass ends with at most this times the settled "
        "answer's median residual (measured on the vineyard: 0.75-0.83 px against 0.91 px where "
        "δt had settled at 1 ms for 20)",
    )
    restart_max_cm: float = Field(
        10.0,
        gt=0,
        description="... and its answer's translation is within this of the settled one's: a "
        "restart that moves it farther has traded δt·v for a translation along the motion (on the "
        "urban street a −50 ms offset went to −4 ms and 37 cm with a lower median residual), "
        "where the rescues it is for moved it 2-4 cm",
    )
    from_px: PositiveFloat | None = Field(
        180.0,
        description="the matcher pyramid's levels at or above this working focal length estimate δt "
        "too (the coarser ones hold it), and the first of them runs the restarts; the finer "
        "levels go on from its δt without restarts (null, or no such level: the finest level "
        "alone, with the restarts). A restart moves the points by 25 ms of motion, 1.4° in the "
        "vineyard's headland turn: 13 px at full resolution, past the finest level's reach; at "
        "360 px (9 px) one vineyard run of two still settled at δt 0.9 ms for 20, at 180 px both "
        "reached 19.8 ms (README)",
    )
    sweep: Literal["recorded", "clockwise", "counterclockwise"] = Field(
        "recorded",
        description="per-point times: as the scans record them (none: not deskewed), or, for a "
        "rotating LiDAR that records none, from each point's azimuth turning this way",
    )
    sweep_period_s: float = Field(0.1, gt=0, description="one turn of the LiDAR's head")
    sweep_stamp_azimuth_deg: float = Field(
        0.0, ge=-180, le=180, description="where the head faces at the scan's stamp (KITTI: forward, 0)"
    )
    neighbours: int = Field(
        3,
        ge=1,
        le=10,
        description="scans either side of each used frame given to the LiDAR odometry; its twist is "
        "the geodesic over that many scans each way (averages one registration's error over them)",
    )
    deskew_rounds: int = Field(
        1,
        ge=0,
        le=5,
        description="with per-point times, the LiDAR odometry runs this many times more on the scans "
        "deskewed by its last run (KISS-ICP deskews a short run's first scans with no motion; "
        ":func:`~calib.init.lidar_odometry.scan_motions`). Synthetic urban at 8 m/s, ten scans, "
        "three seeds: median speed error 0.58-0.93 m/s, 0.18-0.26 after one round, 0.08-0.29 "
        "after two; each round costs about one more odometry run (1-2 s)",
    )


class CalibrateConfig(BaseModel):
    """``configs/calibrate.yaml``."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    matcher: Literal["edge", "flow"] = "edge"
    flow_model: Path | None = Field(None, description="the flow matcher's ONNX file (None: the shipped one)")
    flow_coarse_passes: int = Field(
        0,
        ge=0,
        description="passes of the learned flow matcher (`flow_model`) from the initial extrinsic "
        "(it was trained on errors up to 10° / 50 cm), after the global coarse stage; where they end "
        "is one more start for the edge passes, taken only where its first edge pass ends best "
        "aligned (0: none; the packaged config: 2 on 3 frames). README, from 10° / 50 cm: the "
        "synthetic vineyard 11 of 12 draws within 2 cm / 0.2° (6 of 12 without), six real KITTI "
        "frames and synthetic urban without a basin miss, as without",
    )
    flow_coarse_frames: int | None = Field(
        None,
        ge=1,
        description="the flow passes run on this many of the frames, spread evenly (null: all); "
        "their answer is only a start, judged by the probe on every frame",
    )
    edge: EdgeMatcherConfig = EdgeMatcherConfig()
    support_map: Literal["support", "agreement"] = Field(
        "support",
        description="which offline map SGIS reads: the raw Eq. 2 sum (sampled matches measured "
        "closer to the truth) or the density-normalised agreement",
    )
    sampling: SamplingConfig = SamplingConfig()
    refine: RefineConfig = RefineConfig()
    frames: int = Field(10, ge=1, description="frames used")
    selection: FrameSelectionConfig = Field(FrameSelectionConfig(), description="which frames are used")
    passes: int = Field(5, ge=1)
    min_update_cm: float = Field(0.01, ge=0, description="stop early when a pass moves less than this")
    min_update_deg: float = Field(0.001, ge=0)
    check_passes: bool = Field(
        True,
        description="match once more after each pass; when the matcher's median residual did not "
        "fall, go back half the pass's update (up to `halvings` times), then undo it and stop",
    )
    coarse_margin: float = Field(
        0.5,
        gt=0,
        le=1,
        description="the passes go on from a coarse stage's answer only when their first pass from "
        "it ends with at most this times the median residual of their first pass from the initial "
        "extrinsic (measured: right answers 0.11-0.53; aliased ones on the vineyard's rows and a "
        "sparse nuScenes frame 0.55-0.68: the ratio alone barely separates them)",
    )
    coarse_min_share: float = Field(
        0.5,
        ge=0,
        le=1,
        description="a start (the initial extrinsic or a coarse stage's answer) is kept only when its "
        "first pass leaves the matcher at least this share of the most correspondences any start's "
        "first pass leaves (a PJLab frame from 2°: an answer 42° off matched by 23 points at 9.4 px "
        "beat 211 at 42 px; six KITTI frames from 10°: the initial, 47 cm off, matched by 1818 at "
        "2.6 px beat a coarse answer 15 cm off matched by 8829 at 3.2 px)",
    )
    coarse_gain: NonNegativeFloat | None = Field(
        None,
        description="after the choice by `coarse_margin`, a start whose first pass leaves the "
        "matcher more than 1 + this times the chosen start's correspondences, at a lower median "
        "residual, is taken instead (of several, the one matched by most). null: off. The "
        "vineyard's initial extrinsic 49 cm / 3.9° off kept at 1.96 px (9.6k matches) against "
        "the flow's answer 13 cm / 1.8° off at 1.59 px (16.4k): README, stop 69",
    )
    finest_focal_px: PositiveFloat | None = Field(
        None,
        description="working focal length (px) of the edge matcher's finest passes (null: "
        "`edge.working_focal_px`); `edge` itself stays the matcher of the other commands (maps, "
        "analyze, online). Above the camera's own focal length the image is used as it is",
    )
    pyramid_focals_px: tuple[PositiveFloat, ...] = Field(
        (90.0, 180.0),
        description="run the edge matcher's passes first at these coarser working focal lengths (px, "
        "coarse to fine; those from 90 % of the finest level's (`finest_focal_px`, or the camera's "
        "own where that is shorter) up are skipped; empty: none), each going on from the last, "
        "after the start (initial or coarse) is chosen by one pass at the finest level (or "
        "`probe_focal_px`): its windows and search range, in working pixels, span 4x the angles "
        "at 90 px. "
        "Six real KITTI frames, 20 draws each (README): from 2° / 10 cm 19 of 20 within 5 cm / 0.5° "
        "(13 without), median 2.50 cm against 4.15; from 10° / 50 cm 19 of 20 (18, one 36 cm off "
        "without); 16 s per calibration against 11",
    )
    probe_focal_px: PositiveFloat | None = Field(
        None,
        description="working focal length (px) of the one pass that chooses the start (initial or "
        "coarse) before the pyramid; null: the finest level's. Where the finest "
        "level is full resolution (721.5 px on KITTI) a probe at 360 px costs a quarter as much and "
        "still tells a wrong start from the right one",
    )
    probe_frames: int | None = Field(
        None,
        ge=1,
        description="the probe's pass runs on this many of the frames, spread evenly (null: all); "
        "the pyramid's levels go on from its choice on every frame. README (packaged: 4): the "
        "synthetic vineyard's 12 draws from 10° / 50 cm make the same choice of start in all 12 "
        "(11 within 2 cm / 0.2° either way); ten urban frames 0.78x the time (median of 8 draws)",
    )
    fine_intensity_weight: NonNegativeFloat | None = Field(
        None,
        description="`edge.intensity_weight` of the finest level's passes (null: the same), and of "
        "the pyramid levels from `fine_from_px` on; the probe and the coarser levels keep "
        "`edge.intensity_weight`. The intensity edges hold the basin at the coarse levels, and at "
        "the fine ones the stripes of the scan lines in them lean the roll (README: six KITTI frames "
        "at full resolution, +0.20° with 0.5 everywhere)",
    )
    fine_from_px: PositiveFloat | None = Field(
        None,
        description="the pyramid levels at or above this working focal length (px) use "
        "`fine_intensity_weight` too (null: the finest level alone)",
    )
    pyramid_min_frames: int = Field(
        2,
        ge=1,
        description="the pyramid runs only on at least this many frames: on one frame its coarse "
        "levels (KITTI's image 155x47 px at 90 px) hold too few edges and wander (README: single "
        "real frames from 2° / 10 cm, 4 draws each, KITTI object 000114 4 of 4 within 5 cm / 0.5° "
        "without it, 1 of 4 with it)",
    )
    few_frames_from_px: PositiveFloat | None = Field(
        None,
        description="on fewer than `pyramid_min_frames` frames, the pyramid levels at or above this "
        "working focal length (px) still run (null: none). Where the finest level is full "
        "resolution, one frame's passes then start at the half-resolution level, whose reach in "
        "angle is twice the finest's",
    )
    check_on: Literal["all", "common"] = Field(
        "all",
        description="the check's two median residuals: over all the points each matching keeps, or over "
        "the points both keep (a step also changes which points the matcher keeps, which moves the "
        "median by itself). README, stop 64: common takes six KITTI frames from 2° / 10 cm from 1.59 to "
        "2.09 cm (medians, 8 draws; from 10° / 50 cm one of 8 ends 26 cm off), synthetic urban and "
        "vineyard within their scatter: a switch",
    )
    check_tolerance: NonNegativeFloat = Field(
        0.0,
        description="a checked pass is undone only when the median residual after it passes the one "
        "before it by more than this share (0: any rise; README, stop 64: most undone passes raise it "
        "by 1-4 %, about the noise of two matchings' medians; 0.03 takes synthetic urban from 0.98 to "
        "0.81 cm and the vineyard from 0.60 cm / 0.084° to 0.51 cm / 0.078° from 10° / 50 cm, but six KITTI "
        "frames from 2° / 10 cm from 1.59 to 1.90 cm on draws 0-7 and 1.59 to 1.97 cm on fresh draws "
        "20-27, medians: a switch)",
    )
    settle_px: NonNegativeFloat = Field(
        0.0,
        description="a pass whose update moves the correspondences by less than this (median, pixels "
        "at the matcher's working focal length), with δt moved less than 0.1 ms, settles its level "
        "without the matching that would check it (that matching decides only whether so small a step "
        "stays; 0: every pass is checked). Packaged 0.1 since stop 67 (README, stops 64-67): the speed "
        "benchmark 14.6 -> 11.4 s (median, 0.78x), single real frames unchanged (70 of 72 runs "
        "identical), six KITTI frames and the time-offset rows within their own scatter, online urban "
        "1.79 -> 1.97 cm (one run), the synthetic vineyard's rotation 0.090 -> 0.120 deg (16 runs from "
        "10 deg / 50 cm), toward what its lasers' 0.12 deg angle errors support: on a LiDAR without "
        "them it ends as near or nearer, 0.81x the time",
    )
    check_below_px: float = Field(
        3.0,
        gt=0,
        description="a pass is checked only when the median residual before it is below this (pixels "
        "at the matcher's working focal length): farther out the residuals saturate at its reach",
    )
    halvings: int = Field(
        2, ge=0, description="how often a pass that did not help is halved before it is undone"
    )
    halve_above: tuple[NonNegativeFloat, NonNegativeFloat] = Field(
        (1.0, 0.05),
        description="(cm, °): a pass that did not help is halved only when its update passes either; "
        "a smaller one is undone at once and the passes stop (each halving costs a matching, and "
        "half of so small a step is within the matcher's noise). Six KITTI frames (5 draws) and "
        "synthetic urban (4) from 10° / 50 cm: 8 of 9 answers the same, one 1.24 -> 1.11 cm, 7 % "
        "less time",
    )
    check_gain: NonNegativeFloat | None = Field(
        None,
        description="a checked pass whose median residual rose is kept all the same where the matching "
        "after it keeps more than 1 + this times the matches of the one before (null: never). Where "
        "height trades for pitch (the vineyard from 10° / 50 cm) the way to the truth raises the "
        "median while it matches ever more points. Packaged 0.05 under `matched_below_px` 360 since stop 68 "
        "(README: the vineyard from 10° / 50 cm 13 -> 15 of 16 within 2 cm / 0.2°; six KITTI frames "
        "unchanged, where at every level it lost: 6 -> 4 of 8 from 2°)",
    )
    matched_below_px: PositiveFloat | None = Field(
        None,
        description="`check_gain` and `level_min_share` hold only where the edge matcher works under "
        "this focal length (px; the pyramid's coarse levels); null: everywhere. README, stop 68: "
        "check_gain at every level loses on six real KITTI frames, level_min_share at 360 px moves "
        "single nuScenes frames",
    )
    level_min_share: float = Field(
        0.0,
        ge=0,
        description="a pyramid level's answer is kept only when the matcher keeps at least this share "
        "of the correspondences it kept under the level's start; else the level is undone and the "
        "next goes on from its start (0: always kept). An aliased answer loses matched points. Packaged "
        "0.8 since stop 68 (README: the vineyard's aliased 90 px level keeps 0.64x its start's, the "
        "right ones 1.04-2.3x, six KITTI frames' 1.15-1.26x)",
    )
    pool_matchings: int = Field(
        1,
        ge=1,
        description="once settled, one fit more over the correspondences of the last this many "
        "matchings measured near the answer (pool_within): each pass's answer carries the noise of "
        "its one matching (six KITTI frames: 0.2-1.2 cm per pass), the pooled fit averages them "
        "without a matching more (1: the last pass's answer). Calibrator pools at its finest level "
        "alone (a coarser answer only starts the next level); an online window pools its own",
    )
    pool_within: tuple[NonNegativeFloat, NonNegativeFloat] = Field(
        (2.0, 0.2), description="(cm, °): a matching is pooled when its extrinsic lies this near the answer"
    )
    outliers: OutlierConfig = Field(OutlierConfig(), description="points, frames and matches left out")
    coarse: GlobalSearchConfig = Field(
        GlobalSearchConfig(), description="the global coarse stage before the dense passes (wide basin)"
    )
    contour: ContourRefineConfig = Field(
        ContourRefineConfig(), description="the contour refinement after the global coarse stage"
    )
    weak_std_cm: float = Field(1.0, gt=0, description="a translation direction with a larger std is weak")
    weak_std_deg: float = Field(0.1, gt=0, description="a rotation direction with a larger std is weak")
    online: OnlineConfig = OnlineConfig()
    time_offset: TimeOffsetConfig = Field(
        TimeOffsetConfig(), description="the camera-LiDAR time offset and motion compensation"
    )


@dataclass(frozen=True)
class ScanTiming:
    """What moves each frame's points to the camera's time (:mod:`calib.motion`); build it with
    :meth:`of`, which deskews once for every matching that follows.

    Attributes:
        motions: one :class:`~calib.motion.ScanMotion` per frame (from LiDAR odometry).
        stamp: each frame's points ``(N, 3)`` in the LiDAR frame at its stamp (deskewed).
        offset_s: ``δt`` to start from (or to hold). estimate: fit ``δt``.
        max_std_s: hold ``δt`` where its fitted standard deviation passes this.
        restarts_s: shifts of the settled ``δt`` to restart from (estimate only; how a restart
            is judged: ``restart_margin`` and ``restart_max_cm`` of :class:`TimeOffsetConfig`).
    """

    motions: Sequence[ScanMotion]
    stamp: Sequence[np.ndarray]
    offset_s: float = 0.0
    estimate: bool = True
    max_std_s: float = 0.002
    restarts_s: tuple[float, ...] = ()
    # the last few frames_at answers, with the frames they moved: every matching of a level
    # where δt is held asks for the same ones (a tenth of a second per ten full scans)
    _moved: list[tuple[float, Sequence[Frame], list[Frame]]] = field(
        default_factory=list, init=False, repr=False, compare=False
    )

    @classmethod
    def of(
        cls,
        frames: Sequence[Frame],
        motions: Sequence[ScanMotion],
        offset_s: float = 0.0,
        estimate: bool = True,
        max_std_s: float = 0.002,
        sweep: Callable[[np.ndarray], np.ndarray] | None = None,
        restarts_s: tuple[float, ...] = (),
    ) -> ScanTiming:
        """The timing of ``frames``: their points deskewed with each frame's per-point times,
        else with ``sweep(points)`` (times from the azimuth) where given, else as measured."""
        stamp = []
        for frame, motion in zip(frames, motions, strict=True):
            points = frame.points[:, :3].astype(np.float64)
            times = point_times(frame, sweep)
            stamp.append(points if times is None else motion.deskew(points, times))
        return cls(motions, stamp, offset_s, estimate, max_std_s, restarts_s if estimate else ())

    def of_frames(self, positions: Sequence[int]) -> ScanTiming:
        """The timing of the frames at ``positions`` alone (a subset of its frames)."""
        return replace(
            self, motions=[self.motions[i] for i in positions], stamp=[self.stamp[i] for i in positions]
        )

    def frames_at(self, frames: Sequence[Frame], offset_s: float) -> list[Frame]:
        """``frames`` as the camera saw them: their points moved ``offset_s`` after each stamp
        (the same list again for the same frames and offset)."""
        for offset, originals, moved in self._moved:
            if offset == offset_s and len(originals) == len(frames):
                if all(a is b for a, b in zip(originals, frames, strict=True)):
                    return moved
        moved = [
            replace(
                frame,
                points=np.column_stack([motion.at(q, offset_s), frame.points[:, 3:]]).astype(
                    frame.points.dtype
                ),
                point_times=None,
            )
            for frame, motion, q in zip(frames, self.motions, self.stamp, strict=True)
        ]
        self._moved[:] = [*self._moved[-(MOVED_KEPT - 1) :], (offset_s, list(frames), moved)]
        return moved


MOVED_KEPT = 2
"""How many answers of :meth:`ScanTiming.frames_at` each timing keeps."""


def sweep_model(config: TimeOffsetConfig) -> Callable[[np.ndarray], np.ndarray] | None:
    """Per-point times from each point's azimuth as ``config.sweep`` says
    (:func:`~calib.motion.sweep_times`), or ``None`` where only recorded times count."""
    if config.sweep == "recorded":
        return None
    return partial(
        sweep_times,
        period_s=config.sweep_period_s,
        clockwise=config.sweep == "clockwise",
        stamp_azimuth_deg=config.sweep_stamp_azimuth_deg,
    )


def point_times(frame: Frame, sweep: Callable[[np.ndarray], np.ndarray] | None) -> np.ndarray | None:
    """``(N,)`` the frame's per-point times from its stamp: recorded, else from ``sweep`` (its
    :func:`sweep_model`), else ``None`` (not deskewed)."""
    if frame.point_times is not None or sweep is None:
        return frame.point_times
    return sweep(frame.points[:, :3].astype(np.float64))


def scan_timing(
    frames: Sequence[Frame],
    motions: Sequence[ScanMotion],
    config: TimeOffsetConfig,
    offset_s: float,
    restarts: bool = True,
) -> tuple[ScanTiming, str]:
    """The :class:`ScanTiming` that ``config`` asks for, starting at ``offset_s`` (with
    ``restarts``: restarting at ``config.restarts_ms`` from where it settles), and ``""``; or,
    where ``δt`` is to be estimated but the frames' motion varies too little to tell it from a
    translation (:func:`~calib.motion.twist_spread` under both minimums), one that holds it, and
    a line saying why."""
    estimate, note = config.mode == "estimate", ""
    speed, turn = twist_spread(motions)
    if estimate and speed < config.min_speed_spread_mps and turn < config.min_turn_spread_radps:
        estimate = False
        note = (
            f"held at {offset_s:g} s: the frames' motion varies too little to tell it from a "
            f"translation (speed spread {speed:.2f} m/s, turn-rate spread {turn:.3f} rad/s; needs "
            f"{config.min_speed_spread_mps:g} or {config.min_turn_spread_radps:g})"
        )
    sweep = sweep_model(config)
    shifts = tuple(ms / 1e3 for ms in config.restarts_ms) if restarts else ()
    return ScanTiming.of(frames, motions, offset_s, estimate, config.max_std_s, sweep, shifts), note


@dataclass(frozen=True)
class PassesResult:
    """``T_cam_lidar (4, 4)`` and ``covariance (6, 6)`` (independent residuals) of the last
    accepted pass, with its ``cell_covariance`` where ``refine.covariance_cell_deg`` asks for the
    cluster-robust one (else ``None``); ``passes`` one
    dict per pass (iterations, cost, correspondences, matched, alignment, update, accepted);
    ``correspondences`` used in the last accepted pass; ``start`` which start the passes took
    (0: ``T_init``, then the alternatives) and ``probe_alignments_px`` the median residual after
    the first pass from each (empty without alternatives; None where the matcher found too few
    correspondences to fit); ``time_offset_s`` and ``time_offset_std_s`` with a
    :class:`ScanTiming` (the std ``None`` where ``δt`` was held); ``time_offset_restarts`` one
    dict per ``δt`` restart (its ``δt``; the median residual of the settled answer, after its
    first pass and, where that was better, after its passes; how far that moved the translation;
    taken); ``probe_correspondences`` how many correspondences the matching after each start's
    first pass found (0 where it could not fit; a start with fewer than ``coarse_min_share`` of
    the most is ruled out)."""

    T_cam_lidar: np.ndarray
    covariance: np.ndarray
    passes: list[dict]
    correspondences: int
    start: int = 0
    probe_alignments_px: list[float | None] = field(default_factory=list)
    time_offset_s: float | None = None
    time_offset_std_s: float | None = None
    time_offset_restarts: list[dict] = field(default_factory=list)
    probe_correspondences: list[int] = field(default_factory=list)
    cell_covariance: np.ndarray | None = None

    @property
    def matched(self) -> tuple[int, int]:
        """How many correspondences the matcher kept under the start the passes went on from and
        under their answer (where no matching followed the last accepted pass, settled or begun
        beyond the matcher's reach, the one it started from); ``(0, 0)`` without passes."""
        if not self.passes:
            return 0, 0
        last = self.passes[-1]
        answer = last.get("matched_after", last["matched"]) if last["accepted"] else last["matched"]
        return self.passes[0]["matched"], answer

    @property
    def reported_covariance(self) -> np.ndarray:
        """``(6, 6)`` what a calibration reports: the cluster-robust covariance where there is
        one, else the independent one."""
        return self.covariance if self.cell_covariance is None else self.cell_covariance


def draw(
    support: np.ndarray | None,
    n: int,
    config: SamplingConfig,
    rng: np.random.Generator,
    depth: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Indices and Eq. 4 weights of ``config.per_frame`` of ``n`` candidates: SGIS on their
    support values ``(n,)``, or uniform when ``support`` is ``None``; with
    ``config.depth_strata > 1`` SGIS within depth strata of ``depth (n,)`` (required then), each
    stratum's weights scaled to mean 1."""
    if support is None:
        index = uniform_sample(n, config.per_frame, rng)
        return index, np.ones(len(index))
    s = np.asarray(support, np.float64)
    if config.depth_strata == 1:
        index = support_sample(s, config.per_frame, rng, config.floor)
        return index, (s[index] + config.floor if config.weight_by_support else np.ones(len(index)))
    if depth is None:
        raise ValueError(f"sampling.depth_strata = {config.depth_strata} needs each candidate's depth")
    strata = depth_strata(depth, config.depth_strata)
    index = stratified_support_sample(s, strata, config.per_frame, rng, config.floor)
    if not config.weight_by_support:
        return index, np.ones(len(index))
    weight = s[index] + config.floor
    _, label, count = np.unique(strata[index], return_inverse=True, return_counts=True)
    return index, weight * count[label] / np.bincount(label, weights=weight)[label]


def _usable(corr: Correspondences, config: OutlierConfig) -> Correspondences:
    """``corr`` without the points nearer the LiDAR than ``config.min_range_m`` (ego-vehicle)."""
    return corr.subset(~near_points(corr.points_lidar, config.min_range_m))


def _along(T_from: np.ndarray, T_to: np.ndarray, fraction: float) -> np.ndarray:
    """``exp(fraction · log(T_to · T_from⁻¹)) · T_from``: that fraction of the way (on SE(3))."""
    twist = se3_log(torch.as_tensor(T_to @ np.linalg.inv(T_from)))
    return se3_exp(fraction * twist).numpy() @ T_from


def _median_norm(residual: np.ndarray) -> float:
    return float(np.median(np.linalg.norm(residual, axis=1))) if len(residual) else float("inf")


def _kept(matched: list[Correspondences]) -> int:
    """How many correspondences one matching of the frames kept."""
    return sum(len(c) for c in matched)


def _common_medians(before: list[Correspondences], after: list[Correspondences]) -> list[float]:
    """The median residual of two matchings of the same frames, each over the points both kept."""
    kept_before, kept_after = [], []
    for a, b in zip(before, after, strict=True):
        _, in_a, in_b = np.intersect1d(a.index, b.index, return_indices=True)
        kept_before.append(a.residual[in_a])
        kept_after.append(b.residual[in_b])
    return [_median_norm(np.concatenate(kept_before)), _median_norm(np.concatenate(kept_after))]


def refine_passes(
    frames: Sequence[Frame],
    T_init: np.ndarray,
    matcher: Matcher,
    support: SupportSource,
    config: CalibrateConfig,
    rng: np.random.Generator,
    alternatives: Sequence[np.ndarray] = (),
    timing: ScanTiming | None = None,
) -> PassesResult:
    """Refine ``T_init`` over ``frames`` (one shared ``K``, or the cameras of one rig: ``T_init``
    is then ``T_rig_lidar``) in up to ``config.passes`` passes.

    Each pass matches every frame under the current estimate, leaves out the frames whose median
    residual is an outlier among the frames, draws each frame's correspondences (SGIS or uniform),
    fits Eq. 4, drops the correspondences far off that fit and fits again. With
    ``config.check_passes`` the matching that starts the next pass (one extra round after the
    last) checks the pass: when the median residual the matcher measures under the new estimate
    is not below the one under the previous estimate, the estimate goes back half the pass's
    update and is checked again (``config.halvings`` times, a backtracking line search; a pass
    that moved less than ``config.halve_above`` is not halved), and after that the pass is undone
    and the passes stop.

    ``alternatives`` are other starts (``(4, 4)`` each, a coarse stage's answer). The first pass
    runs from each start, and the passes go on from the one whose first pass ends best aligned,
    an alternative only when clearly so (``config.coarse_margin``: ``T_init`` is a prior):
    far from the truth the matcher's residuals saturate at its search range, so the alignment of
    a start itself cannot tell two bad starts apart, but one pass brings a start inside the
    matcher's reach to a low median residual and leaves one outside it high. A start whose pass
    leaves the matcher fewer than ``config.coarse_min_share`` of the most correspondences any
    start's leaves is ruled out, the initial one too: far off, a few edges can line up by chance.
    With ``config.coarse_gain``, a start whose pass leaves the matcher more than ``1 +
    coarse_gain`` times the chosen one's correspondences, at a lower median, is taken instead.
    A start under which the matcher finds too few correspondences to fit is passed over (``None``
    in ``probe_alignments_px``); when every start is, the refinement raises.

    With ``timing`` every matching sees the points moved to the camera's time under the current
    ``δt``, and each fit estimates ``δt`` with the extrinsic from the first pass on (held where
    its standard deviation passes ``timing.max_std_s``: the frames' motion does not tell it from a
    translation). Holding it through the first pass was tried: the extrinsic then absorbs the
    offset (the vineyard's 20 ms in a turn is a 1.2° rotation) and ``δt`` stays near 1 ms. So,
    once settled, the passes restart from the settled extrinsic with ``δt`` moved by each of
    ``timing.restarts_s``: one pass each, the passes go on from a restart whose pass ends better
    aligned than the settled answer (``config.time_offset.restart_margin``), and its answer
    replaces the settled one where it ends better aligned still and its translation moved at
    most ``config.time_offset.restart_max_cm``. Starting the first pass
    at other ``δt`` instead was tried: from the initial error the moved start's first pass ends
    worse aligned even where it leads to the truth, and it is not taken.

    Raises:
        NumericalError: too few correspondences to fit (from every start, with alternatives).
    """
    K = frames[0].K
    rigs = rig_poses(frames)
    in_rig = frames[0].calibration.T_cam_rig is not None
    if not in_rig and any(not np.allclose(f.K, K) for f in frames):
        raise DataError("frames", "have different intrinsics and cannot share one refinement")
    # a rig's cameras each project through their own K and T_cam_rig; its pixel thresholds are
    # the first camera's
    Ks = np.stack([f.K for f in frames])
    rules = config.outliers
    # the check needs residuals the matcher can still measure: beyond its reach they saturate
    reach_px = config.check_below_px * K[0, 0] / min(K[0, 0], config.edge.working_focal_px)

    stamp = timing.stamp if timing is not None else None
    twists = None if timing is None else np.stack([np.stack([m.before, m.after]) for m in timing.motions])

    def at(dt: float | None) -> Sequence[Frame]:
        """The frames as the camera saw them ``dt`` after each stamp."""
        if timing is None:
            return frames
        return timing.frames_at(frames, dt)

    # the last matchings, for the pooled fit (a matching of ten full-resolution frames holds ~10 MB)
    matchings: deque[tuple[np.ndarray, float | None, list[Correspondences]]] = deque(
        maxlen=2 * config.pool_matchings + config.halvings if config.pool_matchings > 1 else 0
    )

    def matched_under(T: np.ndarray, dt: float | None) -> tuple[list[Correspondences], float]:
        matched = [_usable(corr, rules) for corr in match_frames(matcher, at(dt), T)]
        matchings.append((T, dt, matched))
        return matched, _median_norm(np.concatenate([c.residual for c in matched]))

    def fit(points, targets, weights, scans, T: np.ndarray, dt: float | None) -> Refinement:
        focal = Ks[scans, 0, 0] if in_rig else K[0, 0]
        clusters = image_cells(targets, scans, focal, config.refine.covariance_cell_deg)
        solve = partial(
            refine_extrinsic,
            points,
            targets,
            weights,
            Ks[scans] if in_rig else K,
            T,
            config.refine,
            clusters=clusters,
            T_cam_rig=rigs[scans] if in_rig else None,
        )
        if timing is None:
            return solve()
        result = solve(TimeModel(scans, twists, dt, timing.estimate))
        if result.time_offset_std_s is not None and result.time_offset_std_s > timing.max_std_s:
            result = solve(TimeModel(scans, twists, dt, False))
        return result

    working = min(1.0, config.edge.working_focal_px / K[0, 0])  # the matcher's pixels per frame pixel
    # the δt restarts compare with the median residual a descent ends at, and the pooled fit reads
    # the last matchings; without either, a matching that can neither check nor stop a pass is not made
    needs_alignment = (timing is not None and bool(timing.restarts_s)) or config.pool_matchings > 1

    bases: dict[int, list[Correspondences]] = {}  # check_on common: each pass's own matching
    gains = config.check_gain is not None and matched_rules_hold(config, config.edge.working_focal_px)

    def settles(entry: dict, dt_before: float | None, dt: float | None) -> bool:
        """Whether a pass settles its level unchecked (``config.settle_px``)."""
        moved_s = 0.0 if dt is None or dt_before is None else abs(dt - dt_before)
        return entry.get("update_px", math.inf) < config.settle_px and moved_s < SETTLE_TIME_S

    def one_pass(
        T: np.ndarray, dt: float | None, matched: list[Correspondences], alignment: float, pooled: int = 1
    ) -> tuple[Refinement, dict]:
        dropped = frame_outliers(
            np.array([_median_norm(c.residual) for c in matched]), rules.frame_factor, rules.frame_floor_px
        )
        points, targets, weights, scans = [], [], [], []
        sampling = config.sampling.model_copy(update={"per_frame": config.sampling.per_frame * pooled})
        for k, (frame, corr, drop) in enumerate(zip(frames, matched, dropped, strict=True)):
            if drop:
                continue
            support_map = support(frame)
            values = None if support_map is None else pixel_lookup(support_map, corr.uv)
            # depth strata's depth: the range, only where SGIS draws within strata
            ranges = np.linalg.norm(corr.points_lidar, axis=1) if sampling.depth_strata > 1 else None
            index, w = draw(values, len(corr), sampling, rng, ranges)
            # with a time model the solver moves the points itself, from their stamp's frame
            points.append(corr.points_lidar[index] if stamp is None else stamp[k][corr.index[index]])
            targets.append(corr.uv_matched[index])
            weights.append(w)
            scans.append(np.full(len(index), k))
        points, targets, weights, scans = (np.concatenate(x) for x in (points, targets, weights, scans))
        first = fit(points, targets, weights, scans, T, dt)
        keep = trim_points(np.linalg.norm(first.residuals, axis=1), rules.point_sigmas, rules.point_floor_px)
        result = fit(
            points[keep],
            targets[keep],
            weights[keep],
            scans[keep],
            first.T_cam_lidar,
            first.time_offset_s,
        )
        entry = {
            "iterations": first.iterations + result.iterations,
            "cost": result.cost,
            "correspondences": int(keep.sum()),
            "trimmed": int((~keep).sum()),
            "matched": _kept(matched),
            "frames_left_out": [int(i) for i in np.flatnonzero(dropped)],
            "alignment_px": alignment,
            "accepted": True,
            "step": 1.0,
            "update": calibration_error(result.T_cam_lidar, T).to_dict(),
        }
        if timing is not None:
            entry["time_offset_s"] = result.time_offset_s
            entry["time_offset_std_s"] = result.time_offset_std_s  # None: held (not observable)
        if config.settle_px > 0:
            entry["update_px"] = _update_px(frames, matched, T, result.T_cam_lidar, working)
        if config.check_on == "common":
            bases[id(entry)] = matched  # what the check compares the matching after it with
        return result, entry

    def descend(
        T: np.ndarray,
        dt: float | None,
        T_before: np.ndarray | None,
        dt_before: float | None,
        history: list[dict],
        fits: list[tuple[Refinement, int]],
        pending: tuple[list[Correspondences], float] | None,
        done: int,
    ) -> tuple[np.ndarray, float | None, float]:
        """Passes from ``T`` (``dt``; ``done`` of them already in ``history``, ``pending`` the
        matching after the last) until settled, ``config.passes`` of them, or one that does not
        lower the matcher's median residual; ``history`` and ``fits`` grow in place. Returns
        the estimate and the median residual under it (NaN where nothing needs it and no
        matching followed the last pass)."""
        alignment, limit = math.nan, len(history) - done + config.passes
        while not (len(history) >= limit and not config.check_passes):
            if pending is None and len(history) >= limit and not needs_alignment:
                if not history[-1]["alignment_px"] < reach_px:
                    break  # the last pass started beyond the matcher's reach: no matching checks it
            matched, alignment = pending if pending is not None else matched_under(T, dt)
            pending = None
            if history:  # this matching checks the last pass
                last = history[-1]
                last["alignment_after_px"] = alignment
                last["matched_after"] = _kept(matched)
                checked = config.check_passes and last["alignment_px"] < reach_px
                allowed = 1.0 + config.check_tolerance
                worse = not alignment < last["alignment_px"] * allowed
                if gains:  # more points matched: the step found structure
                    worse = worse and not last["matched_after"] > (1.0 + config.check_gain) * last["matched"]
                if checked and config.check_on == "common":
                    last["common_px"] = _common_medians(bases[id(last)], matched)
                    worse = not last["common_px"][1] < last["common_px"][0] * allowed
                if checked and worse:
                    cm, deg = config.halve_above
                    worth = last["step"] < 1 or (
                        last["update"]["translation_cm"] > cm or last["update"]["rotation_deg"] > deg
                    )
                    if worth and last["step"] > 0.5**config.halvings:  # back along the update, half way
                        last["step"] /= 2
                        T = _along(T_before, T, 0.5)
                        dt = None if dt is None else (dt + dt_before) / 2
                        last["update"] = calibration_error(T, T_before).to_dict()
                        continue
                    last["accepted"] = False
                    T, dt, alignment = T_before, dt_before, last["alignment_px"]
                    break
                update = last["update"]
                if (
                    update["translation_cm"] < config.min_update_cm
                    and update["rotation_deg"] < config.min_update_deg
                ):
                    break  # settled: the estimate hardly moved
            if len(history) >= limit:
                break
            result, entry = one_pass(T, dt, matched, alignment)
            history.append(entry)
            fits.append((result, entry["correspondences"]))
            T_before, T, dt_before, dt = T, result.T_cam_lidar, dt, result.time_offset_s
            if settles(entry, dt_before, dt):
                entry["settled"] = True  # accepted unchecked: too small a step for a matching to judge
                break
        # not matched after the last pass: match now where the δt restarts or the pooled fit read it
        unchecked = history and history[-1]["accepted"] and "alignment_after_px" not in history[-1]
        if needs_alignment and (math.isnan(alignment) or unchecked):
            alignment = matched_under(T, dt)[1]
        return T, dt, alignment

    dt = dt_start = None if timing is None else timing.offset_s
    starts = [np.asarray(T, np.float64) for T in (T_init, *alternatives)]
    T, T_before, history, fits, pending, chosen, probes = starts[0], None, [], [], None, 0, []
    counts = np.zeros(0, int)
    if len(starts) > 1:
        for k, T_start in enumerate(starts):
            try:
                result, entry = one_pass(T_start, dt, *matched_under(T_start, dt))
            except NumericalError:  # a start where the matcher finds (almost) nothing
                if k == len(starts) - 1 and all(probe[1] is None for probe in probes):
                    raise
                probes.append((T_start, None, None, (None, math.inf)))
                continue
            probes.append((T_start, result, entry, matched_under(result.T_cam_lidar, result.time_offset_s)))
        after = np.array([probe[3][1] for probe in probes])
        # a start matched by few points can show a low median by luck (an aliased pose, or the
        # initial extrinsic far off with a few edges lined up): every start, the initial too, must
        # keep `coarse_min_share` of the most correspondences any start's first pass leaves
        counts = np.array([_kept(probe[3][0]) if probe[1] is not None else 0 for probe in probes])
        after = np.where(counts < config.coarse_min_share * counts.max(), math.inf, after)
        best = int(np.argmin(after[1:])) + 1
        # the initial extrinsic (the user's, or Stage 1's) is a prior: another start must end its
        # first pass clearly better aligned (median residual at most `coarse_margin` times the
        # initial's; inf where the initial failed or was ruled out above)
        chosen = best if after[best] <= config.coarse_margin * after[0] else 0
        if config.coarse_gain is not None:
            # a start matched by clearly more points and ending better aligned: an aliased or far
            # start matches fewer (the vineyard's rows), the truth's neighbourhood gains them
            gaining = np.flatnonzero(
                (counts > (1 + config.coarse_gain) * counts[chosen]) & (after < after[chosen])
            )
            chosen = int(gaining[np.argmax(counts[gaining])]) if gaining.size else chosen
        T_before, result, entry, pending = probes[chosen]
        T, history, fits = result.T_cam_lidar, [entry], [(result, entry["correspondences"])]
        dt = result.time_offset_s
    T, dt, alignment = descend(T, dt, T_before, dt_start, history, fits, pending, len(history))
    restarts = []
    judge = config.time_offset  # how a restart is taken
    for shift in timing.restarts_s if timing is not None else ():
        # settled, perhaps where the extrinsic absorbed the offset: one pass from δt + shift
        # under the settled extrinsic, and the passes go on from there where it ends better aligned
        probe = {"time_offset_from_s": dt + shift, "alignment_before_px": alignment}
        try:
            result, entry = one_pass(T, dt + shift, *matched_under(T, dt + shift))
        except NumericalError:
            restarts.append({**probe, "alignment_after_first_pass_px": None, "taken": False})
            continue
        probe_matched = matched_under(result.T_cam_lidar, result.time_offset_s)
        probe["alignment_after_first_pass_px"] = probe_matched[1]
        if not probe_matched[1] <= judge.restart_margin * alignment:
            restarts.append({**probe, "taken": False})
            continue
        entry["restart"] = True
        tried, tried_fits = [*history, entry], [*fits, (result, entry["correspondences"])]
        T_new, dt_new, alignment_new = descend(
            result.T_cam_lidar, result.time_offset_s, T, dt + shift, tried, tried_fits, probe_matched, 1
        )
        moved_cm = calibration_error(T_new, T).translation_cm
        taken = alignment_new < alignment and moved_cm <= judge.restart_max_cm
        restarts.append({**probe, "alignment_px": alignment_new, "moved_cm": moved_cm, "taken": taken})
        if taken:
            T, dt, alignment, history, fits = T_new, dt_new, alignment_new, tried, tried_fits
    if config.pool_matchings > 1:
        T, dt = _pooled_fit(T, dt, matchings, history, fits, one_pass, config)
    accepted = [fit for fit, step in zip(fits, history, strict=True) if step["accepted"]] or fits
    last, correspondences = accepted[-1]
    return PassesResult(
        T,
        last.covariance,
        history,
        correspondences,
        chosen,
        [a if math.isfinite(a) else None for *_, (_, a) in probes],
        dt,
        last.time_offset_std_s,
        restarts,
        [int(n) for n in counts],
        last.cell_covariance,
    )


def matched_rules_hold(config: CalibrateConfig, focal: float) -> bool:
    """Whether ``check_gain`` and ``level_min_share`` hold at a level whose edge matcher works at
    ``focal`` px: under ``config.matched_below_px`` (everywhere where that is unset)."""
    return config.matched_below_px is None or focal < config.matched_below_px


SETTLE_TIME_S = 1e-4
"""``settle_px``: a pass settles its level only where it moved δt less than this too."""


def _update_px(
    frames: Sequence[Frame],
    matched: list[Correspondences],
    T_before: np.ndarray,
    T_after: np.ndarray,
    scale: float,
) -> float:
    """The median image motion (pixels of each frame's camera, times ``scale``) of a pass from
    ``T_before`` to ``T_after (4, 4)``, over (at most about 5000 of) the matched points it was
    fitted to."""
    points = np.concatenate([c.points_lidar for c in matched])
    which = np.concatenate([np.full(len(c), k) for k, c in enumerate(matched)])
    step = max(1, len(points) // 5000)
    points, which = points[::step], which[::step]
    motion = np.empty(len(points))
    for k, frame in enumerate(frames):
        mine = which == k
        uv = []
        for T in (T_before, T_after):
            T = frame.calibration.camera_extrinsic(T)
            uvw = (points[mine] @ T[:3, :3].T + T[:3, 3]) @ frame.K.T
            uv.append(uvw[:, :2] / np.maximum(uvw[:, 2:], 1e-9))
        motion[mine] = np.linalg.norm(uv[1] - uv[0], axis=1)
    return float(np.median(motion) * scale) if len(points) else math.inf


def _pooled_fit(
    T: np.ndarray,
    dt: float | None,
    matchings: Sequence[tuple[np.ndarray, float | None, list[Correspondences]]],
    history: list[dict],
    fits: list[tuple[Refinement, int]],
    one_pass: Callable[..., tuple[Refinement, dict]],
    config: CalibrateConfig,
) -> tuple[np.ndarray, float | None]:
    """One pass more from the answer ``T`` over each frame's correspondences of the last
    ``config.pool_matchings`` matchings measured within ``config.pool_within`` of it (and of its
    ``δt`` within a millisecond), drawn ``per_frame`` times as many; ``history`` and ``fits`` gain
    it. A correspondence is a LiDAR point and the image location the matcher found for it, whatever
    extrinsic it was measured under, so matchings near the answer pool; each pass's answer carries
    the noise of its one matching, and the pooled fit averages them; its independent covariance
    is reported as one matching's (the cluster-robust one already counts errors its image cells
    share). Returns ``T, dt`` unchanged where fewer than two matchings are near."""
    cm, deg = config.pool_within
    near = [
        matched
        for T_m, dt_m, matched in matchings
        if (error := calibration_error(T_m, T)).translation_cm <= cm
        and error.rotation_deg <= deg
        and (dt is None or dt_m is None or abs(dt_m - dt) <= 1e-3)
    ][-config.pool_matchings :]
    if len(near) < 2:
        return T, dt
    merged = [Correspondences.concatenate(parts) for parts in zip(*near, strict=True)]
    alignment = _median_norm(np.concatenate([c.residual for c in near[-1]]))
    result, entry = one_pass(T, dt, merged, alignment, pooled=len(near))
    # its correspondences are not len(near) times the evidence (the matchings share the image
    # and the scan): its uncertainty stays one matching's
    std = result.time_offset_std_s
    result = replace(
        result,
        covariance=result.covariance * len(near),
        time_offset_std_s=None if std is None else std * math.sqrt(len(near)),
    )
    history.append({**entry, "pooled_matchings": len(near)})
    fits.append((result, entry["correspondences"]))
    return result.T_cam_lidar, result.time_offset_s


def image_cells(
    uv: np.ndarray, frame: np.ndarray, focal_px: float | np.ndarray, cell_deg: float
) -> np.ndarray | None:
    """``(N,)`` an id per image cell of ``cell_deg`` (view angle at the focal length
    ``focal_px``, one or ``(N,)`` each pixel's camera's) per frame for pixels ``uv (N, 2)`` of
    frames ``frame (N,)``; ``None`` where ``cell_deg`` is 0."""
    if cell_deg <= 0:
        return None
    cell_px = np.asarray(focal_px, np.float64).reshape(-1, 1) * math.tan(math.radians(cell_deg))
    cells = np.column_stack([frame, np.floor(uv / cell_px)]).astype(np.int64)
    if len(cells) == 0:  # no correspondences: no cells
        return np.zeros(0, np.int64)
    cells -= cells.min(axis=0)
    # one integer per (frame, row, column) within the data's own extent: a flat unique is about
    # ten times faster than a unique over rows, and numbers the cells in the same order
    flat = np.ravel_multi_index(cells.T, cells.max(axis=0) + 1)
    return np.unique(flat, return_inverse=True)[1].reshape(-1)


def load_calibrate_config(path: Path | None = None) -> CalibrateConfig:
    """``path`` (default: the packaged ``calibrate.yaml``), validated."""
    return load_config(CalibrateConfig, path, "calibrate.yaml")
