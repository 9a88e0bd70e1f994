"""Stage 2 side by side: the learned flow matcher against the EdgeMatcher on held-out sequences.

Every 8th frame of a sequence (every frame of a real fixture) is matched under fixed random
extrinsic errors of 1°, 2°, 5° and 10° with 5 cm per degree (seeded per frame); a point's
endpoint error is the distance from its matched pixel to where the reference extrinsic projects
it. Medians and 90th percentiles over each matcher's own points, the share of residuals pointing
toward the reference, medians over the points every matcher returned ("common": the EdgeMatcher
keeps only confident ones) and by class (rigid structure, foliage), beside the error of not
matching at all, the points each matcher returns and milliseconds per frame. Then the final
calibration error of Stage 4 with
either matcher, with uniform sampling and with SGIS on the predicted support map: ``--runs``
paired runs from 10 cm / 2° on an 80-frame held-out sequence of each world (the same initial
draws for every matcher and support). Prints tables and writes benchmarks/results/flow_matcher.json.

    python benchmarks/bench_flow_matcher.py [--data build/model/vineyard:09 ...] [--model FILE]
        [--compare NAME=FILE ...] [--real] [--runs 10]

``--compare`` adds other learned models beside ``--model`` (named ``flow``), matched on the same
frames and draws in the same run.

Without ``--data`` it synthesises one 40-frame full-resolution sequence of each world with seed 9
(held out: the shipped flow matcher trained on seeds 101-116) in a temporary folder; ``--real``
adds every real fixture in ../shared/realdata. The Stage 4 runs use small 624x188 sequences
(seed 9), as the shipped support predictor was trained on.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from results_io import save_results
from rich.console import Console

from calib.data import open_dataset
from calib.data.classes import RIGID_CLASSES
from calib.data.real_fixtures import check_fixtures, realdata_root
from calib.data.types import Frame
from calib.geometry import perturb
from calib.match.edge_matcher import EdgeMatcher
from calib.projection import project_points, transform_points
from calib.refine.passes import load_calibrate_config
from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config
from supportnet.cli.cmd_calibrate import paired_wins, run_calibrate
from supportnet.runtime.flow_matcher import SHIPPED_FLOW_MODEL, FlowMatcher
from train.flow_module import FOLIAGE_CLASSES

LEVELS = (1, 2, 5, 10)
"""Extrinsic errors (°) the matchers are compared at, each with :data:`CM_PER_DEG` cm per degree
(``bench_real``'s 2° / 10 cm and 10° / 50 cm)."""
CM_PER_DEG = 5.0


def _true_uv(points: np.ndarray, T: np.ndarray, K: np.ndarray) -> np.ndarray:
    uv, _ = project_points(
        transform_points(torch.from_numpy(T), torch.from_numpy(points)), torch.from_numpy(K)
    )
    return uv.numpy()


def _held_out(world: str, tmp: Path) -> str:
    """A 40-frame full-resolution sequence of ``world`` with seed 9 under ``tmp`` (held out: the
    shipped matcher trained on seeds 101-116), as ``root:sequence``."""
    write_sequence(Synthesizer(load_synth_config(world), 40, seed=9), tmp / world, "09")
    return f"{tmp / world}:09"


def _frames(data: str, camera: str | None, stride: int) -> list[Frame]:
    """Every ``stride``-th frame of ``root[:sequence]``."""
    root, _, sequence = data.rpartition(":") if ":" in Path(data).name else (data, "", "")
    with open_dataset(Path(root), sequence=sequence or None, camera=camera) as seq:
        return [seq[i] for i in range(0, len(seq), stride)]


def _stats(epe: np.ndarray) -> tuple[float | None, float | None]:
    return (float(np.median(epe)), float(np.percentile(epe, 90))) if len(epe) else (None, None)


def evaluate(frames: list[Frame], matchers: dict) -> dict:
    """Endpoint errors, capture and timings of each matcher at each error of :data:`LEVELS`.

    A point's endpoint error is the distance from its matched pixel to where the reference puts
    it; it *points toward the reference* when its residual has a positive component along the
    true one (the share of such points is a matcher's capture: Stage 4 moves the right way where
    most do)."""
    out = {}
    for deg in LEVELS:
        cm = CM_PER_DEG * deg
        errors = {
            name: {k: [] for k in ("all", "rigid", "foliage", "none", "common", "toward")}
            for name in matchers
        }
        seconds = {name: [] for name in matchers}
        for i, frame in enumerate(frames):
            T_ref = frame.calibration.T_cam_lidar
            T_init = perturb(T_ref, cm, deg, torch.Generator().manual_seed(i))
            found = {}
            for name, matcher in matchers.items():
                start = time.perf_counter()
                found[name] = matcher.match(frame, T_init)
                seconds[name].append(time.perf_counter() - start)
            common = set.intersection(*(set(corr.index.tolist()) for corr in found.values()))
            for name, corr in found.items():
                truth = _true_uv(corr.points_lidar, T_ref, frame.K)
                e = errors[name]
                epe = np.linalg.norm(corr.uv_matched - truth, axis=1)
                e["common"].append(epe[np.isin(corr.index, list(common))])
                e["all"].append(epe)
                e["none"].append(np.linalg.norm(corr.uv - truth, axis=1))
                e["toward"].append(((corr.uv_matched - corr.uv) * (truth - corr.uv)).sum(1) > 0)
                if frame.labels is not None:
                    labels = np.asarray(frame.labels)[corr.index]
                    e["rigid"].append(epe[np.isin(labels, list(RIGID_CLASSES))])
                    e["foliage"].append(epe[np.isin(labels, list(FOLIAGE_CLASSES))])
        for name in matchers:
            e = {k: np.concatenate(v) if v else np.zeros(0) for k, v in errors[name].items()}
            median, p90 = _stats(e["all"])
            out[f"{deg:g}/{name}"] = {
                "error_cm_deg": (cm, deg),
                "epe_median_px": median,
                "epe_p90_px": p90,
                "toward_reference": float(e["toward"].mean()) if len(e["toward"]) else None,
                "epe_median_rigid_px": _stats(e["rigid"])[0],
                "epe_median_foliage_px": _stats(e["foliage"])[0],
                "epe_median_common_px": _stats(e["common"])[0],
                "no_matching_median_px": _stats(e["none"])[0],
                "points_per_frame": len(e["all"]) / len(frames),
                "ms_per_frame": 1000 * float(np.median(seconds[name][1:] or seconds[name])),
            }
    return out


def calibration(world: str, tmp: Path, model: Path, runs: int) -> dict:
    """Stage 4's final errors with each matcher and support, and flow's paired wins over edge."""
    data = tmp / f"{world}_calibrate"
    write_sequence(Synthesizer(load_synth_config(world, small=True), 80, seed=9), data, "09")
    runs_of, out = {}, {}
    for matcher in ("edge", "flow"):
        config = load_calibrate_config().model_copy(update={"matcher": matcher, "flow_model": model})
        result = run_calibrate(
            data, "09", "uniform,onnx", "perturb:10,2", tmp / f"out_{world}_{matcher}", config, runs,
            console=Console(stderr=True, quiet=True),
        )  # fmt: skip
        for support, r in result["results"].items():
            runs_of[matcher, support] = r["runs"]
            out[f"{matcher}/{support}"] = r["summary"]
    for support in ("uniform", "onnx"):
        out[f"flow_vs_edge/{support}"] = paired_wins(runs_of["flow", support], runs_of["edge", support])
    return out


def _print_calibration(rows: dict) -> None:
    print("\nStage 4 from 10 cm / 2 deg, paired runs (onnx = SGIS on the predicted support map)")
    print(
        f"{'world':10} {'matcher/support':16} {'t mean':>7} {'t med':>7} {'R mean':>7} {'R med':>7} "
        f"{'flow won t/R':>13}"
    )
    for world, result in rows.items():
        for key, s in result.items():
            if key.startswith("flow_vs_edge"):
                continue
            t, r = s["translation_cm"], s["rotation_deg"]
            wins = result.get(f"flow_vs_edge/{key.split('/')[1]}") if key.startswith("flow") else None
            won = f"{wins['translation_wins']}/{wins['rotation_wins']} of {wins['runs']}" if wins else ""
            print(
                f"{world:10} {key:16} {t['mean']:>7.2f} {t['median']:>7.2f} {r['mean']:>7.3f} "
                f"{r['median']:>7.3f} {won:>13}"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", nargs="+", help="root:sequence of held-out sequences")
    parser.add_argument("--model", type=Path, default=SHIPPED_FLOW_MODEL)
    parser.add_argument(
        "--compare", nargs="+", default=[], metavar="NAME=FILE", help="more learned models, same draws"
    )
    parser.add_argument(
        "--real", action="store_true", help="also the real KITTI fixtures (../shared/realdata)"
    )
    parser.add_argument("--runs", type=int, default=10, help="paired calibration runs (0: none)")
    args = parser.parse_args()
    matchers = {"edge": EdgeMatcher(), "flow": FlowMatcher(args.model)}
    for entry in args.compare:
        name, sep, path = entry.partition("=")
        if not sep or name in matchers:
            parser.error(f"--compare takes NAME=FILE with a new name, not {entry!r}")
        matchers[name] = FlowMatcher(path)
    with tempfile.TemporaryDirectory() as tmp:
        data = {
            Path(d).name: (d, None, 8)
            for d in args.data or [_held_out(w, Path(tmp)) for w in ("vineyard", "urban")]
        }
        real = realdata_root() if args.real else None
        if real is not None:  # every real fixture, whole (no labels there: the class columns stay empty)
            data |= {f.name: (str(f.path), f.camera, 1) for f in check_fixtures(real, Path(tmp) / "real")}
        rows = {}
        for name, (path, camera, stride) in data.items():
            rows[name] = evaluate(_frames(path, camera, stride), matchers)
            print(f"{name}: done", flush=True)
        calibrated = (
            {world: calibration(world, Path(tmp), args.model, args.runs) for world in ("vineyard", "urban")}
            if args.runs
            else {}
        )
    print(
        "endpoint errors in pixels (median, 90th percentile); toward: share of residuals pointing "
        f"toward the reference; errors of {CM_PER_DEG:g} cm per degree"
    )
    columns = (
        ("all", 6),
        ("p90", 6),
        ("toward", 6),
        ("common", 6),
        ("rigid", 6),
        ("foliage", 8),
        ("none", 6),
        ("pts/frame", 10),
        ("ms", 6),
    )
    print(f"{'sequence':26} {'deg/matcher':12} " + " ".join(f"{name:>{width}}" for name, width in columns))
    fmt = lambda v, spec=".2f": format(v, spec) if v is not None else "-"  # noqa: E731
    for data_name, result in rows.items():
        for key, r in result.items():
            print(
                f"{data_name:26} {key:12} {fmt(r['epe_median_px']):>6} {fmt(r['epe_p90_px']):>6} "
                f"{fmt(r['toward_reference']):>6} {fmt(r['epe_median_common_px']):>6} "
                f"{fmt(r['epe_median_rigid_px']):>6} {fmt(r['epe_median_foliage_px']):>8} "
                f"{fmt(r['no_matching_median_px']):>6} {r['points_per_frame']:>10.0f} "
                f"{r['ms_per_frame']:>6.0f}"
            )
    if calibrated:
        _print_calibration(calibrated)
    save_results(
        "flow_matcher",
        {
            "levels_deg": LEVELS,
            "cm_per_deg": CM_PER_DEG,
            "model": str(args.model),
            "compared": dict(entry.partition("=")[::2] for entry in args.compare),
            "sequences": rows,
            "calibration": calibrated,
        },
    )


if __name__ == "__main__":
    main()
