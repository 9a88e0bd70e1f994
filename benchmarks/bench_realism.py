"""How hard synthetic frames are for the matcher compared with real ones: the EdgeMatcher's endpoint
error under the reference extrinsic on every real fixture and on full-resolution synthetic frames,
with the synthetic camera's effects (``camera_effects`` of the world's config: blur, vignetting,
exposure, shot noise, JPEG) on and off, side by side.

Under the reference the ideal residual is zero, so a correspondence's endpoint error (EPE) is
``‖uv_matched − uv‖`` in full-resolution frame pixels. Each dataset reports the median, mean and
90th percentile over its correspondences, pooled over its frames, in pixels and in milliradians
(pixels / f, comparable across cameras). Like is compared with like: synthetic urban (KITTI's
1242x375, f = 721.5) against the four KITTI fixtures pooled (f = 707–721.5) in pixels; the vineyard
(960x540, f = 527; no real vineyard fixture) against the same KITTI median in milliradians, at its
focal length. ``ratio`` is real / synthetic of the medians: the synthetic frames are as hard as real
ones within 1.5x when it is at most 1.5. The JSON also keeps the vineyard's ratio against the mean of
all real fixtures' medians (nuScenes' and PJLab's rest on 15–2000 correspondences of one frame).

Synthetic frames: ``--frames`` of each of ``--seeds`` (unseen seeds, as bench_real), camera exposing
with the LiDAR (``camera_offset_s = 0``), the world's own wind and moving cars, and its own scan
motion distortion (each LiDAR beam cast from the pose at its own time: on for urban, as KITTI's
scans are not de-skewed; ``--motion-distortion on|off`` sets it for both worlds).
Prints a table, progress to stderr, and writes ``benchmarks/results/bench_realism.json``.

    .venv/bin/python benchmarks/bench_realism.py [--frames 5] [--seeds 201,202]
        [--motion-distortion world|on|off] [--only real|synthetic] [--set blur_px=1.0 --set jpeg_quality=80]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

os.environ.setdefault(
    "OMP_NUM_THREADS", "1"
)  # a benchmark shares its machine: one thread, timings comparable

import numpy as np
import torch
from results_io import save_results
from rich.console import Console

from calib.data import Frame, open_dataset
from calib.data.real_fixtures import check_fixtures, realdata_root
from calib.features import ring_stripes
from calib.match.edge_matcher import EdgeMatcher
from calib.refine.passes import load_calibrate_config
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import CameraEffectsConfig, load_synth_config

KITTI = ("kitti-raw-0928", "kitti-raw-0928-more", "kitti-object-000008", "kitti-object-000114")
"""The real fixtures at KITTI's pixel scale, the urban world's reference."""
TARGET_RATIO = 1.5
"""Synthetic frames are hard enough when the real median EPE is at most this times theirs."""

console = Console(stderr=True, highlight=False, soft_wrap=True)


def endpoint_errors(matcher: EdgeMatcher, frames: list[Frame], T_ref: np.ndarray) -> np.ndarray:
    """``(M,)`` endpoint errors in frame pixels of every correspondence of ``frames`` under ``T_ref``."""
    errors = [np.linalg.norm(c.uv_matched - c.uv, axis=1) for c in (matcher.match(f, T_ref) for f in frames)]
    return np.concatenate(errors) if errors else np.zeros(0)


def _summary(values: np.ndarray) -> dict:
    if len(values) == 0:
        return {"median": None, "mean": None, "p90": None}
    return {
        "median": float(np.median(values)),
        "mean": float(np.mean(values)),
        "p90": float(np.percentile(values, 90)),
    }


def stats(errors: np.ndarray, focal_px: float | np.ndarray) -> dict:
    """Median, mean and 90th percentile of ``errors (M,)`` in pixels and in milliradians.

    Args:
        errors: ``(M,)`` endpoint errors in pixels.
        focal_px: the frames' focal length, or ``(M,)`` one per correspondence (fixtures pooled).
    """
    focal = np.broadcast_to(np.asarray(focal_px, np.float64), errors.shape)
    return {
        "correspondences": len(errors),
        "focal_px": float(np.median(focal)) if len(errors) else float(np.mean(focal_px)),
        "px": _summary(errors),
        "mrad": _summary(1000 * errors / focal),
    }


def stripes(scans: list[np.ndarray]) -> float | None:
    """The median over ``scans`` of :func:`~calib.features.ring_stripes` (how striped along the
    scan lines the levelled intensity stays: about 1 for gains alone); ``None`` where no scan
    tells."""
    ratios = [r for points in scans if (r := ring_stripes(points)) is not None]
    return float(np.median(ratios)) if ratios else None


def real_rows(matcher: EdgeMatcher, work: Path) -> dict:
    """Per real fixture its stats and frame facts, and ``kitti-pooled``: the KITTI fixtures'
    correspondences together."""
    rows, kitti, kitti_focal = {}, [], []
    for fixture in check_fixtures(realdata_root(), work):
        clock = time.perf_counter()
        with open_dataset(fixture.path, camera=fixture.camera) as seq:
            frames = [seq[i] for i in range(len(seq))]
            T_ref = np.asarray(seq.calibration.T_cam_lidar, np.float64)
        errors = endpoint_errors(matcher, frames, T_ref)
        focal = float(frames[0].K[0, 0])
        if fixture.name in KITTI:
            kitti.append(errors)
            kitti_focal.append(np.full(len(errors), focal))
        H, W = frames[0].image.shape[:2]
        rows[fixture.name] = {
            "frames": len(frames),
            "size": f"{W}x{H}",
            "ring_stripes": stripes([f.points for f in frames]),
            **stats(errors, focal),
        }
        console.print(f"{fixture.name}: {len(errors)} correspondences in {time.perf_counter() - clock:.1f} s")
    rows["kitti-pooled"] = {
        "frames": sum(rows[n]["frames"] for n in KITTI),
        "size": "~1242x375",
        **stats(np.concatenate(kitti), np.concatenate(kitti_focal)),
    }
    return rows


def synthetic_row(
    matcher: EdgeMatcher,
    world: str,
    effects: dict | None,
    seeds: list[int],
    frames: int,
    distort: bool | None,
) -> dict:
    """Stats of ``frames`` frames of each seed of ``world`` at its full resolution, with the
    camera effects of its config (``effects=None``) or these, the scans motion-distorted as the
    world's config says (``distort=None``) or as ``distort`` says."""
    timing = {"camera_offset_s": 0.0} | ({} if distort is None else {"motion_distortion": distort})
    overrides: dict = {"timing": timing}
    if effects is not None:
        overrides["camera_effects"] = effects
    config = load_synth_config(world, **overrides)
    errors, scans = [], []
    for seed in seeds:
        clock = time.perf_counter()
        synth = Synthesizer(config, frames, seed=seed)
        seq = [synth.render(i).frame for i in range(frames)]
        errors.append(endpoint_errors(matcher, seq, synth.T_cam_lidar))
        scans += [f.points for f in seq]
        console.print(
            f"{world} seed {seed}: {len(errors[-1])} correspondences in {time.perf_counter() - clock:.1f} s"
        )
    c = config.camera
    return {
        "frames": frames * len(seeds),
        "size": f"{c.width}x{c.height}",
        "camera_effects": config.camera_effects.model_dump(),
        "ring_stripes": stripes(scans),
        **stats(np.concatenate(errors), c.fx),
    }


