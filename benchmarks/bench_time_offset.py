"""The camera–LiDAR time offset ``δt`` (issue 21) on full-resolution synthetic drives that turn.

Each world renders a stretch of its drive that holds a turn, at real pixel scale (bench_real's
cameras), with its default camera offset (urban 5 ms at 8 m/s with motion-distorted scans,
vineyard 20 ms at 1.2 m/s) or those of ``--offsets-ms``:

- urban frames 25–70: straight street, a 0.7 rad/s turn (frames ~37–57), straight again;
- vineyard frames 55–105: the end of a row and the 1.0 rad/s headland turn (frames ~70–95).

Each run draws a start of 10 cm / 2° (bench_real's draws, ``--level``) and calibrates it with
the packaged config (10 of the stretch's frames, by information) three ways:

- ``off``: the points as measured (``time_offset.mode: off``, what Stage 4 did before);
- ``odometry``: ``--time-offset estimate``, the LiDAR's motion from KISS-ICP around each frame;
- ``no restarts``: the same without the ``δt`` restarts once settled (``time_offset.restarts_ms:
  []``), as before they existed;
- ``true motion``: estimate with the world's own trajectory as the motion, which separates the
  odometry's error from the method's.

``--set KEY=VALUE,...`` runs all of them on the packaged config with those keys changed
(``edge.carry=own``: one key of a group; a switch measured here as ``bench_speed.py --compare``
times it); ``--world-set GROUP.KEY=VALUE,...`` renders the worlds with those keys changed
(``lidar.laser_angle_std_deg=0``: lasers without their angle errors). Each run records its
error per LiDAR axis as well. A run succeeds when it ends within 2 cm and 0.2° (the issue's
target); the table gives median and 90th-percentile errors, the ``δt`` error and the share of
runs within 1 ms. Prints a table and writes ``benchmarks/results/bench_time_offset.json``.

    .venv/bin/python benchmarks/bench_time_offset.py [--runs 4] [--worlds urban,vineyard]
        [--offsets-ms default|-50,-20,0,5,20,50] [--level 2]
        [--variants "off,odometry,no restarts,true motion"]
        [--set settle_px=0.1] [--world-set lidar.laser_angle_std_deg=0] [--name bench_time_offset]
        [--first-run K --threads 1: a part of the runs, side by side]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
import zlib

import numpy as np
import torch
from bench_real import LEVELS, SYNTH_CAMERAS, draw_start, set_threads
from bench_speed import merged, packaged_with, parse_changes
from pydantic import ValidationError
from results_io import RESULTS, save_results
from rich.console import Console

from calib.geometry import calibration_error
from calib.motion import motions_from_poses
from calib.refine.passes import CalibrateConfig
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config
from supportnet import Calibrator  # builds the packaged config's learned matcher too

STRETCHES = {"urban": range(25, 70), "vineyard": range(55, 105)}
SEED = 301
"""Unseen: training uses small seeds, bench_check 101–104, bench_real 201–202."""
VARIANTS = ("off", "odometry", "no restarts", "true motion")
SUCCESS = (2.0, 0.2)

console = Console(stderr=True, highlight=False, soft_wrap=True)


def world_changes(text: str | None) -> dict:
    """``GROUP.KEY=VALUE,...`` (values read as YAML) into :func:`load_synth_config` overrides,
    e.g. ``lidar.laser_angle_std_deg=0`` → ``{"lidar": {"laser_angle_std_deg": 0}}``."""
    changes = parse_changes(text)
    if plain := [key for key in changes if "." not in key.strip(".")]:
        raise ValueError(f"--world-set takes GROUP.KEY=VALUE, got {plain[0]!r}")
    return merged({}, changes)


def render(world: str, offset_s: float | None, changes: dict) -> tuple[list, np.ndarray, dict, float]:
    """The stretch's frames, the reference extrinsic, the true motion by position, and δt;
    ``changes`` (:func:`world_changes`) are merged into the world's config groups."""
    overrides = changes if offset_s is None else merged(changes, {"timing.camera_offset_s": offset_s})
    config = load_synth_config(world, camera=SYNTH_CAMERAS[world], **overrides)
    stretch = STRETCHES[world]
    synth = Synthesizer(config, stretch.stop, seed=SEED)
    start = time.perf_counter()
    frames = [item.frame for item in synth.frames(workers=2, indices=stretch)]
    console.print(f"{world}: {len(frames)} frames rendered in {time.perf_counter() - start:.0f} s")
    stamps = np.array(stretch) / config.timing.rate_hz
    motions = motions_from_poses(synth.world.drive.lidar_poses(stamps), stamps)
    return frames, synth.T_cam_lidar, dict(enumerate(motions)), config.timing.camera_offset_s


