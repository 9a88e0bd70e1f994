"""Generate a synthetic sequence: build the world, drive through it, let both sensors sample it
at their own time stamps, and write the KITTI odometry layout with every ground truth."""

from __future__ import annotations

import json
import math
import multiprocessing
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from calib.data.classes import RIGID_CLASSES
from calib.data.kitti_odometry import KittiOdometryWriter
from calib.data.types import Calibration, Frame
from calib.errors import ConfigError
from calib.geometry import perturb, random_perturbation, se3_exp, se3_log
from calib.seeds import check_seed
from calib.synth.raycast import Raycaster
from calib.synth.render import Camera, Lidar
from calib.synth.synth_config import ExtrinsicConfig, SynthConfig
from calib.synth.urban import build_urban
from calib.synth.vineyard import build_vineyard
from calib.synth.world import World

__all__ = ["SyntheticFrame", "Synthesizer", "reference_extrinsic", "write_sequence"]

EFFECTS_STREAM = 1
"""Third seed word of each frame's camera-effects generator (the frame's own is ``[seed, i]``)."""
MAX_FRAMES = 100_000
"""At most this many frames (about 3 h at 10 Hz): the world grows with the distance driven."""
MAX_DRIFT = (100.0, 45.0)
"""The largest drift (cm, °) by the last frame: beyond that a mount has fallen off, not drifted."""


def reference_extrinsic(config: ExtrinsicConfig, rng: np.random.Generator) -> np.ndarray:
    """The sequence's ground-truth ``T_cam_lidar``: the nominal mounting (camera looking along the
    LiDAR's x axis, tilted down by ``camera_pitch_deg``) composed with a seeded deviation of
    ``jitter_cm`` · U(0.5, 1) in a random direction and ``jitter_deg`` · U(0.5, 1) about a random
    axis (its calibration error against the nominal), so no two sequences share an extrinsic."""
    pitch = np.radians(config.camera_pitch_deg)
    z_cam = np.array([np.cos(pitch), 0.0, -np.sin(pitch)])  # optical axis, in the LiDAR frame
    x_cam = np.array([0.0, -1.0, 0.0])
    T_lidar_cam = np.eye(4)
    T_lidar_cam[:3, :3] = np.column_stack([x_cam, np.cross(z_cam, x_cam), z_cam])
    T_lidar_cam[:3, 3] = config.camera_position_m
    generator = torch.Generator().manual_seed(int(rng.integers(2**31)))
    size = rng.uniform(0.5, 1.0, 2)
    return perturb(
        np.linalg.inv(T_lidar_cam), config.jitter_cm * size[0], config.jitter_deg * size[1], generator
    )


@dataclass(frozen=True)
class SyntheticFrame:
    """One frame with its ground truth beyond what :class:`Frame` holds."""

    frame: Frame
    instances: np.ndarray
    T_world_lidar: np.ndarray


