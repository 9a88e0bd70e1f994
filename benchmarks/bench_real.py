"""Calibration (:class:`calib.pipeline.Calibrator`, Stages 2–4 from a perturbed start) on every real
fixture and on full-resolution synthetic sequences: success rate, median and 90th-percentile final
errors, seconds per calibration, from 2° / 10 cm, 5° / 25 cm and 10° / 50 cm.

Real fixtures (``../shared/realdata``, converted by :func:`calib.data.real_fixtures.check_fixtures`):
the two KITTI raw 2011_09_28 folders (grey camera 0, two and four frames) and all six frames
together (``kitti-raw-0928-all6``: both folders' calibrations are checked to be equal), KITTI object
000008 (scan cropped to the camera view) and 000114 (full scan, colour camera), the six nuScenes
cameras of one sample, the three PJLab scenes (64 rings, distorted 1920x1200 camera; scans in
scan-line order, per-point times dropped: Stages 2–4 do not read them). Synthetic: urban at KITTI's
pixel scale (1242x375, f = 721.5) and vineyard at the BLT ZED's half resolution (960x540, f = 527),
10-frame sequences of unseen seeds, the world's own wind, once with the camera exposing with the
LiDAR (``camera_offset_s = 0``) and once with the world's default offset (5 ms urban, 20 ms vineyard).

Each run draws a start ``T_ref · Δ`` with ``Δ`` of random axis and direction and its size uniform in
the ball of the level (``--shell``: exactly the level's size), from a generator seeded by the crc32
of dataset / level / run, so all variants start from the same draws. Variants, each the packaged
``calibrate.yaml`` with its stages switched as named: ``dense`` (the dense passes alone),
``global`` (the global coarse stage with each of its edge maps, then the dense passes, which go on
from the start, initial or coarse, that their first pass aligns best, a coarse one only when
clearly so), ``global-pyramid`` (the same with the dense passes run first at working focal lengths
of 90 and 180 px) and the ``contour`` ones. A run
succeeds when it ends within 2 cm and 0.2° of the reference (several frames) or 5 cm and 0.5°
(one frame); a run whose pipeline raises counts as a failure
and its message is kept. Prints a table, one progress line per run to stderr, and writes
``benchmarks/results/bench_real.json``.

    .venv/bin/python benchmarks/bench_real.py [--runs 20] [--levels 2,5,10] [--only real|synthetic]
        [--fixtures NAME,...] [--variants global,global-pyramid] [--shell]
"""

from __future__ import annotations

import argparse
import copy
import json
import platform
import tempfile
import time
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from results_io import save_results
from rich.console import Console

from calib.data import Frame, open_dataset
from calib.data.real_fixtures import check_fixtures, realdata_root
from calib.geometry import calibration_error, perturb
from calib.refine.passes import CalibrateConfig, load_calibrate_config
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config
from supportnet import Calibrator  # builds the config's matcher, the learned one too

LEVELS = {"0": (0.0, 0.0), "2": (10.0, 2.0), "5": (25.0, 5.0), "10": (50.0, 10.0)}
"""Start errors: level name (its rotation in °) -> (cm, °). ``0`` starts at the reference itself."""
SUCCESS = {"multi": (2.0, 0.2), "single": (5.0, 0.5)}
"""Success: final error within (cm, °), for several frames and for one."""
VARIANTS = {
    "dense": "dense",
    "global": "global+dense",
    "contour": "contour+dense",
    "global-contour": "global+contour+dense",
    "global-pyramid": "global+pyramid+dense",  # the packaged calibrate.yaml
    "flow-global": "flow+global+dense",  # the learned matcher (its own pyramid-free passes)
}
PYRAMID_FOCALS_PX = (90.0, 180.0)
"""The ``pyramid`` variants' coarser working focal lengths (``pyramid_focals_px``)."""
ALL6 = "kitti-raw-0928-all6"
KITTI_RES = {"width": 1242, "height": 375, "fx": 721.5, "fy": 721.5, "cx": 609.6, "cy": 172.9}
ZED_HALF = {"width": 960, "height": 540, "fx": 527.0, "fy": 527.0, "cx": 479.5, "cy": 269.5}
SYNTH_CAMERAS = {"urban": KITTI_RES, "vineyard": ZED_HALF}
SYNTH_SEEDS = (201, 202)
"""Unseen seeds (training uses small ones, bench_check 101–104); run ``i`` uses ``SYNTH_SEEDS[i % 2]``."""
SYNTH_FRAMES = 10
RESULTS = Path(__file__).parent / "results"