def one_run(frames, T_ref, truth_motions, offset_s, variant, level, run, base: CalibrateConfig) -> dict:
    cm, deg = LEVELS[level]
    generator = torch.Generator().manual_seed(zlib.crc32(f"dt/{level}/{run}".encode()))
    T_init = draw_start(T_ref, cm, deg, generator, False)
    timing = {"mode": "off" if variant == "off" else "estimate"}
    if variant == "no restarts":
        timing["restarts_ms"] = ()
    config = base.model_copy(update={"time_offset": base.time_offset.model_copy(update=timing)})
    start = time.perf_counter()
    result = Calibrator(config=config).calibrate(
        frames, T_init, seed=run, motions=truth_motions if variant == "true motion" else None
    )
    error = calibration_error(result.T_cam_lidar, T_ref)
    dt = result.time_offset_s
    return {
        "translation_cm": error.translation_cm,
        "rotation_deg": error.rotation_deg,
        "translation_xyz_cm": list(error.translation_xyz_cm),
        "rotation_xyz_deg": list(error.rotation_xyz_deg),
        "time_offset_ms": None if dt is None else 1e3 * dt,
        "time_offset_error_ms": None if dt is None else 1e3 * (dt - offset_s),
        "time_offset_std_ms": None if result.time_offset_std_s is None else 1e3 * result.time_offset_std_s,
        "note": result.time_offset_note,
        "seconds": time.perf_counter() - start,
    }


def summary(runs: list[dict]) -> dict:
    cm = np.array([r["translation_cm"] for r in runs])
    deg = np.array([r["rotation_deg"] for r in runs])
    dt = np.array([abs(r["time_offset_error_ms"]) for r in runs if r["time_offset_error_ms"] is not None])
    return {
        "runs": len(runs),
        "success": float(np.mean((cm <= SUCCESS[0]) & (deg <= SUCCESS[1]))),
        "cm_median": float(np.median(cm)),
        "cm_p90": float(np.percentile(cm, 90)),
        "deg_median": float(np.median(deg)),
        "deg_p90": float(np.percentile(deg, 90)),
        "dt_error_ms_median": float(np.median(dt)) if len(dt) else None,
        "dt_error_ms_p90": float(np.percentile(dt, 90)) if len(dt) else None,
        "dt_within_1ms": float(np.mean(dt <= 1.0)) if len(dt) else None,
        "seconds_median": float(np.median([r["seconds"] for r in runs])),
    }