def real_reference_px(kitti: dict, focal_px: float, same_scale: bool) -> float:
    """The real median EPE a synthetic world is held to, in its pixels: the pooled KITTI
    fixtures' median in pixels (urban, KITTI's own camera) or in milliradians at ``focal_px``."""
    return kitti["px"]["median"] if same_scale else kitti["mrad"]["median"] * focal_px / 1000


def _f(value: float | None, spec: str = "6.2f") -> str:
    return format(value, spec) if value is not None else "–"


def line(name: str, row: dict, reference: float | None = None) -> str:
    px, mrad = row["px"], row["mrad"]
    ratio = reference / px["median"] if reference is not None and px["median"] else None
    return (
        f"{name:34s} {row['size']:>9s} {row['focal_px']:7.1f} {row['frames']:3d} {row['correspondences']:6d} "
        f"{_f(px['median'])} {_f(px['mean'])} {_f(px['p90'])} {_f(mrad['median'], '6.2f')} "
        f"{_f(reference, '7.2f')} {_f(ratio, '6.2f')} {_f(row.get('ring_stripes'), '7.2f')}"
    )


HEADER = (
    f"{'dataset':34s} {'size':>9s} {'f px':>7s} {'fr':>3s} {'corr':>6s} {'med px':>6s} {'mean':>6s} "
    f"{'p90':>6s} {'med mr':>6s} {'real px':>7s} {'ratio':>6s} {'stripes':>7s}"
)


