"""Issue 20's speed goal: one 10-frame calibration at full resolution from 10° / 50 cm, alone on
the machine (its cores, its default threads), on synthetic urban sequences at KITTI's pixel scale
(1242x375, f = 721.5) of unseen seeds, the packaged ``calibrate.yaml``. Per draw: seconds, the
seconds of each stage, frame matchings per working focal length, the final error. Then the
median and 90th percentile against the 15 s target.

This machine's speed moves from session to session (``make test`` 536 s on 2026-12-01, 1280 s on
2026-11-29, same tests), so each run also times a fixed piece of work, one full-resolution match
of a frame (median of 30), and reports the calibration in those units as well: a figure another
machine can compare. ``--compare KEY=VALUE,...`` times the packaged config with those keys
changed, draw by draw in alternation with the packaged one, and reports the ratio of their
medians (measured in one run). Prints a table and writes ``benchmarks/results/speed.json``.

    .venv/bin/python benchmarks/bench_speed.py [--draws 4] [--seeds 301,302] [--compare settle_px=0]
"""

from __future__ import annotations

import argparse
import json
import re
import time
import zlib
from collections import Counter

import numpy as np
import torch
import yaml
from bench_real import KITTI_RES, SYNTH_FRAMES, draw_start
from pydantic import ValidationError
from results_io import cpu_description, package_versions, save_results

import calib.refine.passes as passes_module
from calib.geometry import calibration_error
from calib.match.edge_matcher import EdgeMatcher
from calib.refine.passes import CalibrateConfig, load_calibrate_config
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config
from supportnet import Calibrator

TARGET_S = 15.0
"""Issue 20, item 7: a 10-frame full-resolution calibration from 10° / 50 cm on the 2-core machine."""
START = (50.0, 10.0)
"""The start's size (cm, °), uniform in the ball, random directions (bench_real's draws)."""
REFERENCE_MATCHES = 30


def frames_of(seed: int) -> tuple[list, np.ndarray]:
    """The seed's 10-frame urban sequence at KITTI's pixel scale, the camera exposing with the
    LiDAR (bench_real's ``synth-urban-offset0``)."""
    config = load_synth_config("urban", camera=KITTI_RES, timing={"camera_offset_s": 0.0})
    synth = Synthesizer(config, SYNTH_FRAMES, seed=seed)
    return [synth.render(i).frame for i in range(SYNTH_FRAMES)], synth.T_cam_lidar


def reference_match_ms(frames: list, T_cam_lidar: np.ndarray, focal_px: float) -> float:
    """Median ms of one EdgeMatcher match of a frame at ``focal_px`` (its caches warm), the unit
    of this machine's speed."""
    matcher = EdgeMatcher(load_calibrate_config().edge.model_copy(update={"working_focal_px": focal_px}))
    for frame in frames:
        matcher.match(frame, T_cam_lidar)
    times = []
    for k in range(REFERENCE_MATCHES):
        start = time.perf_counter()
        matcher.match(frames[k % len(frames)], T_cam_lidar)
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


class MatchCounter:
    """Counts the frames each matching round matches, by the matcher's working focal length."""

    def __init__(self) -> None:
        self.counts: Counter[str] = Counter()
        self._match_frames = passes_module.match_frames

    def __enter__(self) -> MatchCounter:
        def counted(matcher, frames, T_cam_lidar):
            focal = getattr(getattr(matcher, "config", None), "working_focal_px", None)
            name = getattr(matcher, "name", "?")
            self.counts[f"{name} {focal:g} px" if focal else name] += len(frames)
            return self._match_frames(matcher, frames, T_cam_lidar)

        passes_module.match_frames = counted
        return self

    def __exit__(self, *_: object) -> None:
        passes_module.match_frames = self._match_frames


def one_draw(frames: list, T_ref: np.ndarray, seed: int, draw: int, config: CalibrateConfig) -> dict:
    generator = torch.Generator().manual_seed(zlib.crc32(f"synth-urban-offset0/10/{draw}".encode()))
    T_start = draw_start(T_ref, *START, generator, False)
    with MatchCounter() as counter:
        start = time.perf_counter()
        result = Calibrator(config=config).calibrate(frames, T_init=T_start, seed=draw)
        seconds = time.perf_counter() - start
    error = calibration_error(result.T_cam_lidar, T_ref)
    return {
        "seed": seed,
        "draw": draw,
        "seconds": seconds,
        "stages": dict(result.stage_seconds),
        "frame_matches": dict(counter.counts),
        "final": {"cm": error.translation_cm, "deg": error.rotation_deg},
    }


