"""Stage 2 side by side: the learned flow matcher against the EdgeMatcher on held-out sequences.

Every 8th frame is matched under a fixed random extrinsic error (10 cm / 2°, seeded per frame, as
the flow matcher's validation draws); a point's endpoint error is the distance from its matched
pixel to where the reference extrinsic projects it. Medians over each matcher's own points, over
the points every matcher returned ("common": the EdgeMatcher keeps only confident ones), and by
class (rigid structure, foliage), beside the error of not matching at all, the points each
matcher returns and milliseconds per frame. Then the final calibration error of Stage 4 with
either matcher, with uniform sampling and with SGIS on the predicted support map: ``--runs``
paired runs from 10 cm / 2° on an 80-frame held-out sequence of each world (the same initial
draws for every matcher and support). Prints tables and writes benchmarks/results/flow_matcher.json.

    python benchmarks/bench_flow_matcher.py [--data build/model/vineyard:09 ...] [--model FILE]
        [--real] [--runs 10]

Without ``--data`` it synthesises one 40-frame sequence of each world with seed 9 (held out: the
shipped models trained on seeds 1 to 3) in a temporary folder, at the small 624x188 size the
shipped models were trained on (``small=True``).
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
from calib.data.real_fixtures import kitti_object_from_mmdet, realdata_root
from calib.geometry import perturb
from calib.match.edge_matcher import EdgeMatcher
from calib.projection import project_points, transform_points
from calib.refine.passes import load_calibrate_config
from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config
from supportnet.cli.cmd_calibrate import paired_wins, run_calibrate
from supportnet.runtime.flow_matcher import SHIPPED_FLOW_MODEL, FlowMatcher
from train.flow_module import FOLIAGE_CLASSES

ERROR = (10.0, 2.0)
AMZ_KITTI_RAW = "amz_kitti_raw_0928/data/0928-KITTI-dataset"


def _true_uv(points: np.ndarray, T: np.ndarray, K: np.ndarray) -> np.ndarray:
    uv, _ = project_points(
        transform_points(torch.from_numpy(T), torch.from_numpy(points)), torch.from_numpy(K)
    )
    return uv.numpy()


def _held_out(world: str, tmp: Path) -> str:
    """A 40-frame sequence of ``world`` with seed 9 under ``tmp``, as ``root:sequence``."""
    write_sequence(Synthesizer(load_synth_config(world, small=True), 40, seed=9), tmp / world, "09")
    return f"{tmp / world}:09"


def evaluate(data: str, matchers: dict, stride: int = 8) -> dict:
    """Endpoint errors and timings of each matcher on one sequence (``root:sequence``)."""
    root, _, sequence = data.rpartition(":") if ":" in Path(data).name else (data, "", "")
    errors = {name: {"all": [], "rigid": [], "foliage": [], "none": [], "common": []} for name in matchers}
    seconds = {name: [] for name in matchers}
    with open_dataset(Path(root), sequence=sequence or None) as seq:
        for i in range(0, len(seq), stride):
            frame = seq[i]
            T_ref = frame.calibration.T_cam_lidar
            T_init = perturb(T_ref, *ERROR, torch.Generator().manual_seed(i))
            found = {}
            for name, matcher in matchers.items():
                start = time.perf_counter()
                found[name] = matcher.match(frame, T_init)
                seconds[name].append(time.perf_counter() - start)
            common = set.intersection(*(set(corr.index.tolist()) for corr in found.values()))
            for name, corr in found.items():
                truth = _true_uv(corr.points_lidar, T_ref, frame.K)
                epe = np.linalg.norm(corr.uv_matched - truth, axis=1)
                errors[name]["common"].append(epe[np.isin(corr.index, list(common))])
                labels = np.asarray(frame.labels)[corr.index] if frame.labels is not None else None
                errors[name]["all"].append(epe)
                errors[name]["none"].append(np.linalg.norm(corr.uv - truth, axis=1))
                if labels is not None:
                    errors[name]["rigid"].append(epe[np.isin(labels, list(RIGID_CLASSES))])
                    errors[name]["foliage"].append(epe[np.isin(labels, list(FOLIAGE_CLASSES))])
    out = {}
    for name in matchers:
        e = {k: np.concatenate(v) if v else np.zeros(0) for k, v in errors[name].items()}
        out[name] = {
            "epe_median_px": float(np.median(e["all"])),
            "epe_median_rigid_px": float(np.median(e["rigid"])) if len(e["rigid"]) else None,
            "epe_median_foliage_px": float(np.median(e["foliage"])) if len(e["foliage"]) else None,
            "epe_median_common_px": float(np.median(e["common"])) if len(e["common"]) else None,
            "no_matching_median_px": float(np.median(e["none"])),
            "points_per_frame": len(e["all"]) / len(seconds[name]),
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
        "--real", action="store_true", help="also the real KITTI fixtures (../shared/realdata)"
    )
    parser.add_argument("--runs", type=int, default=10, help="paired calibration runs (0: none)")
    args = parser.parse_args()
    matchers = {"edge": EdgeMatcher(), "flow": FlowMatcher(args.model)}
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data or [_held_out(world, Path(tmp)) for world in ("vineyard", "urban")]
        real = realdata_root() if args.real else None
        if real is not None:  # no labels there: the class columns stay empty
            data += [
                str(real / AMZ_KITTI_RAW),
                str(kitti_object_from_mmdet(real, Path(tmp) / "kitti_object")),
            ]
        rows = {Path(d).name: evaluate(d, matchers) for d in data}
        calibrated = (
            {world: calibration(world, Path(tmp), args.model, args.runs) for world in ("vineyard", "urban")}
            if args.runs
            else {}
        )
    print(f"error {ERROR[0]:.0f} cm / {ERROR[1]:.0f} deg; endpoint error medians in pixels")
    columns = (
        ("all", 6),
        ("common", 6),
        ("rigid", 6),
        ("foliage", 8),
        ("none", 6),
        ("pts/frame", 10),
        ("ms", 6),
    )
    print(f"{'sequence':26} {'matcher':8} " + " ".join(f"{name:>{width}}" for name, width in columns))
    for data, result in rows.items():
        for name, r in result.items():
            fmt = lambda v: f"{v:.2f}" if v is not None else "-"  # noqa: E731
            print(
                f"{data:26} {name:8} {r['epe_median_px']:>6.2f} {fmt(r['epe_median_common_px']):>6} "
                f"{fmt(r['epe_median_rigid_px']):>6} "
                f"{fmt(r['epe_median_foliage_px']):>8} {r['no_matching_median_px']:>6.2f} "
                f"{r['points_per_frame']:>10.0f} {r['ms_per_frame']:>6.0f}"
            )
    if calibrated:
        _print_calibration(calibrated)
    save_results(
        "flow_matcher",
        {"error_cm_deg": ERROR, "model": str(args.model), "sequences": rows, "calibration": calibrated},
    )


if __name__ == "__main__":
    main()