def parse_effects(settings: list[str]) -> dict:
    """``["blur_px=1", "jpeg_quality=80"]`` as a dict, validated as camera-effects overrides."""
    values = dict(s.split("=", 1) for s in settings)
    CameraEffectsConfig.model_validate(values)  # refuse a misspelt key or a bad value before rendering
    return values


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=5, help="frames per synthetic seed")
    parser.add_argument("--seeds", default="201,202", help="synthetic seeds, comma-separated")
    parser.add_argument("--only", choices=("real", "synthetic"), default=None)
    parser.add_argument(
        "--motion-distortion",
        choices=("world", "on", "off"),
        default="world",
        help="synthetic scans motion-distorted as each world's config says (urban: on, as KITTI's "
        "scans are not de-skewed; vineyard: off), or on / off for both",
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a camera_effects value of both worlds for the 'on' rows (tuning)",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    seeds = [int(s) for s in args.seeds.split(",")]
    distort = {"world": None, "on": True, "off": False}[args.motion_distortion]
    effects_on = parse_effects(args.set) if args.set else None
    effects_off = CameraEffectsConfig().model_dump()
    matcher = EdgeMatcher(load_calibrate_config().edge)
    clock = time.perf_counter()
    results: dict = {
        "synthetic_seeds": seeds,
        "frames_per_seed": args.frames,
        "effects_overrides": effects_on,
        "motion_distortion": args.motion_distortion,
        "target_ratio": TARGET_RATIO,
        "machine": f"{platform.machine()}, {platform.python_version()}",
        "real": {},
        "synthetic": {},
    }
    if args.only != "synthetic":
        if realdata_root() is None:
            print("real fixtures absent (../shared/realdata, SUPPORTNET_REALDATA): skipped")
        else:
            with tempfile.TemporaryDirectory() as work:
                results["real"] = real_rows(matcher, Path(work))
            medians = [r["mrad"]["median"] for n, r in results["real"].items() if n != "kitti-pooled"]
            results["real_mean_of_medians_mrad"] = float(np.mean([m for m in medians if m is not None]))
    if args.only != "real":
        for world in ("urban", "vineyard"):
            for label, effects in (("effects", effects_on), ("no effects", effects_off)):
                results["synthetic"][f"synth-{world} ({label})"] = synthetic_row(
                    matcher, world, effects, seeds, args.frames, distort
                )
    print(HEADER)
    for name, row in results["real"].items():
        print(line(name, row))
    kitti = results["real"].get("kitti-pooled")
    for name, row in results["synthetic"].items():
        reference = None
        if kitti is not None:
            reference = real_reference_px(kitti, row["focal_px"], "urban" in name)
            mean_real = results["real_mean_of_medians_mrad"] * row["focal_px"] / 1000
            median = row["px"]["median"]
            row["real_reference_px"] = reference
            row["ratio"] = reference / median if median else None
            row["ratio_to_mean_of_real_medians"] = mean_real / median if median else None
        print(line(name, row, reference))
    print(
        "real px: the KITTI fixtures' pooled median (for the vineyard: its angle at f = 527); "
        f"ratio = real / synthetic median, target ≤ {TARGET_RATIO}"
    )
    results["seconds"] = time.perf_counter() - clock
    print(f"wrote {save_results('bench_realism', results)} in {results['seconds']:.0f} s")


if __name__ == "__main__":
    main()
