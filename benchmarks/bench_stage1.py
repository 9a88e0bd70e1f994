"""Stage 1's success rate: how often it returns a right rotation, returns a wrong one, or refuses.

Per world, ``--per-world`` synthetic sequences (seeds ``--first-seed`` on; the thresholds were
chosen on seeds 100–111 and 1000–1019, so the default 2000 on are unseen), each a short drive
whose length and start before the first turn follow from its seed: vineyard 40, 80 or 120 frames
starting 0–8 m before a headland U-turn (a pure turn, a turn with a straight, a row with no turn);
urban 40 or 60 frames starting 0–30 m before a corner. Small camera (624x188), default Stage 1
config.

Every run goes through Stage 1 with the refusal switched off, then :func:`check_motion` with the
shipped thresholds decides as Stage 1 would: so a refused run still shows the rotation it would
have returned. A run **succeeds** when it returns a rotation within ``--max-rotation-deg`` (2°:
where Stage 4's benchmarks start) of the truth; the translation is the prior (zero) by design and
is reported, not judged. **Wrong** = returned beyond that; the aim is none.

    python benchmarks/bench_stage1.py [--per-world 20] [--first-seed 1000] [--worlds vineyard,urban]

Prints a table (median and 90th percentile) and writes benchmarks/results/stage1.json; ``--table
PATH`` prints the table of a JSON it wrote. "wrong w/o tests": runs that got an answer from the
hand–eye solve and would have returned it beyond the criterion before these tests existed.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from results_io import save_results

from calib.data.types import MemorySequence
from calib.geometry import calibration_error
from calib.init.degeneracy import DegenerateMotionError, check_motion
from calib.init.hand_eye import UnobservableError
from calib.init.motion_init import initial_calibration, load_stage1_config
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config

WORLDS = ("vineyard", "urban")
DRIVES = {  # frame counts, and the range of the distance driven before the first turn (m)
    "vineyard": ((40, 80, 120), (0.0, 8.0)),
    "urban": ((40, 60), (0.0, 30.0)),
}


def drive_of(world: str, seed: int) -> tuple[int, float]:
    """The frame count and the metres before the first turn of ``seed``'s sequence."""
    counts, (low, high) = DRIVES[world]
    rng = np.random.default_rng([seed, 7])
    return int(counts[seed % len(counts)]), round(float(rng.uniform(low, high)), 1)


def run(world: str, seed: int, max_rotation_deg: float, pairs: Path | None = None) -> dict:
    """One sequence through Stage 1: outcome, errors, diagnostics, time (``pairs``: a folder to
    keep the motion pairs and the truth in, ``<world>_<seed>.npz``, to study the tests offline)."""
    frames, before_turn = drive_of(world, seed)
    config = load_stage1_config()
    report_only = config.model_copy(
        update={"degeneracy": config.degeneracy.model_copy(update={"refuse": False})}
    )
    start = time.perf_counter()
    synth = Synthesizer(
        load_synth_config(world, small=True, drive={"start_before_turn_m": before_turn}), frames, seed=seed
    )
    sequence = MemorySequence(
        [item.frame for item in synth.frames()],
        synth.calibration,
        f"synthetic {synth.config.world} seed {synth.seed}",
        layout="synthetic",
    )
    row = {"world": world, "seed": seed, "frames": frames, "start_before_turn_m": before_turn}
    row["synth_s"] = time.perf_counter() - start
    start = time.perf_counter()
    try:
        result = initial_calibration(sequence, report_only)
    except UnobservableError as exc:  # before the tests: too few rotating pairs, no parallax
        row.update(outcome="refused", reason=str(exc), seconds=time.perf_counter() - start)
        row.update(rotation_deg=None, translation_cm=None, diagnostics=None)
        return row
    seconds = time.perf_counter() - start
    if pairs is not None:
        pairs.mkdir(parents=True, exist_ok=True)
        A = np.stack([m.T for m, k in zip(result.motions, result.kept, strict=True) if k])
        np.savez(pairs / f"{world}_{seed}.npz", A=A, B=result.lidar_motions, X=synth.T_cam_lidar)
    error = calibration_error(result.T_cam_lidar, synth.T_cam_lidar)
    try:
        check_motion(result.diagnostics, config.degeneracy)
        outcome, reason = ("correct" if error.rotation_deg <= max_rotation_deg else "wrong"), ""
    except DegenerateMotionError as exc:
        outcome, reason = "refused", str(exc)
    row.update(
        outcome=outcome,
        reason=reason,
        seconds=seconds,
        degeneracy_s=result.seconds["degeneracy"],
        rotation_deg=error.rotation_deg,  # for a refused run: what it would have returned
        translation_cm=error.translation_cm,
        hand_eye_translation_cm=calibration_error(
            result.calibration.T_cam_lidar, synth.T_cam_lidar
        ).translation_cm,
        diagnostics=result.diagnostics.to_dict(),
    )
    return row


