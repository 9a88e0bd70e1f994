"""Stage 1: the initial extrinsic from motion (MDPCalib-style), a thin orchestrator.

LiDAR odometry (KISS-ICP) → visual odometry (OpenCV, up to scale) → LiDAR poses interpolated at
the camera keyframes' time stamps → scaled hand–eye calibration with robust refinement and an
observability report.

Like MDPCalib, Stage 1 keeps the hand–eye rotation and, by default, not its translation: with a
monocular camera each motion gives only a direction, and on a ground robot most motions hardly
rotate, so ``(R_A − I) t_X`` is small and a bias of a degree in the visual directions (measured on
our synthetic worlds, against ground truth) moves ``t_X`` by metres. The translation comes from a
prior instead (the lever arm measured on the robot, zero by default) and Stage 4 refines it; the
hand–eye translation and its error stay in the report (``translation: motion`` uses it).

Before returning, the degeneracy tests (:mod:`calib.init.degeneracy`: spread of the rotation axes,
conditioning of the hand–eye rotation, agreement of random halves) decide whether the motion
determined the rotation; when it did not, Stage 1 refuses (:class:`DegenerateMotionError`) rather
than return a rotation tens of degrees off with a warning.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from calib.data.types import Sequence
from calib.init.degeneracy import DegeneracyConfig, MotionDiagnostics, check_motion, diagnose
from calib.init.hand_eye import HandEyeConfig, HandEyeResult, UnobservableError, hand_eye
from calib.init.lidar_odometry import lidar_odometry, sensor_range
from calib.init.time_sync import StampOffset, interpolate_poses, stamp_offset
from calib.init.visual_odometry import CameraMotion, VisualOdometryConfig, visual_odometry
from calib.yaml_io import load_config

__all__ = ["LidarOdometryConfig", "Stage1Config", "Stage1Result", "initial_calibration"]


class LidarOdometryConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    max_range_m: float | None = Field(
        None, gt=0, description="None: from the data, the 99.5th percentile range of the first scans"
    )
    min_range_m: float = Field(2.0, ge=0)
    voxel_size_m: float | None = Field(None, gt=0, description="None: KISS-ICP's default, max_range / 100")
    deskew: bool = Field(True, description="deskew with per-point times where the data has them")


class Stage1Config(BaseModel):
    """``configs/init_calib.yaml``."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    lidar: LidarOdometryConfig = LidarOdometryConfig()
    visual: VisualOdometryConfig = VisualOdometryConfig()
    max_sync_gap_s: float = Field(
        0.15, gt=0, description="LiDAR poses farther apart are not interpolated across"
    )
    hand_eye: HandEyeConfig = HandEyeConfig()
    degeneracy: DegeneracyConfig = DegeneracyConfig()
    translation: Literal["prior", "motion"] = Field(
        "prior", description="where the extrinsic's translation comes from (see the module docstring)"
    )
    translation_prior_m: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0),
        description="t of T_cam_lidar: the LiDAR origin in camera axes (x right, y down, z forward)",
    )


MAX_SEED_STD_S = 0.02
"""Stage 1's δt seeds Stage 4 only where its std is at most this: Stage 4 comes back from about
20 ms (README, "Time offset and deskewing": the table over offsets)."""


@dataclass(frozen=True)
class Stage1Result:
    """What Stage 1 found, with what it used.

    Attributes:
        T_cam_lidar: ``(4, 4)`` Stage 1's extrinsic: the hand–eye rotation, the translation from
            ``translation_source``.
        translation_source: ``prior`` or ``motion``.
        calibration: the hand–eye result (its own extrinsic, covariance, weak directions).
        lidar_poses: ``(F, 4, 4)`` ``T_lidar0_lidar`` at the LiDAR stamps.
        lidar_times, camera_times: ``(F,)`` seconds.
        motions: the camera keyframe motions (unit translations).
        lidar_motions: ``(M, 4, 4)`` the synchronised LiDAR motions, one per kept camera motion.
        kept: ``(len(motions),)`` bool, motions whose stamps could be synchronised.
        diagnostics: the degeneracy tests' numbers (all passed, or ``degeneracy.refuse`` is off).
        seconds: wall time per step.
        notes: facts a user should know (stamps assumed, planar motion).
        stamp_offset: the lag of the camera's stamps behind the LiDAR's clock from the two
            streams' rotation angles (:func:`~calib.init.time_sync.stamp_offset`), or ``None``.
    """

    T_cam_lidar: np.ndarray
    translation_source: str
    calibration: HandEyeResult
    lidar_poses: np.ndarray
    lidar_times: np.ndarray
    camera_times: np.ndarray
    motions: list[CameraMotion]
    lidar_motions: np.ndarray
    kept: np.ndarray
    diagnostics: MotionDiagnostics
    seconds: dict[str, float]
    notes: list[str]
    stamp_offset: StampOffset | None = None

    @property
    def time_offset_s(self) -> float | None:
        """Stage 4's ``δt`` (camera exposure minus LiDAR stamp) as Stage 1 sees it: the stamps'
        median difference less the camera stamps' lag; ``None`` where the lag is not determined to
        :data:`MAX_SEED_STD_S` (a seed farther off than Stage 4 can come back from)."""
        if self.stamp_offset is None or not self.stamp_offset.std_s <= MAX_SEED_STD_S:
            return None
        return float(np.median(self.camera_times - self.lidar_times) - self.stamp_offset.offset_s)