def _f(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def print_table(rows: list[dict]) -> None:
    print(
        f"{'world':9} {'δt ms':>6} {'variant':14} {'runs':>4} {'success':>7} {'cm med':>7} {'cm p90':>7} "
        f"{'° med':>6} {'° p90':>6} {'|δt err| med':>12} {'p90':>6} {'≤1 ms':>6} {'s':>5}"
    )
    for row in rows:
        print(
            f"{row['world']:9} {row['offset_ms']:6g} {row['variant']:14} {row['runs']:4d} "
            f"{row['success']:7.0%} "
            f"{row['cm_median']:7.2f} {row['cm_p90']:7.2f} {row['deg_median']:6.3f} {row['deg_p90']:6.3f} "
            f"{_f(row['dt_error_ms_median'], '12.2f')} {_f(row['dt_error_ms_p90'], '6.2f')} "
            f"{_f(row['dt_within_1ms'], '6.0%')} {row['seconds_median']:5.0f}"
        )


def joined(parts: list[list[dict]]) -> list[dict]:
    """The rows of several parts of one benchmark (``--first-run``) as one: each world, offset and
    variant's runs in the parts' order, summarised again."""
    rows: dict[tuple, dict] = {}
    for part in parts:
        for row in part:
            key = (row["world"], row["offset_ms"], row["variant"])
            rows.setdefault(key, {"world": key[0], "offset_ms": key[1], "variant": key[2], "per_run": []})
            rows[key]["per_run"] += row["per_run"]
    return [{**row, **summary(row["per_run"])} for row in rows.values()]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=4)
    parser.add_argument("--worlds", default="urban,vineyard")
    parser.add_argument("--offsets-ms", default="default", help="default, or comma-separated milliseconds")
    parser.add_argument("--level", default="2", choices=sorted(LEVELS))
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument(
        "--set", default=None, help="KEY=VALUE,...: the packaged config with these keys changed (YAML values)"
    )
    parser.add_argument(
        "--world-set",
        default=None,
        help="GROUP.KEY=VALUE,...: the worlds' configs with these keys changed, e.g. "
        "lidar.laser_angle_std_deg=0 (a LiDAR without per-laser angle errors)",
    )
    parser.add_argument("--name", default="bench_time_offset", help="results/NAME.json")
    parser.add_argument(
        "--first-run",
        type=int,
        default=0,
        help="the first run's number: runs in parts (several processes side by side) draw the same "
        "starts as one run of all",
    )
    parser.add_argument(
        "--threads",
        type=int,
        default=None,
        help="torch and OpenCV threads (1 where processes run side by side)",
    )
    parser.add_argument(
        "--join",
        default=None,
        help="comma-separated results/NAME.json of parts (--first-run) to join into --name; runs nothing",
    )
    args = parser.parse_args()
    if args.join is not None:
        names = args.join.split(",")
        parts = [json.loads((RESULTS / f"{n}.json").read_text()) for n in names]
        rows = joined([p["rows"] for p in parts])
        print_table(rows)
        out = save_results(args.name, {**parts[0], "first_run": 0, "parts": names, "rows": rows})
        console.print(f"wrote {out}")
        return
    if args.threads is not None:
        set_threads(args.threads)
    offsets = [None] if args.offsets_ms == "default" else [float(v) / 1e3 for v in args.offsets_ms.split(",")]
    variants = args.variants.split(",")
    changes = parse_changes(args.set)
    try:
        base = packaged_with(changes)
    except ValidationError as error:
        parser.error(f"--set: {error}")
    try:
        worlds_changed = world_changes(args.world_set)
    except ValueError as error:
        parser.error(str(error))
    rows = []
    for world in args.worlds.split(","):
        for offset in offsets:
            frames, T_ref, truth, offset_s = render(world, offset, worlds_changed)
            for variant in variants:
                runs = []
                for run in range(args.first_run, args.first_run + args.runs):
                    runs.append(one_run(frames, T_ref, truth, offset_s, variant, args.level, run, base))
                    r = runs[-1]
                    console.print(
                        f"{world} {1e3 * offset_s:g} ms {variant} run {run}: {r['translation_cm']:.2f} cm "
                        f"{r['rotation_deg']:.3f}° (LiDAR x y z "
                        f"{' '.join(f'{v:+.2f}' for v in r['translation_xyz_cm'])} cm), "
                        f"δt {_f(r['time_offset_ms'], '.2f')} ms "
                        f"± {_f(r['time_offset_std_ms'], '.2f')} ({r['seconds']:.0f} s) {r['note']}"
                    )
                rows.append(
                    {
                        "world": world,
                        "offset_ms": 1e3 * offset_s,
                        "variant": variant,
                        **summary(runs),
                        "per_run": runs,
                    }
                )
    print_table(rows)
    out = save_results(
        args.name,
        {
            "machine": platform.machine(),
            "level": args.level,
            "seed": SEED,
            "first_run": args.first_run,
            "changes": changes,
            "world_changes": worlds_changed,
            "rows": rows,
        },
    )
    console.print(f"wrote {out}")


if __name__ == "__main__":
    main()