def summary(rows: list[dict], max_rotation_deg: float) -> dict:
    """Counts, success rate and the median / 90th percentile of errors and times."""
    returned = [r for r in rows if r["outcome"] != "refused"]
    refused = [r for r in rows if r["outcome"] == "refused"]
    would = [r["rotation_deg"] for r in refused if r["rotation_deg"] is not None]

    def stats(values: list[float]) -> dict:
        if not values:
            return {"median": None, "p90": None}
        return {"median": float(np.median(values)), "p90": float(np.percentile(values, 90))}

    return {
        "sequences": len(rows),
        "correct": sum(r["outcome"] == "correct" for r in rows),
        "wrong": sum(r["outcome"] == "wrong" for r in rows),
        "refused": len(refused),
        "refused_before_tests": sum(r["diagnostics"] is None for r in refused),
        "refused_would_have_been_wrong": sum(v > max_rotation_deg for v in would),
        # what Stage 1 returned before the tests existed: every run that got as far as an answer
        "without_tests_wrong": sum(
            r["rotation_deg"] is not None and r["rotation_deg"] > max_rotation_deg for r in rows
        ),
        "success_rate": sum(r["outcome"] == "correct" for r in rows) / max(len(rows), 1),
        "returned_rotation_deg": stats([r["rotation_deg"] for r in returned]),
        "returned_translation_cm": stats([r["translation_cm"] for r in returned]),
        "refused_would_be_rotation_deg": stats(would),
        "stage1_s": stats([r["seconds"] for r in rows]),
        "degeneracy_s": stats([r["degeneracy_s"] for r in rows if "degeneracy_s" in r]),
    }


def _number(value: float | str | None) -> str:
    return "–" if value is None else (value if isinstance(value, str) else f"{value:.2f}")


def _line(row: dict) -> str:
    """One run's progress line."""
    diag = row["diagnostics"] or {}
    return (
        f"{row['world']:8} seed {row['seed']} {row['frames']:3d} frames, turn at "
        f"{row['start_before_turn_m']:4.1f} m: {row['outcome']:7} rotation {_number(row['rotation_deg'])}° "
        f"std {_number(diag.get('rotation_std_deg'))}° halves {_number(diag.get('subset_spread_deg'))}° "
        f"axes {_number(diag.get('axis_spread'))} ({row['seconds']:.0f} s) {row['reason'][:100]}"
    )


def _cell(stats: dict, fmt: str = ".2f") -> str:
    if stats["median"] is None:
        return "–"
    return f"{stats['median']:{fmt}} / {stats['p90']:{fmt}}"


def table(runs: dict[str, list[dict]], first_seed: int, max_rotation_deg: float) -> dict:
    """Print the table; return the per-world summaries."""
    summaries = {world: summary(rows, max_rotation_deg) for world, rows in runs.items()}
    count = max(len(rows) for rows in runs.values())
    print(
        f"\nStage 1 on {count} synthetic sequences per world (seeds {first_seed}–{first_seed + count - 1}); "
        f"success: returned within {max_rotation_deg:g}°; wrong: returned beyond"
    )
    print(
        f"{'world':9} {'success':>7} {'correct':>7} {'wrong':>5} {'refused':>7} {'(would be wrong)':>16} "
        f"{'wrong w/o tests':>15} {'returned rot ° med/p90':>22} {'refused: would-be °':>20} "
        f"{'Stage 1 s':>9}"
    )
    for world, s in summaries.items():
        print(
            f"{world:9} {s['success_rate']:>7.0%} {s['correct']:>7} {s['wrong']:>5} {s['refused']:>7} "
            f"{s['refused_would_have_been_wrong']:>16} {s['without_tests_wrong']:>15} "
            f"{_cell(s['returned_rotation_deg']):>22} {_cell(s['refused_would_be_rotation_deg']):>20} "
            f"{_cell(s['stage1_s'], '.0f'):>9}"
        )
    return summaries


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-world", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=2000)
    parser.add_argument("--worlds", default=",".join(WORLDS))
    parser.add_argument("--max-rotation-deg", type=float, default=2.0)
    parser.add_argument("--name", default="stage1", help="results/<name>.json")
    parser.add_argument("--pairs", type=Path, help="keep each run's motion pairs here (npz)")
    parser.add_argument("--table", type=Path, help="only print the table of a JSON this wrote")
    args = parser.parse_args()
    if args.table:
        stored = json.loads(args.table.read_text())
        table(stored["runs"], stored["seeds"][0], stored["max_rotation_deg"])
        return
    runs: dict[str, list[dict]] = {}
    for world in args.worlds.split(","):
        runs[world] = []
        for seed in range(args.first_seed, args.first_seed + args.per_world):
            row = run(world, seed, args.max_rotation_deg, args.pairs)
            runs[world].append(row)
            print(_line(row), flush=True)
    summaries = table(runs, args.first_seed, args.max_rotation_deg)
    out = save_results(
        args.name,
        {
            "criterion": f"returned with a rotation error ≤ {args.max_rotation_deg:g}° "
            "(the translation is the prior, not judged)",
            "max_rotation_deg": args.max_rotation_deg,
            "seeds": [args.first_seed, args.first_seed + args.per_world - 1],
            "camera": "624x188 (small=True)",
            "degeneracy": load_stage1_config().degeneracy.model_dump(),
            "summary": summaries,
            "runs": runs,
        },
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