console = Console(stderr=True, highlight=False, soft_wrap=True)


@dataclass
class Dataset:
    """One benchmark dataset: ``frames(run)`` the frames of run ``run`` (synthetic sequences
    alternate seeds), with the reference ``T_cam_lidar (4, 4)`` they carry."""

    name: str
    frames: Callable[[int], tuple[list[Frame], np.ndarray, dict]]
    count: int


def variant_configs(names: list[str]) -> dict[str, CalibrateConfig]:
    """Each variant's config: the packaged one with the global coarse stage, the contour
    refinement, the matcher pyramid (:data:`PYRAMID_FOCALS_PX`) and the learned flow matcher
    switched on as the name says."""
    base = load_calibrate_config()

    def switched(name: str) -> CalibrateConfig:
        stages = name.split("-")
        return base.model_copy(
            update={
                "coarse": base.coarse.model_copy(update={"enabled": "global" in stages}),
                "contour": base.contour.model_copy(update={"enabled": "contour" in stages}),
                "pyramid_focals_px": PYRAMID_FOCALS_PX if "pyramid" in stages else (),
                "matcher": "flow" if "flow" in stages else "edge",
            }
        )

    return {name: switched(name) for name in names}


def draw_start(
    T_ref: np.ndarray, cm: float, deg: float, generator: torch.Generator, shell: bool
) -> np.ndarray:
    """``T_ref · Δ``: ``Δ`` of uniformly random rotation axis and translation direction, of size
    ``(cm, deg)`` exactly (``shell``) or uniform in the ball of that radius (each size
    ``radius · u^(1/3)``, the radial law of a uniform draw in a 3-ball)."""
    if not shell:
        u = torch.rand(2, generator=generator, dtype=torch.float64).numpy()
        cm, deg = cm * float(u[0]) ** (1 / 3), deg * float(u[1]) ** (1 / 3)
    return perturb(T_ref, cm, deg, generator)


def converged(passes: list[dict], config: CalibrateConfig) -> bool:
    """Whether the dense passes settled: the last pass moved less than ``min_update_cm`` and
    ``min_update_deg`` (they stopped early) rather than running out of passes."""
    if not passes:
        return False
    update = passes[-1]["update"]
    return update["translation_cm"] < config.min_update_cm and update["rotation_deg"] < config.min_update_deg


def one_run(
    frames: list[Frame], T_start: np.ndarray, T_ref: np.ndarray, config: CalibrateConfig, seed: int
) -> dict:
    start_error = calibration_error(T_start, T_ref)
    run: dict = {"start": {"cm": start_error.translation_cm, "deg": start_error.rotation_deg}}
    clock = time.perf_counter()
    try:
        result = Calibrator(config=config).calibrate(frames, T_init=T_start, seed=seed)
    except Exception as error:  # noqa: BLE001 (a benchmark records every failure and goes on)
        run.update(
            final=None,
            seconds=time.perf_counter() - clock,
            converged=False,
            raised=f"{type(error).__name__}: {error}",
        )
        return run
    final = calibration_error(result.T_cam_lidar, T_ref)
    run.update(
        final={"cm": final.translation_cm, "deg": final.rotation_deg},
        final_xyz={"cm": list(final.translation_xyz_cm), "deg": list(final.rotation_xyz_deg)},
        seconds=time.perf_counter() - clock,
        converged=converged(result.passes, config),
        raised=None,
        passes=len(result.passes),
    )
    return run


