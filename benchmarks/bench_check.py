"""``supportnet check`` (:mod:`calib.verify`) on every real fixture and on synthetic worlds: the
reference extrinsic, and seeded draws of 1° / 5 cm and 0.5° / 2.5 cm errors in random directions.

Real fixtures (``../shared/realdata``, converted by :func:`calib.data.real_fixtures.check_fixtures`):
the two KITTI raw 2011_09_28 folders (grey camera 0), KITTI object 000008 (cropped scan) and 000114
(full scan), the six nuScenes cameras, and the same six as one rig (``nuscenes-rig``), the three
PJLab scenes. Synthetic: urban and vineyard at
KITTI's pixel scale (1242x375, f = 721.5), still (no wind, no camera time offset), unseen seeds,
one frame and five frames; these are where the thresholds were set.

Prints a table (verdict of the reference, share of perturbed draws called bad and suspect, scores,
the smallest error each dataset shows) and writes ``benchmarks/results/check.json``.

    .venv/bin/python benchmarks/bench_check.py [--draws 8] [--only real|synthetic] [--fixtures NAMES]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np
import torch
from results_io import RESULTS, save_results

from calib.data import Frame, open_dataset
from calib.data.real_fixtures import check_fixtures, realdata_root
from calib.data.rig import as_rig, unknown_reference
from calib.geometry import calibration_error, perturb
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config
from calib.verify import CheckConfig, check_extrinsic

SIZES = {"1deg_5cm": (5.0, 1.0), "0.5deg_2.5cm": (2.5, 0.5)}
"""Perturbations drawn around the reference: name -> (cm, °)."""
FULL_RES = {"width": 1242, "height": 375, "fx": 721.5, "fy": 721.5, "cx": 609.6, "cy": 172.9}
STILL = {"wind": {"amplitude_m": 0.0}, "timing": {"camera_offset_s": 0.0}, "camera": FULL_RES}
SYNTH_SEEDS = (101, 102, 103, 104)
NUSCENES_RIG = "nuscenes-rig"


def roll_share(T: np.ndarray, T_ref: np.ndarray) -> float:
    """How much of ``T``'s rotation error is about the camera's optical axis (roll), in [0, 1]:
    the direction a single frame sees least."""
    omega = np.asarray(calibration_error(T, T_ref).rotation_xyz_deg)
    axis = np.asarray(T_ref)[2, :3]  # the optical axis in LiDAR coordinates
    norm = float(np.linalg.norm(omega))
    return abs(float(omega @ axis)) / norm if norm > 0 else 0.0


def one_check(frames: list[Frame], T: np.ndarray, T_ref: np.ndarray, config: CheckConfig) -> dict:
    result = check_extrinsic(frames, T, config)
    c, d = result.correction, result.detectable
    return {
        "verdict": result.verdict,
        "roll_share": roll_share(T, T_ref),
        "significance": result.significance["joint"],
        "significance_rotation": result.significance["rotation"],
        "significance_translation": result.significance["translation"],
        "peak_share": result.peak_share,
        "score": result.score,
        "alignment": result.alignment,
        "correction_deg": c.rotation_deg,
        "correction_cm": c.translation_cm,
        "suggested_error": calibration_error(result.suggested_T_cam_lidar, T_ref).to_dict(),
        "detectable_deg": d["rotation_deg"],
        "detectable_cm": d["translation_cm"],
        "detectable_per_axis": {k: d[k] for k in ("per_axis", "bootstrap_per_axis", "peak_per_axis")},
        "seconds": result.runtime_s,
    }


def dataset_row(name: str, frames: list[Frame], T_ref: np.ndarray, config: CheckConfig, draws: int) -> dict:
    row: dict = {"frames": len(frames), "reference": one_check(frames, T_ref, T_ref, config)}
    for size, (cm, deg) in SIZES.items():
        generator = torch.Generator().manual_seed(zlib.crc32(f"{name}/{size}".encode()))
        checks = [one_check(frames, perturb(T_ref, cm, deg, generator), T_ref, config) for _ in range(draws)]
        verdicts = [c["verdict"] for c in checks]
        row[size] = {
            "bad": verdicts.count("bad") / draws,
            "suspect": verdicts.count("suspect") / draws,
            "good": verdicts.count("good") / draws,
            "significance": [c["significance"] for c in checks],
            "checks": checks,
        }
    return row


def real_rows(config: CheckConfig, draws: int, wanted: set[str] | None = None) -> dict:
    """Every real fixture's row (or those named in ``wanted``), and ``nuscenes-rig``: the one
    nuScenes sweep seen by its six cameras checked as one rig (:mod:`calib.data.rig`; the
    extrinsic checked is CAM_FRONT's, the rig's frame)."""
    root = realdata_root()
    if root is None:
        print("real fixtures absent (../shared/realdata, SUPPORTNET_REALDATA): skipped")
        return {}
    rows, nuscenes = {}, []
    with tempfile.TemporaryDirectory() as work:
        for fixture in check_fixtures(root, Path(work)):
            with open_dataset(fixture.path, camera=fixture.camera) as seq:
                frames = [seq[i] for i in range(len(seq))][: config.frames]
                if fixture.name.startswith("nuscenes-cam"):
                    nuscenes += frames
                if wanted is not None and fixture.name not in wanted:
                    continue
                rows[fixture.name] = dataset_row(
                    fixture.name, frames, seq.calibration.T_cam_lidar, config, draws
                )
            print(line(fixture.name, rows[fixture.name]), flush=True)
    if wanted is None or NUSCENES_RIG in wanted:
        rig = as_rig(nuscenes)
        rows[NUSCENES_RIG] = dataset_row(
            NUSCENES_RIG, rig, unknown_reference(rig[0].calibration), config, draws
        )
        print(line(NUSCENES_RIG, rows[NUSCENES_RIG]), flush=True)
    return rows


def synthetic_rows(config: CheckConfig, draws: int) -> dict:
    rows = {}
    for world in ("urban", "vineyard"):
        for seed in SYNTH_SEEDS:
            synth = Synthesizer(load_synth_config(world, **STILL), 5, seed=seed)
            frames = [synth.render(i).frame for i in range(5)]
            T_ref = frames[0].calibration.T_cam_lidar
            for count in (1, 5):
                name = f"synth-{world}-{seed}-{count}f"
                rows[name] = dataset_row(name, frames[:count], T_ref, config, draws)
                print(line(name, rows[name]), flush=True)
    return rows


HEADER = (
    f"{'dataset':26s} {'fr':>2s} {'reference':>9s} {'m':>5s} {'align':>5s} "
    f"{'1°/5cm bad':>10s} {'susp':>5s} {'0.5°/2.5cm bad':>14s} {'susp':>5s} "
    f"{'detect °':>8s} {'cm':>5s} {'s':>4s}"
)


def line(name: str, row: dict) -> str:
    ref = row["reference"]
    big, small = row["1deg_5cm"], row["0.5deg_2.5cm"]
    seconds = np.mean([c["seconds"] for c in big["checks"]] + [ref["seconds"]])
    return (
        f"{name:26s} {row['frames']:2d} {ref['verdict']:>9s} {ref['significance']:5.1f} "
        f"{ref['alignment']:5.2f} {big['bad']:10.0%} {big['suspect']:5.0%} {small['bad']:14.0%} "
        f"{small['suspect']:5.0%} {ref['detectable_deg']:8.2f} {ref['detectable_cm']:5.1f} {seconds:4.1f}"
    )


def summary(rows: dict) -> dict:
    if not rows:
        return {}
    return {
        "datasets": len(rows),
        "reference_good": sum(r["reference"]["verdict"] == "good" for r in rows.values()),
        "reference_bad": sum(r["reference"]["verdict"] == "bad" for r in rows.values()),
        "1deg_5cm_all_bad": sum(r["1deg_5cm"]["bad"] == 1.0 for r in rows.values()),
        "1deg_5cm_bad_share": float(np.mean([r["1deg_5cm"]["bad"] for r in rows.values()])),
        "1deg_5cm_good_share": float(np.mean([r["1deg_5cm"]["good"] for r in rows.values()])),
        "0.5deg_2.5cm_bad_share": float(np.mean([r["0.5deg_2.5cm"]["bad"] for r in rows.values()])),
        "1deg_5cm_roll_share_of_missed": _mean_roll(rows, lambda v: v != "bad"),
        "1deg_5cm_roll_share_of_called_bad": _mean_roll(rows, lambda v: v == "bad"),
    }


def _mean_roll(rows: dict, pick) -> float | None:
    shares = [c["roll_share"] for r in rows.values() for c in r["1deg_5cm"]["checks"] if pick(c["verdict"])]
    return float(np.mean(shares)) if shares else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=8, help="perturbed draws per size and dataset")
    parser.add_argument("--only", choices=("real", "synthetic"), default=None)
    parser.add_argument(
        "--fixtures",
        default=None,
        help=f"comma-separated real rows (fixture names, {NUSCENES_RIG}); written to check_fixtures.json",
    )
    args = parser.parse_args()
    config = CheckConfig()
    start = time.perf_counter()
    print(HEADER)
    results: dict = {"config": config.model_dump(mode="json"), "draws": args.draws, "sizes": SIZES}
    earlier = RESULTS / "check.json"
    if args.only and earlier.exists():  # keep the other part when it was made with the same settings
        kept = json.loads(earlier.read_text())
        if kept.get("config") == results["config"] and kept.get("draws") == args.draws:
            other = "synthetic" if args.only == "real" else "real"
            results.update({k: kept[k] for k in (other, f"{other}_summary") if k in kept})
    if args.fixtures:  # a few real rows, kept apart from the README's table
        results["real"] = real_rows(config, args.draws, set(args.fixtures.split(",")))
        print(f"wrote {save_results('check_fixtures', results)}")
        return
    if args.only != "synthetic":
        results["real"] = real_rows(config, args.draws)
        results["real_summary"] = summary(results["real"])
    if args.only != "real":
        results["synthetic"] = synthetic_rows(config, args.draws)
        results["synthetic_summary"] = summary(results["synthetic"])
    results["seconds"] = time.perf_counter() - start
    for part in ("real_summary", "synthetic_summary"):
        if results.get(part):
            print(part, results[part])
    print(f"wrote {save_results('check', results)} in {results['seconds']:.0f} s")


if __name__ == "__main__":
    main()
