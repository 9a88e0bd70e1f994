"""Synthetic worlds: rendering speed, ground-truth label agreement, and LiDAR odometry drift.

usage: python benchmarks/bench_synth.py [--frames N] [--odometry-frames N] [--out results.json]

Prints three tables and writes them as JSON:
- speed: frames per second (624x188 image + 64-beam scan, files written) with 1 and 2 workers;
  every sequence here renders the small camera (``small=True``), as the recorded figures always did;
- agreement: share of visible LiDAR points whose image pixel (±1 px) has the same class, for
  rigid classes and for foliage, at a still moment (no wind, no time offset), with the world's
  default wind and camera offset, and with strong wind and a 50 ms offset;
- odometry: KISS-ICP on the scans against the ground-truth LiDAR trajectory.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from calib.data.classes import RIGID_CLASSES
from calib.data.label_agreement import sequence_label_agreement
from calib.init.lidar_odometry import drift, lidar_odometry
from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config

WORLDS = ("vineyard", "urban")


def speed(world: str, frames: int, workers: int) -> float:
    synth = Synthesizer(load_synth_config(world, small=True), frames, seed=7)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        write_sequence(synth, Path(tmp), "00", workers)
        return frames / (time.perf_counter() - start)


def agreement(world: str, frames: int, condition: str) -> dict[str, float]:
    default = load_synth_config(world, small=True)
    overrides = {
        "still": {"wind": {"amplitude_m": 0.0}, "timing": {"camera_offset_s": 0.0}},
        "default": {},
        "windy": {"wind": {"amplitude_m": 3 * default.wind.amplitude_m}, "timing": {"camera_offset_s": 0.05}},
    }[condition]
    synth = Synthesizer(load_synth_config(world, small=True, **overrides), frames, seed=11)
    total = sequence_label_agreement(item.frame for item in synth.frames(workers=2))
    return {
        "rigid": total.rate(RIGID_CLASSES),
        "foliage": total.rate({70}),
        "rigid_points": sum(total.totals.get(c, 0) for c in RIGID_CLASSES),
    }


def odometry(world: str, frames: int) -> dict[str, float]:
    synth = Synthesizer(load_synth_config(world, small=True), frames, seed=3)
    scans = [item.frame.points for item in synth.frames(workers=2)]
    start = time.perf_counter()
    estimate = lidar_odometry(scans, max_range_m=60.0, voxel_size_m=0.3 if world == "vineyard" else 0.6)
    result = drift(estimate, synth.lidar_poses())
    result["seconds_per_scan"] = (time.perf_counter() - start) / frames
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--odometry-frames", type=int, default=150)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/synth.json"))
    args = parser.parse_args()
    results: dict[str, dict] = {"speed": {}, "agreement": {}, "odometry": {}}

    print(f"{'world':<10}{'1 worker fps':>14}{'2 workers fps':>15}")
    for world in WORLDS:
        r = {f"workers_{w}": speed(world, args.frames, w) for w in (1, 2)}
        results["speed"][world] = r
        print(f"{world:<10}{r['workers_1']:>14.2f}{r['workers_2']:>15.2f}")

    print(f"\n{'world':<10}{'condition':<10}{'rigid':>8}{'foliage':>9}{'rigid pts':>11}")
    for world in WORLDS:
        for condition in ("still", "default", "windy"):
            r = agreement(world, args.frames, condition)
            results["agreement"][f"{world}/{condition}"] = r
            print(f"{world:<10}{condition:<10}{r['rigid']:>8.3f}{r['foliage']:>9.3f}{r['rigid_points']:>11d}")

    print(f"\n{'world':<10}{'path m':>8}{'end err m':>10}{'drift %':>9}{'rot deg':>9}{'mean err m':>11}")
    for world in WORLDS:
        r = odometry(world, args.odometry_frames)
        results["odometry"][world] = r
        print(
            f"{world:<10}{r['path_m']:>8.1f}{r['end_error_m']:>10.3f}{r['drift_percent']:>9.2f}"
            f"{r['rotation_drift_deg']:>9.3f}{r['mean_error_m']:>11.3f}"
        )

    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2, default=float) + "\n")
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
