"""Where the synthetic worlds' accuracy floor comes from: Stage 4's passes started at the true
extrinsic (no coarse stage, no pyramid: the passes' own fixed point) on full-resolution sequences
of the packaged world, and of the same world with one source of realism taken out at a time.

Started from the truth, a perfect method stays there; how far the passes move away is the floor
that no start can beat. Each row renders the same seeds with one change to the world's config
(``true motion`` keeps the world and deskews with the simulator's own trajectory instead of
KISS-ICP's), calibrates each sequence ``--samplings`` times (the correspondence sampling's seed), and
reports the median final error, the mean translation error in the camera frame (x right, y down,
z along the optical axis) and the seconds per calibration. The camera exposes with the LiDAR
(``camera_offset_s = 0``; the time offset is issue 21's and ``bench_time_offset``'s).
Prints a table, progress to stderr, and writes ``benchmarks/results/bench_floor.json``.

    .venv/bin/python benchmarks/bench_floor.py [--world urban] [--seeds 302,303] [--samplings 2]
        [--rows packaged,true-motion,...]
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np
from bench_real import SYNTH_CAMERAS, SYNTH_FRAMES
from results_io import save_results
from rich.console import Console

from calib.geometry import calibration_error
from calib.motion import motions_from_poses
from calib.pipeline import Calibrator
from calib.refine.passes import load_calibrate_config
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config

NO_DISTORTION = {"timing": {"motion_distortion": False}}
NO_ANGLE_ERRORS = {"lidar": {"laser_angle_std_deg": 0.0}}
NO_SHADOWS = {"light": {"sun": 0.0, "ambient": 1.0}}
NO_WIND = {"wind": {"amplitude_m": 0.0}}
NO_BASELINE = {"extrinsic": {"camera_position_m": (0.0, 0.0, 0.0), "jitter_cm": 0.0}}
ROWS: dict[str, tuple[dict, bool]] = {
    "packaged": ({}, False),
    "true-motion": ({}, True),
    "no-motion-distortion": (NO_DISTORTION, False),
    "no-laser-angle-errors": (NO_ANGLE_ERRORS, False),
    "no-shadows": (NO_SHADOWS, False),
    "no-wind": (NO_WIND, False),
    "lidar-at-camera": (NO_BASELINE, False),
    "none-of-these": (
        {**NO_DISTORTION, **NO_ANGLE_ERRORS, **NO_SHADOWS, **NO_WIND, **NO_BASELINE},
        False,
    ),
}
"""Row name -> (config overrides of the world, deskew with the simulator's trajectory)."""

console = Console(stderr=True, highlight=False, soft_wrap=True)


def _merged(*parts: dict) -> dict:
    """Config overrides merged one level deep (``timing`` from two parts keeps both keys)."""
    out: dict = {}
    for part in parts:
        for key, value in part.items():
            out[key] = {**out.get(key, {}), **value} if isinstance(value, dict) else value
    return out


def one_row(world: str, overrides: dict, true_motion: bool, seeds: list[int], samplings: int) -> dict:
    """The passes from the truth on each seed's sequence, ``samplings`` times each."""
    config = load_calibrate_config()
    config = config.model_copy(
        update={
            "coarse": config.coarse.model_copy(update={"enabled": False}),
            "flow_coarse_passes": 0,
            "pyramid_focals_px": (),
        }
    )
    runs = []
    for seed in seeds:
        world_config = load_synth_config(
            world, camera=SYNTH_CAMERAS[world], **_merged({"timing": {"camera_offset_s": 0.0}}, overrides)
        )
        synth = Synthesizer(world_config, SYNTH_FRAMES, seed=seed)
        frames = [synth.render(i).frame for i in range(SYNTH_FRAMES)]
        T = synth.T_cam_lidar
        stamps = np.arange(SYNTH_FRAMES) / world_config.timing.rate_hz
        motions = dict(enumerate(motions_from_poses(synth.lidar_poses(), stamps))) if true_motion else None
        for sampling in range(samplings):
            clock = time.perf_counter()
            result = Calibrator(config=config).calibrate(frames, T_init=T, seed=sampling, motions=motions)
            error = calibration_error(result.T_cam_lidar, T)
            runs.append(
                {
                    "seed": seed,
                    "sampling": sampling,
                    "cm": error.translation_cm,
                    "deg": error.rotation_deg,
                    "camera_xyz_cm": (100 * (result.T_cam_lidar[:3, 3] - T[:3, 3])).tolist(),
                    "seconds": time.perf_counter() - clock,
                }
            )
            console.print(
                f"  seed {seed} sampling {sampling}: {error.translation_cm:.2f} cm {error.rotation_deg:.3f}°"
            )
    xyz = np.array([r["camera_xyz_cm"] for r in runs])
    return {
        "overrides": overrides,
        "true_motion": true_motion,
        "cm_median": float(np.median([r["cm"] for r in runs])),
        "deg_median": float(np.median([r["deg"] for r in runs])),
        "camera_xyz_cm_mean": xyz.mean(0).tolist(),
        "seconds": float(np.mean([r["seconds"] for r in runs])),
        "runs": runs,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--world", choices=tuple(SYNTH_CAMERAS), default="urban")
    parser.add_argument("--seeds", default="302,303", help="unseen synthetic seeds, comma-separated")
    parser.add_argument("--samplings", type=int, default=2, help="calibrations per sequence (sampling seeds)")
    parser.add_argument("--rows", default=",".join(ROWS), help=f"comma-separated, of {', '.join(ROWS)}")
    args = parser.parse_args()
    rows = args.rows.split(",")
    if bad := [r for r in rows if r not in ROWS]:
        parser.error(f"unknown rows: {', '.join(bad)}")
    seeds = [int(s) for s in args.seeds.split(",")]
    results: dict = {
        "world": args.world,
        "seeds": seeds,
        "samplings": args.samplings,
        "machine": f"{platform.machine()}, {platform.python_version()}",
        "calibrate_config": load_calibrate_config().model_dump(mode="json"),
        "rows": {},
    }
    print(f"{'row':24s} {'cm median':>9s} {'° median':>9s} {'camera x / y / z cm (mean)':>28s} {'s':>5s}")
    for name in rows:
        console.print(f"[bold]{name}[/bold]")
        overrides, true_motion = ROWS[name]
        row = one_row(args.world, overrides, true_motion, seeds, args.samplings)
        results["rows"][name] = row
        x, y, z = row["camera_xyz_cm_mean"]
        print(
            f"{name:24s} {row['cm_median']:9.2f} {row['deg_median']:9.3f} "
            f"{f'{x:+.2f} / {y:+.2f} / {z:+.2f}':>28s} {row['seconds']:5.1f}",
            flush=True,
        )
        save_results("bench_floor", results)
    print(f"wrote {save_results('bench_floor', results)}")


if __name__ == "__main__":
    main()