def _p(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


def summarise(runs: list[dict], frames: int) -> dict:
    """Success rate (raised runs count as failures), median and 90th percentile of the final
    errors of the runs that returned, median seconds."""
    cm_ok, deg_ok = SUCCESS["multi" if frames > 1 else "single"]
    done = [r for r in runs if r["final"] is not None]
    success = [r["final"]["cm"] <= cm_ok and r["final"]["deg"] <= deg_ok for r in done]
    cm = [r["final"]["cm"] for r in done]
    deg = [r["final"]["deg"] for r in done]
    return {
        "runs": len(runs),
        "frames": frames,
        "threshold_cm_deg": [cm_ok, deg_ok],
        "success_rate": sum(success) / len(runs) if runs else None,
        "raised": len(runs) - len(done),
        "converged": sum(r["converged"] for r in runs),
        "cm_median": _p(cm, 50),
        "cm_p90": _p(cm, 90),
        "deg_median": _p(deg, 50),
        "deg_p90": _p(deg, 90),
        "start_cm_median": _p([r["start"]["cm"] for r in runs], 50),
        "start_deg_median": _p([r["start"]["deg"] for r in runs], 50),
        "seconds_median": _p([r["seconds"] for r in runs], 50),
    }


def _loaded(path: Path, camera: str | None) -> tuple[list[Frame], np.ndarray, dict]:
    with open_dataset(path, camera=camera) as seq:
        frames = [seq[i] for i in range(len(seq))]
        return frames, np.asarray(seq.calibration.T_cam_lidar, np.float64), {}


def real_datasets(work: Path, notes: dict) -> Iterator[Dataset]:
    root = realdata_root()
    if root is None:
        print("real fixtures absent (../shared/realdata, SUPPORTNET_REALDATA): skipped")
        return
    raw: dict[str, tuple[list[Frame], np.ndarray]] = {}
    for fixture in check_fixtures(root, work):
        frames, T_ref, _ = _loaded(fixture.path, fixture.camera)
        if fixture.name.startswith("kitti-raw"):
            raw[fixture.name] = (frames, T_ref)
        yield Dataset(fixture.name, lambda _run, f=frames, T=T_ref: (f, T, {}), len(frames))
    (a, T_a), (b, T_b) = raw["kitti-raw-0928"], raw["kitti-raw-0928-more"]
    same = bool(np.array_equal(T_a, T_b) and np.array_equal(a[0].K, b[0].K))
    notes[ALL6] = (
        f"{len(a)} + {len(b)} frames of the two folders; their calibrations (T_cam_lidar and K) are "
        + ("equal" if same else "NOT equal: the first folder's is the reference")
    )
    if not same:
        console.print(f"[red]{notes[ALL6]}[/red]")
    merged = [*a, *b]
    yield Dataset(ALL6, lambda _run: (merged, T_a, {}), len(merged))


def synthetic_datasets(seeds: tuple[int, ...] = SYNTH_SEEDS) -> Iterator[Dataset]:
    cache: dict[tuple, tuple[list[Frame], np.ndarray]] = {}

    def sequence(world: str, timing: dict, seed: int) -> tuple[list[Frame], np.ndarray]:
        key = (world, tuple(timing.items()), seed)
        if key not in cache:
            if len(cache) >= len(seeds):
                cache.clear()  # a dataset's sequences in memory at a time (its runs alternate them)
            config = load_synth_config(world, camera=SYNTH_CAMERAS[world], timing=timing)
            synth = Synthesizer(config, SYNTH_FRAMES, seed=seed)
            cache[key] = ([synth.render(i).frame for i in range(SYNTH_FRAMES)], synth.T_cam_lidar)
        return cache[key]

    for world in ("urban", "vineyard"):
        for suffix, timing in (("offset0", {"camera_offset_s": 0.0}), ("offset", {})):
            name = f"synth-{world}-{suffix}"

            def frames(run: int, world=world, timing=timing) -> tuple[list[Frame], np.ndarray, dict]:
                seed = seeds[run % len(seeds)]
                f, T = sequence(world, timing, seed)
                return f, T, {"seed": seed}

            yield Dataset(name, frames, SYNTH_FRAMES)


def bench_dataset(
    dataset: Dataset, levels: list[str], configs: dict, runs: int, shell: bool, progress: dict
) -> dict:
    row: dict = {"frames": dataset.count, "levels": {}}
    for level in levels:
        cm, deg = LEVELS[level]
        count = 1 if level == "0" else runs
        per_variant: dict[str, list[dict]] = {v: [] for v in configs}
        for i in range(count):
            frames, T_ref, extra = dataset.frames(i)
            generator = torch.Generator().manual_seed(zlib.crc32(f"{dataset.name}/{level}/{i}".encode()))
            T_start = draw_start(T_ref, cm, deg, generator, shell)
            for variant, config in configs.items():
                run = {"run": i, **extra, **one_run(frames, T_start, T_ref, config, seed=i)}
                per_variant[variant].append(run)
                progress["done"] += 1
                console.print(progress_line(dataset.name, level, variant, run, progress))
        day = time.strftime("%Y-%m-%d")  # rows of several runs are merged (--merge): each keeps its day
        row["levels"][level] = {
            v: {"summary": summarise(r, dataset.count), "runs": r, "measured": day}
            for v, r in per_variant.items()
        }
    return row


def progress_line(name: str, level: str, variant: str, run: dict, progress: dict) -> str:
    start, final = run["start"], run["final"]
    end = (
        f"{final['cm']:6.2f} cm / {final['deg']:5.2f}°"
        if final is not None
        else f"[red]raised {run['raised'][:80]}[/red]"
    )
    elapsed = time.perf_counter() - progress["clock"]
    return (
        f"[{progress['done']}/{progress['total']} {elapsed:5.0f} s] {name} level {level} "
        f"{VARIANTS[variant]} run {run['run']}: {start['cm']:5.1f} cm / {start['deg']:4.1f}° -> {end} "
        f"in {run['seconds']:.1f} s"
    )


HEADER = (
    f"{'dataset':28s} {'fr':>2s} {'level':>10s} {'variant':>12s} {'runs':>4s} {'success':>7s} "
    f"{'cm med':>7s} {'cm p90':>7s} {'° med':>6s} {'° p90':>6s} {'raised':>6s} {'s/calib':>7s}"
)


def _f(value: float | None, spec: str) -> str:
    return format(value, spec) if value is not None else "–"


def table_lines(name: str, row: dict) -> list[str]:
    lines = []
    for level, variants in row["levels"].items():
        cm, deg = LEVELS[level]
        for variant, entry in variants.items():
            s = entry["summary"]
            lines.append(
                f"{name:28s} {row['frames']:2d} {f'{deg:g}°/{cm:g}cm':>10s} {VARIANTS[variant]:>12s} "
                f"{s['runs']:4d} {_f(s['success_rate'], '7.0%')} {_f(s['cm_median'], '7.2f')} "
                f"{_f(s['cm_p90'], '7.2f')} {_f(s['deg_median'], '6.3f')} {_f(s['deg_p90'], '6.3f')} "
                f"{s['raised']:6d} {_f(s['seconds_median'], '7.1f')}"
            )
    return lines


def merged(earlier: dict, new: dict) -> dict:
    """``new`` with the datasets, levels and variants of ``earlier`` that it did not run (a
    benchmark in parts); ``runs`` and ``seconds`` become lists, one entry per part."""
    for part in ("real", "synthetic"):
        rows = dict(earlier.get(part, {}))
        for name, row in new[part].items():
            before = rows.get(name, {}).get("levels", {})
            levels = {level: dict(variants) for level, variants in before.items()}
            for level, variants in row["levels"].items():
                levels[level] = {**levels.get(level, {}), **variants}
            rows[name] = {**row, "levels": levels}
        new[part] = rows
    new["levels"] = {**earlier.get("levels", {}), **new["levels"]}
    new["variants"] = {**earlier.get("variants", {}), **new["variants"]}
    new["configs"] = {**earlier.get("configs", {}), **new["configs"]}
    new["notes"] = {**earlier.get("notes", {}), **new["notes"]}
    for key in ("runs", "seconds"):
        before = earlier.get(key, [])
        new[key] = [*(before if isinstance(before, list) else [before]), new[key]]
    return new


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20, help="runs per dataset, level and variant")
    parser.add_argument(
        "--levels",
        default="2,5,10",
        help="start errors by their rotation: 2 (2°/10 cm), 5, 10; 0: the reference",
    )
    parser.add_argument("--only", choices=("real", "synthetic"), default=None)
    parser.add_argument("--fixtures", default=None, help="comma-separated dataset names (default: all)")
    parser.add_argument(
        "--variants",
        default="global,global-pyramid",
        help="dense; global (global coarse + dense); global-pyramid (the packaged config: global "
        "coarse, the matcher pyramid, dense); contour (contour refinement + dense); "
        "global-contour (all three)",
    )
    parser.add_argument(
        "--merge", action="store_true", help="keep the other datasets of an earlier bench_real.json"
    )
    parser.add_argument(
        "--shell", action="store_true", help="starts of exactly the level's size, not in its ball"
    )
    parser.add_argument(
        "--synth-seeds",
        default=",".join(map(str, SYNTH_SEEDS)),
        help="synthetic sequences' seeds, run i uses the (i mod n)-th (a config tuned on the default "
        "seeds is measured honestly on others)",
    )
    args = parser.parse_args()
    synth_seeds = tuple(int(s) for s in args.synth_seeds.split(","))
    levels = args.levels.split(",")
    variants = args.variants.split(",")
    if bad := [x for x in levels if x not in LEVELS] + [v for v in variants if v not in VARIANTS]:
        parser.error(f"unknown level or variant: {', '.join(bad)}")
    wanted = set(args.fixtures.split(",")) if args.fixtures else None
    configs = variant_configs(variants)
    notes: dict = {}
    results: dict = {
        "levels": {k: LEVELS[k] for k in levels},
        "success_cm_deg": SUCCESS,
        "variants": {v: VARIANTS[v] for v in variants},
        "configs": {v: c.model_dump(mode="json") for v, c in configs.items()},
        "runs": args.runs,
        "start_draw": "shell" if args.shell else "ball",
        "synthetic_seeds": list(synth_seeds),
        "machine": f"{platform.machine()}, {platform.python_version()}",
        "real": {},
        "synthetic": {},
        "notes": notes,
    }
    clock = time.perf_counter()
    earlier_path = RESULTS / "bench_real.json"
    earlier = json.loads(earlier_path.read_text()) if args.merge and earlier_path.is_file() else None

    def save() -> Path:
        """Write what has run so far (merged over the earlier file with --merge): a long run cut
        short keeps the datasets it finished."""
        results["seconds"] = time.perf_counter() - clock
        done = copy.deepcopy(results)
        return save_results("bench_real", done if earlier is None else merged(copy.deepcopy(earlier), done))

    with tempfile.TemporaryDirectory() as work:
        sources = []
        if args.only != "synthetic":
            sources.append(("real", real_datasets(Path(work), notes)))
        if args.only != "real":
            sources.append(("synthetic", synthetic_datasets(synth_seeds)))
        datasets = [(part, d) for part, source in sources for d in source]
        known = [d.name for _, d in datasets]
        if wanted is not None and (unknown := wanted - set(known)):
            parser.error(f"unknown datasets: {', '.join(sorted(unknown))}; known: {', '.join(known)}")
        datasets = [(part, d) for part, d in datasets if wanted is None or d.name in wanted]
        per_dataset = sum(1 if level == "0" else args.runs for level in levels) * len(variants)
        progress = {"done": 0, "total": per_dataset * len(datasets), "clock": clock}
        print(HEADER, flush=True)
        for part, dataset in datasets:
            row = bench_dataset(dataset, levels, configs, args.runs, args.shell, progress)
            results[part][dataset.name] = row
            print("\n".join(table_lines(dataset.name, row)), flush=True)
            save()
    for name, note in notes.items():
        print(f"{name}: {note}")
    print(f"wrote {save()} in {time.perf_counter() - clock:.0f} s")


if __name__ == "__main__":
    main()