class Synthesizer:
    """A world and its sensors for one seed; :meth:`frames` renders them one by one.

    Args:
        config: the validated configuration.
        frames: how many frames (sets how far the vehicle drives, hence the world's size).
        seed: every random choice follows from it; the same seed gives the same bytes. An
            integer in [0, 2³²); distinct seeds give distinct worlds.
        drift: ``(cm, °)`` the extrinsic has drifted by the last frame, each in [0, MAX_DRIFT].

    Raises:
        ConfigError: ``frames``, ``seed`` or ``drift`` out of range (NaN and infinity included).
    """

    def __init__(self, config: SynthConfig, frames: int, seed: int, drift: tuple[float, float] = (0.0, 0.0)):
        if not 1 <= frames <= MAX_FRAMES:
            raise ConfigError("frames", f"must be from 1 to {MAX_FRAMES}, got {frames}")
        seed = check_seed(seed)
        if len(drift) != 2 or not all(
            math.isfinite(v) and 0 <= v <= limit for v, limit in zip(drift, MAX_DRIFT, strict=False)
        ):
            raise ConfigError(
                "drift",
                f"must be two sizes, 0 to {MAX_DRIFT[0]:g} cm and 0 to {MAX_DRIFT[1]:g}°, got {tuple(drift)}",
            )
        self.config, self.n_frames, self.seed = config, frames, seed
        rng = np.random.default_rng(seed)
        self.T_cam_lidar = reference_extrinsic(config.extrinsic, rng)
        # the mount drifts linearly in se(3) from the reference to ``drift`` (cm, °) at the last frame,
        # along a direction of its own seed (the world and the reference stay those of ``seed``)
        self.drift = tuple(float(v) for v in drift)
        delta = random_perturbation(*self.drift, generator=torch.Generator().manual_seed(seed + 7919))
        self._drift_twist = se3_log(delta)
        travel = frames / config.timing.rate_hz * config.drive.speed_mps
        build = build_vineyard if config.world == "vineyard" else build_urban
        self.world: World = build(config, travel, rng)
        self.calibration = Calibration(
            K=config.camera.K,
            T_cam_lidar=self.T_cam_lidar,
            image_size=(config.camera.height, config.camera.width),
            source=f"synthetic {config.world} seed {seed}",
        )
        self._static: Raycaster | None = None
        self.camera = Camera(config.camera, config.light, config.camera_effects, seed)
        self.lidar = Lidar(config.lidar, config.timing.lidar_period_s, seed)

    @property
    def static(self) -> Raycaster:
        """The static scene, built on first use (in each worker process, not before forking)."""
        if self._static is None:
            self._static = Raycaster([self.world.static])
        return self._static

    def extrinsic(self, i: int) -> np.ndarray:
        """The true ``T_cam_lidar`` at frame ``i``: the reference, moved by the drift so far."""
        fraction = i / max(self.n_frames - 1, 1)
        return self.T_cam_lidar @ se3_exp(fraction * self._drift_twist).numpy()

    def camera_offset(self, i: int) -> float:
        """Frame ``i``'s camera stamp minus LiDAR stamp: the configured offset, moved by the clock's
        drift so far (linearly, to ``camera_offset_drift_s`` at the last frame)."""
        timing = self.config.timing
        return timing.camera_offset_s + i / max(self.n_frames - 1, 1) * timing.camera_offset_drift_s

    def lidar_poses(self) -> np.ndarray:
        """``(frames, 4, 4)`` ground-truth ``T_world_lidar`` at each scan's stamp."""
        return self.world.drive.lidar_poses(np.arange(self.n_frames) / self.config.timing.rate_hz)

    def render(self, i: int) -> SyntheticFrame:
        """Frame ``i``: the LiDAR sweeps at ``t_L = i / rate``, the camera exposes at
        ``t_L + camera_offset_s``; moving leaves and cars are where they are at each time."""
        timing, wind = self.config.timing, self.config.wind
        rng = np.random.default_rng([self.seed, i])
        t_lidar = i / timing.rate_hz
        t_cam = t_lidar + self.camera_offset(i)
        drive = self.world.drive
        T_world_cam = drive.lidar_poses(np.array([t_cam]))[0] @ np.linalg.inv(self.extrinsic(i))
        image, image_labels = self.camera.render(
            self.static.plus(self.world.dynamic(t_cam, wind)),
            T_world_cam,
            rng,
            np.random.default_rng([self.seed, i, EFFECTS_STREAM]),
        )
        T_stamp = drive.lidar_poses(np.array([t_lidar]))[0]
        # With motion distortion each azimuth column is cast from the pose at its own time
        T_beams = (
            drive.lidar_poses(t_lidar + self.lidar.times[: self.lidar.azimuth_steps])
            if timing.motion_distortion
            else T_stamp
        )
        scan = self.lidar.scan(self.static.plus(self.world.dynamic(t_lidar, wind)), T_beams, rng)
        frame = Frame(
            image=image,
            points=scan.points,
            calibration=self.calibration,
            index=i,
            name=f"{i:06d}",
            timestamp=t_cam,
            lidar_timestamp=t_lidar,
            labels=scan.labels,
            image_labels=image_labels,
            point_times=scan.times if timing.motion_distortion else None,
        )
        return SyntheticFrame(frame, scan.instance, T_stamp)

    def frames(self, workers: int = 1, indices: range | None = None) -> Iterator[SyntheticFrame]:
        """Every frame (or those of ``indices``) in order; ``workers > 1`` renders them in that
        many forked processes (frames depend only on the seed and their index, so the bytes do
        not change)."""
        indices = range(self.n_frames) if indices is None else indices
        if workers <= 1 or len(indices) < 2:
            yield from map(self.render, indices)
            return
        global _WORKER_SYNTH
        _WORKER_SYNTH = self
        with multiprocessing.get_context("fork").Pool(workers, initializer=_quiet_worker) as pool:
            yield from pool.imap(_render_in_worker, indices, chunksize=2)

    def meta(self) -> dict:
        """What ``meta.json`` records: world, seed, sensors, ground truth, offsets."""
        c = self.config
        return {
            "world": c.world,
            "seed": self.seed,
            "frames": self.n_frames,
            "T_cam_lidar": self.T_cam_lidar.tolist(),
            "drift_cm_deg": list(self.drift),
            **(
                {"true_T_cam_lidar": [self.extrinsic(i)[:3].ravel().tolist() for i in range(self.n_frames)]}
                if any(self.drift)
                else {}
            ),
            "K": c.camera.K.tolist(),
            "image_size": [c.camera.height, c.camera.width],
            "camera_offset_s": c.timing.camera_offset_s,
            **(
                {"camera_offsets_s": [self.camera_offset(i) for i in range(self.n_frames)]}
                if c.timing.camera_offset_drift_s
                else {}
            ),
            "wind": c.wind.model_dump(),
            "timing": c.timing.model_dump(),
            "config": c.model_dump(mode="json"),
            "classes": {str(k): v for k, v in sorted(self.world.classes.items())},
            "rigid_classes": sorted(RIGID_CLASSES & set(self.world.classes)),
            "conventions": {
                "times.txt": "camera exposure times; each scan's stamp is in times_lidar.txt (the "
                "exposure minus the frame's camera offset, camera_offset_s plus its drift)",
                "poses": "poses/NN.txt holds camera-0 poses at the LiDAR stamps (KITTI convention); "
                "T_world_lidar = inv(Tr) @ pose @ Tr",
                "point_times": "seconds from the scan stamp, 0 where the beam points forward",
                "true_T_cam_lidar": "with drift: each frame's true extrinsic (12 numbers, rows of "
                "[R | t]); calib.txt holds the reference, the drift's start",
            },
        }


_WORKER_SYNTH: Synthesizer | None = None


def _render_in_worker(i: int) -> SyntheticFrame:
    return _WORKER_SYNTH.render(i)


def _quiet_worker() -> None:
    """A renderer leaves Ctrl-C to the main process, which ends the pool, and ends at once on
    SIGTERM: no traceback from every worker, and the caller's clean-up runs in the main process."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def write_sequence(
    synth: Synthesizer,
    root: Path,
    sequence: str,
    workers: int = 1,
    progress: Callable[[int], None] | None = None,
) -> Path:
    """Render every frame into ``root/sequences/<sequence>`` with ``meta.json`` and
    ``classes.json`` beside the KITTI files. Returns the sequence folder."""
    writer = KittiOdometryWriter(root, sequence, synth.calibration)
    poses = []
    for item in synth.frames(workers):
        writer.add(item.frame, item.instances)
        poses.append(item.T_world_lidar)
        if progress is not None:
            progress(1)
    seq_dir = writer.close(np.stack(poses))
    meta = synth.meta()
    (seq_dir / "meta.json").write_text(json.dumps(meta, indent=2) + "\n")
    (seq_dir / "classes.json").write_text(json.dumps(meta["classes"], indent=2) + "\n")
    return seq_dir