def parse_changes(text: str | None) -> dict:
    """``KEY=VALUE,...`` (values read as YAML; a list's commas inside its brackets,
    ``pyramid_focals_px=[180,360]``) into a config update."""
    if not text:
        return {}
    items = re.split(r",(?![^\[]*\])", text)  # not at a comma inside [...]
    return {k: yaml.safe_load(v) for k, v in (item.split("=", 1) for item in items)}


def merged(base: dict, changes: dict) -> dict:
    """``base`` with ``changes`` merged in, a dotted key (``edge.carry``) reaching into its
    group (the group's other keys kept); a plain key replaces the whole value."""
    out = dict(base)
    for key, value in changes.items():
        group, dot, rest = key.partition(".")
        if dot:
            inner = out.get(group, {})
            if not isinstance(inner, dict):
                raise ValueError(f"{key}: {group!r} is not a group of keys")
            out[group] = merged(inner, {rest: value})
        else:
            out[key] = value
    return out


def packaged_with(changes: dict) -> CalibrateConfig:
    """The packaged ``calibrate.yaml`` with ``changes`` (:func:`parse_changes`, dotted keys into
    their groups: :func:`merged`) applied and validated: a misspelt key or a bad value raises
    ``pydantic.ValidationError``."""
    return CalibrateConfig.model_validate(merged(load_calibrate_config().model_dump(), changes))


def summary(runs: list[dict], reference_ms: float) -> dict:
    seconds = [r["seconds"] for r in runs]
    return {
        "seconds_median": float(np.median(seconds)),
        "seconds_p90": float(np.percentile(seconds, 90)),
        "in_reference_matches_median": float(np.median(seconds)) * 1e3 / reference_ms,
        "within_target": sum(s <= TARGET_S for s in seconds),
        "cm_median": float(np.median([r["final"]["cm"] for r in runs])),
        "deg_median": float(np.median([r["final"]["deg"] for r in runs])),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=4, help="draws per seed")
    parser.add_argument("--seeds", default="301,302", help="comma-separated unseen seeds")
    parser.add_argument("--compare", default=None, help="KEY=VALUE,...: a variant timed beside it")
    args = parser.parse_args()
    packaged = load_calibrate_config()
    changes = parse_changes(args.compare)
    configs = {"packaged": packaged}
    if changes:
        try:
            configs[args.compare] = packaged_with(changes)
        except ValidationError as error:
            parser.error(f"--compare: {error}")
    runs: dict[str, list[dict]] = {name: [] for name in configs}
    reference_ms = None
    for seed in (int(s) for s in args.seeds.split(",")):
        frames, T_ref = frames_of(seed)
        if reference_ms is None:
            reference_ms = reference_match_ms(frames, T_ref, packaged.finest_focal_px or 721.5)
            print(f"one full-resolution match of a frame: {reference_ms:.0f} ms (this machine's unit)")
        for draw in range(args.draws):
            for name, config in configs.items():  # alternating, so both see the same machine
                run = one_draw(frames, T_ref, seed, draw, config)
                runs[name].append(run)
                print(
                    f"{name:>14s} seed {seed} draw {draw}: {run['seconds']:5.1f} s, "
                    f"{run['final']['cm']:.2f} cm / {run['final']['deg']:.3f}°, matched "
                    + ", ".join(f"{k} x{v}" for k, v in run["frame_matches"].items())
                )
    rows = {name: {"summary": summary(r, reference_ms), "runs": r} for name, r in runs.items()}
    print(
        f"\n{'config':>24s} {'s median / p90':>15s} {'in matches':>11s} {'<= 15 s':>8s} "
        f"{'cm / ° median':>15s}"
    )
    for name, row in rows.items():
        s = row["summary"]
        print(
            f"{name:>24s} {s['seconds_median']:6.1f} / {s['seconds_p90']:<6.1f} "
            f"{s['in_reference_matches_median']:>10.0f} {s['within_target']:>4d}/{len(row['runs']):<3d} "
            f"{s['cm_median']:6.2f} / {s['deg_median']:.3f}"
        )
    if changes:
        ratio = (
            rows[args.compare]["summary"]["seconds_median"] / rows["packaged"]["summary"]["seconds_median"]
        )
        print(f"{args.compare} / packaged, median seconds: {ratio:.2f} (one run)")
    stages = Counter()
    for run in runs["packaged"]:
        stages.update(run["stages"])
    print(
        "packaged, mean seconds per stage: "
        + json.dumps({k: round(v / len(runs["packaged"]), 2) for k, v in stages.items()})
    )
    out = save_results(
        "speed",
        {
            "target_s": TARGET_S,
            "start_cm_deg": START,
            "reference_match_ms": reference_ms,
            "cpu": cpu_description(),
            "threads": torch.get_num_threads(),
            "packages": package_versions(),
            "configs": rows,
        },
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