def initial_calibration(
    seq: Sequence, config: Stage1Config = Stage1Config(), progress: Callable[[str], None] | None = None
) -> Stage1Result:
    """``T_cam_lidar`` of ``seq`` from its motion alone (no reference used).

    Raises:
        UnobservableError: the motion cannot determine the extrinsic (the message says why);
            :class:`DegenerateMotionError` (a kind of it) when a degeneracy test failed.
    """
    say = progress or (lambda _: None)
    notes: list[str] = []
    seconds: dict[str, float] = {}
    frames = [seq[i] for i in range(len(seq))]
    camera_times = np.asarray(seq.timestamps, np.float64)  # the reader's, 10 Hz where it has none
    lidar_times = np.array(
        [
            f.lidar_timestamp if f.lidar_timestamp is not None else camera_times[i]
            for i, f in enumerate(frames)
        ]
    )
    if all(f.lidar_timestamp is None for f in frames):
        notes.append("the data has no separate LiDAR stamps: scans taken at the camera stamps")

    say("LiDAR odometry (KISS-ICP)")
    start = time.perf_counter()
    deskew = config.lidar.deskew and all(f.point_times is not None for f in frames)
    max_range = config.lidar.max_range_m or sensor_range([f.points for f in frames[:10]])
    lidar_poses = lidar_odometry(
        (f.points for f in frames),
        (f.point_times for f in frames) if deskew else None,
        max_range,
        config.lidar.min_range_m,
        config.lidar.voxel_size_m,
    )
    seconds["lidar_odometry"] = time.perf_counter() - start
    pose_times = lidar_times  # when each pose holds: KISS-ICP deskews a scan to its last point's time
    if deskew:
        pose_times = lidar_times + np.array([float(np.max(f.point_times)) for f in frames])

    say("visual odometry (OpenCV)")
    start = time.perf_counter()
    motions = visual_odometry((f.image for f in frames), seq.calibration.K, config.visual)
    seconds["visual_odometry"] = time.perf_counter() - start
    if not motions:
        raise UnobservableError(f"{seq.name}: visual odometry found no keyframe pair with enough parallax")

    say("time sync and hand–eye")
    start = time.perf_counter()
    ends = np.array([[camera_times[m.i], camera_times[m.j]] for m in motions])
    at_camera, valid = interpolate_poses(pose_times, lidar_poses, ends.ravel(), config.max_sync_gap_s)
    at_camera, kept = at_camera.reshape(-1, 2, 4, 4), valid.reshape(-1, 2).all(axis=1)
    try:  # the clocks' offset from the rotation angles alone, before any extrinsic
        lag = stamp_offset(
            pose_times,
            lidar_poses,
            ends,
            np.stack([m.T[:3, :3] for m in motions]),
            max_gap_s=config.max_sync_gap_s,
        )
    except ValueError as error:
        lag = None
        notes.append(f"no time offset from the motion: {error}")
    if kept.sum() < 3:
        period = float(np.median(np.diff(pose_times))) if len(pose_times) > 1 else float("nan")
        raise UnobservableError(
            f"{seq.name}: only {int(kept.sum())} camera motions lie between LiDAR scans at most "
            f"{config.max_sync_gap_s:g} s apart (the scans come every {period:.3g} s): raise "
            "max_sync_gap_s to about 1.5 scan periods, or give every scan"
        )
    A = np.stack([m.T for m, k in zip(motions, kept, strict=True) if k])
    B = np.linalg.inv(at_camera[kept, 1]) @ at_camera[kept, 0]  # T_lidar_j_lidar_i
    calibration = hand_eye(A, B, config.hand_eye)
    seconds["hand_eye"] = time.perf_counter() - start

    say("degeneracy tests")
    start = time.perf_counter()
    diagnostics = diagnose(A, B, calibration, config.hand_eye, config.degeneracy)
    seconds["degeneracy"] = time.perf_counter() - start
    check_motion(diagnostics, config.degeneracy, seq.name)
    if diagnostics.failed:  # refuse is off: the caller asked for the answer anyway
        notes += [f"degeneracy test failed (degeneracy.refuse is off): {f}" for f in diagnostics.failed]
    T_cam_lidar = calibration.T_cam_lidar.copy()
    if config.translation == "prior":
        T_cam_lidar[:3, 3] = config.translation_prior_m
        notes.append(
            "translation from the prior (translation_prior_m), not from the monocular hand–eye solve: "
            "Stage 4 refines it"
        )
    return Stage1Result(
        T_cam_lidar=T_cam_lidar,
        translation_source=config.translation,
        calibration=calibration,
        lidar_poses=lidar_poses,
        lidar_times=lidar_times,
        camera_times=camera_times,
        motions=motions,
        lidar_motions=B,
        kept=kept,
        diagnostics=diagnostics,
        seconds=seconds,
        notes=notes + calibration.notes,
        stamp_offset=lag,
    )


def load_stage1_config(path: Path | None = None) -> Stage1Config:
    """``path`` (default: the packaged ``init_calib.yaml``), validated."""
    return load_config(Stage1Config, path, "init_calib.yaml")
