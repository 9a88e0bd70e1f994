"""Accuracy: Stage 4 with uniform sampling vs SGIS on the offline map vs SGIS on the predicted map,
both worlds, paired runs from a 10 cm / 2° error; and Stage 1 from motion on 300-frame sequences.

Everything is synthesised in a temporary folder with fixed seeds: Stage 4 on the held-out seed 9
(80 frames, the shipped predictor never saw it), Stage 1 on seed 21, all at the small 624x188 size
the shipped predictor was trained on (``small=True``), or with ``--full-res`` Stage 4 at the
worlds' real pixel scale (urban 1242x375, vineyard 960x540; the predictor resamples their images
to the 360.8 px it learned at, ``predict_frame``). Prints a table and writes
benchmarks/results/accuracy.json.

    python benchmarks/bench_accuracy.py [--runs 10] [--stage1-frames 300] [--camera-offset-ms MS]
        [--model OTHER.onnx] [--time-offset estimate|off|fixed:MS] [--supports uniform,offline,onnx]
        [--worlds vineyard,urban] [--full-res] [--depth-strata N] [--name accuracy]

``--depth-strata N`` runs each SGIS support once more, from the same starts and sampling seeds,
with ``sampling.depth_strata: N`` (SGIS within N depth quantiles, calib/refine/sgis.py): rows
``NAME/strataN``, their paired wins against the same uniform runs.

The table's last column is each support's median translation error over uniform's (the paper's
Experiment 3 asks whether SGIS lowers it by at least 15 %: a ratio of 0.85 or less).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from results_io import save_results
from rich.console import Console

from calib.errors import NumericalError
from calib.init.motion_init import load_stage1_config
from calib.refine.passes import load_calibrate_config
from calib.support.support_maps import load_maps_config
from supportnet.cli.cmd_calibrate import paired_wins, run_calibrate
from supportnet.cli.cmd_init_calib import run_init_calib
from supportnet.cli.cmd_maps import run_maps
from supportnet.cli.cmd_synth import run_synth
from supportnet.cli.options import time_offset_setting

WORLDS = ("vineyard", "urban")


def stage4(
    world: str,
    tmp: Path,
    runs: int,
    console: Console,
    offset_ms: float | None,
    model: Path | None,
    time_offset: str,
    supports: str,
    small: bool,
    depth_strata: int | None = None,
) -> dict:
    data = tmp / world
    run_synth(world, 80, 9, data, "09", console=console, small=small, camera_offset_ms=offset_ms)
    maps = run_maps(data, "09", tmp / f"maps_{world}", load_maps_config(), console=console)
    supports = supports.replace("offline", f"offline:{maps}") + (f",onnx:{model}" if model else "")
    config = load_calibrate_config()
    config = config.model_copy(update={"time_offset": time_offset_setting(time_offset, config.time_offset)})
    result = run_calibrate(
        data, "09", supports, "perturb:10,2", tmp / f"cal_{world}", config, runs, console=console
    )
    names = {"uniform": "uniform", "onnx": "sgis_predicted", f"offline:{maps}": "sgis_offline"}
    if model:
        names[f"onnx:{model}"] = f"sgis_predicted:{Path(model).name}"
    rows = {
        names[name]: {
            **r["summary"],
            "vs_uniform": result["paired_vs_uniform"].get(name),
        }
        for name, r in result["results"].items()
    }
    sgis = ",".join(name for name in result["results"] if name != "uniform")
    if depth_strata is None or not sgis:
        return rows
    strata = config.model_copy(
        update={"sampling": config.sampling.model_copy(update={"depth_strata": depth_strata})}
    )
    stratified = run_calibrate(
        data, "09", sgis, "perturb:10,2", tmp / f"cal_{world}_strata", strata, runs, console=console
    )
    uniform = result["results"].get("uniform")
    for name, r in stratified["results"].items():
        rows[f"{names[name]}/strata{depth_strata}"] = {
            **r["summary"],
            "vs_uniform": paired_wins(r["runs"], uniform["runs"]) if uniform else None,
        }
    return rows


def stage1(world: str, tmp: Path, frames: int, console: Console) -> dict:
    data = tmp / f"{world}_s1"
    run_synth(world, frames, 21, data, "01", console=console, small=True)
    start = time.perf_counter()
    try:
        r = run_init_calib(data, "01", tmp / f"s1_{world}", load_stage1_config(), console=console)
    except NumericalError as exc:
        return {"refused": str(exc)}
    return {
        "rotation_deg": r["error"]["rotation_deg"],
        "translation_cm": r["error"]["translation_cm"],
        "translation_source": r["translation_source"],
        "hand_eye_translation_cm": r["hand_eye_error"]["translation_cm"],
        "seconds": time.perf_counter() - start,
        "weak": [w["text"] for w in r["weak"]],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--stage1-frames", type=int, default=300, help="0: no Stage 1 benchmark")
    parser.add_argument(
        "--camera-offset-ms", type=float, default=None, help="Stage 4's camera offset (default: the worlds')"
    )
    parser.add_argument("--model", type=Path, default=None, help="another support predictor, run beside")
    parser.add_argument("--time-offset", default="estimate", help="Stage 4's: off, estimate or fixed:MS")
    parser.add_argument("--supports", default="uniform,offline,onnx", help="offline: seed 9's maps")
    parser.add_argument("--worlds", default=",".join(WORLDS))
    parser.add_argument("--full-res", action="store_true", help="Stage 4 at the worlds' real pixel scale")
    parser.add_argument(
        "--depth-strata", type=int, default=None, help="each SGIS support again with sampling.depth_strata N"
    )
    parser.add_argument("--name", default="accuracy", help="results/NAME.json")
    args = parser.parse_args()
    console = Console(stderr=True)
    with tempfile.TemporaryDirectory() as tmp:
        rows = {
            "stage4": {
                w: stage4(
                    w,
                    Path(tmp),
                    args.runs,
                    console,
                    args.camera_offset_ms,
                    args.model,
                    args.time_offset,
                    args.supports,
                    small=not args.full_res,
                    depth_strata=args.depth_strata,
                )
                for w in args.worlds.split(",")
            },
            "stage1": {w: stage1(w, Path(tmp), args.stage1_frames, console) for w in WORLDS}
            if args.stage1_frames
            else {},
        }
    rows["runs"], rows["stage1_frames"] = args.runs, args.stage1_frames
    rows["camera_offset_ms"], rows["time_offset"] = args.camera_offset_ms, args.time_offset
    rows["full_res"], rows["depth_strata"] = args.full_res, args.depth_strata
    print(f"Stage 4 from 10 cm / 2°, {args.runs} paired runs (mean / median)")
    head = ("t cm mean", 9), ("median", 7), ("r ° mean", 9), ("median", 7), ("wins t/r", 9), ("t/unif", 7)
    print(f"{'world':9} {'support':24} " + " ".join(f"{n:>{w}}" for n, w in head))
    for world, supports in rows["stage4"].items():
        for name, s in supports.items():
            t, r, wins = s["translation_cm"], s["rotation_deg"], s["vs_uniform"]
            won = f"{wins['translation_wins']}/{wins['rotation_wins']}" if wins else ""
            uniform = supports["uniform"]["translation_cm"]["median"]
            s["translation_median_over_uniform"] = t["median"] / uniform
            print(
                f"{world:9} {name:24} {t['mean']:>9.2f} {t['median']:>7.2f} {r['mean']:>9.3f} "
                f"{r['median']:>7.3f} {won:>9} {s['translation_median_over_uniform']:>7.2f}"
            )
    if rows["stage1"]:
        print(f"Stage 1 on {args.stage1_frames} frames")
    for world, s in rows["stage1"].items():
        if "refused" in s:
            print(f"{world:9} refused: {s['refused']}")
        else:
            print(
                f"{world:9} rotation {s['rotation_deg']:.2f}°, translation {s['translation_cm']:.1f} cm "
                f"({s['translation_source']}; hand–eye's own {s['hand_eye_translation_cm']:.0f} cm), "
                f"{s['seconds']:.0f} s"
            )
    save_results(args.name, rows)


if __name__ == "__main__":
    main()
