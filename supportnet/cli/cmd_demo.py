"""``supportnet demo``: the whole pipeline on a small default, with a report a person reads.

1. A small vineyard and urban sequence (held-out seed: the shipped predictor never saw them).
2. Stage 2 + 3 offline: EdgeMatcher residuals under the reference, support maps (Eq. 2), and the
   paper's class-wise residual chart (Experiments 1 and 2).
3. Stage 1 from motion (KISS-ICP, OpenCV, hand–eye), or its report of what the motion cannot tell.
4. Stage 4 from a 10 cm / 2° error: uniform vs SGIS with the offline map vs SGIS with the map the
   shipped predictor makes from the image alone, paired runs.
5. The conventions checked on every real fixture (when ``../shared/realdata`` is found): contour
   alignment under the reference against 1° perturbations, with overlays.

Writes ``report.md`` (tables, Fig. 1-style overlays, support maps, class-wise charts) with every
stage's own output folder beside it.
"""

from __future__ import annotations

import contextlib
import re
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from rich.console import Console
from rich.progress import track
from rich.table import Table

from calib.data import Frame, open_dataset
from calib.data.io import write_image
from calib.data.real_fixtures import real_scenes, realdata_root
from calib.features import contour_check
from calib.geometry import perturb
from calib.projection import project_scan
from supportnet.cli.output_dir import atomic_output, write_json
from supportnet.report.pictures import draw_projection

__all__ = ["run_demo", "synthetic_scenes"]

DEMO_SEED = 9
DRIVES = {"vineyard": {}, "urban": {"start_before_turn_m": 1.0}}
"""The vineyard drives down a row (Stage 1 refuses it, and says why); the urban car turns a corner."""


def synthetic_scenes(workdir: Path, frames: int = 3) -> list[tuple[str, Frame, np.ndarray | None]]:
    """One frame of a small synthetic sequence of each world, written and read back."""
    from calib.synth.generate import Synthesizer, write_sequence
    from calib.synth.synth_config import load_synth_config

    scenes = []
    for world in ("vineyard", "urban"):
        write_sequence(Synthesizer(load_synth_config(world), frames, seed=0), workdir / world, "00")
        with open_dataset(workdir / world, sequence="00") as seq:
            scenes.append((f"synthetic {world}", seq[frames - 1], None))
    return scenes


def run_demo(out: Path, overwrite: bool = False, frames: int = 40, runs: int = 3) -> None:
    console = Console()
    realdata = realdata_root()
    start = time.perf_counter()
    with atomic_output(out, overwrite) as tmp, tempfile.TemporaryDirectory() as work:
        pipeline = [
            run_pipeline(world, tmp / world, frames, runs, console) for world in ("vineyard", "urban")
        ]
        with console.status("generating synthetic sequences"):
            scenes = synthetic_scenes(Path(work))
        if realdata is not None:
            scenes += real_scenes(realdata, Path(work))
        else:
            console.print("real fixtures not found (set SUPPORTNET_REALDATA): synthetic scenes only")
        table = Table(title="Contour alignment: reference vs 1° perturbations (higher = on image edges)")
        for col in ("scene", "contour pts", "reference", "perturbed mean", "ratio"):
            table.add_column(col, justify="left" if col == "scene" else "right")
        results = {}
        for name, frame, ring in track(scenes, description="checking conventions", console=console):
            check = contour_check(frame, ring)
            results[name] = check
            table.add_row(
                name,
                str(check["contour_points"]),
                f"{check['reference']:.3f}",
                f"{check['perturbed_mean']:.3f}",
                f"{check['ratio']:.2f}",
            )
            T = frame.calibration.T_cam_lidar
            slug = name.replace(" ", "_")
            for label, T_used in (
                ("reference", T),
                ("perturbed_1deg", perturb(T, 0.0, 1.0, torch.Generator().manual_seed(1))),
            ):
                projected = project_scan(frame.points, T_used, frame.K, frame.image_size)
                write_image(tmp / f"overlay_{slug}_{label}.png", draw_projection(frame.image, projected))
        console.print(table)
        write_json(tmp / "contour_alignment.json", results)
        report = _report(pipeline, results, frames, runs, time.perf_counter() - start)
        (tmp / "report.md").write_text(report)
    console.print(_stage4_table(pipeline), markup=False, highlight=False)
    console.print(f"report written to [bold]{out / 'report.md'}[/] in {time.perf_counter() - start:.0f} s")


def run_pipeline(world: str, out: Path, frames: int, runs: int, console: Console) -> dict:
    """Stages 1 to 4 on a fresh ``frames``-frame sequence of ``world``; their folders under ``out``."""
    from calib.errors import NumericalError
    from calib.init.motion_init import load_stage1_config
    from calib.refine.passes import load_calibrate_config
    from calib.support.support_maps import load_maps_config
    from calib.synth.generate import Synthesizer, write_sequence
    from calib.synth.synth_config import load_synth_config
    from supportnet.cli.cmd_analyze import run_analyze
    from supportnet.cli.cmd_calibrate import run_calibrate
    from supportnet.cli.cmd_init_calib import run_init_calib
    from supportnet.cli.cmd_maps import run_maps

    console.rule(f"{world}: {frames} frames")
    out.mkdir(parents=True)
    with contextlib.chdir(out):  # relative paths: the report and every result.json name what is beside them
        data = Path("data")
        with console.status(f"synthesising {frames} {world} frames"):
            synth = Synthesizer(load_synth_config(world, drive=DRIVES[world]), frames, DEMO_SEED)
            write_sequence(synth, data, "09", workers=2)
        maps = run_maps(data, "09", Path("maps"), load_maps_config(), console=console)
        run_analyze(data, ["09"], Path("classes"), load_maps_config(), maps=maps, console=console)
        try:
            stage1 = run_init_calib(data, "09", Path("stage1"), load_stage1_config(), console=console)
        except NumericalError as exc:  # the motion cannot tell: the report says what, and the demo goes on
            stage1 = {"refused": str(exc)}
            console.print(f"Stage 1: {exc}", markup=False, highlight=False, soft_wrap=True)
        stage4 = run_calibrate(
            data,
            "09",
            "uniform,offline:maps,onnx",
            "perturb:10,2",
            Path("stage4"),
            load_calibrate_config(),
            runs,
            console=console,
        )
    return {"world": world, "stage1": stage1, "stage4": stage4}


def _stage4_table(pipeline: list[dict]) -> str:
    lines = [
        "| world | support | translation cm mean / median | rotation ° mean / median | beats uniform t / r |",
        "|---|---|---|---|---|",
    ]
    for item in pipeline:
        results, paired = item["stage4"]["results"], item["stage4"]["paired_vs_uniform"]
        for name, r in results.items():
            t, rot = r["summary"]["translation_cm"], r["summary"]["rotation_deg"]
            label = {"uniform": "uniform", "onnx": "SGIS, predicted map"}.get(name, "SGIS, offline map")
            wins = paired.get(name)
            won = (
                f"{wins['translation_wins']}/{wins['runs']}, {wins['rotation_wins']}/{wins['runs']}"
                if wins
                else ""
            )
            lines.append(
                f"| {item['world']} | {label} | {t['mean']:.2f} / {t['median']:.2f} | "
                f"{rot['mean']:.3f} / {rot['median']:.3f} | {won} |"
            )
    return "\n".join(lines)


def _report(pipeline: list[dict], contours: dict, frames: int, runs: int, seconds: float) -> str:
    """``report.md``: what the demo did, its tables, and the pictures to look at."""
    lines = [
        "# supportnet demo",
        "",
        f"{frames}-frame synthetic sequences (seed {DEMO_SEED}, held out from the shipped predictor), "
        f"{runs} paired Stage 4 runs from a 10 cm / 2° error per support; {seconds:.0f} s in all.",
        "",
        "## Stage 4: uniform vs support-guided sampling",
        "",
        _stage4_table(pipeline),
        "",
    ]
    for item in pipeline:
        world, stage4 = item["world"], item["stage4"]
        lines += [f"## {world}", "", "### Stage 1 (from motion)", ""]
        stage1 = item["stage1"]
        if "refused" in stage1:
            lines += [f"Refused, with the reason: {stage1['refused']}", ""]
        else:
            e = stage1["error"]
            weak = "; ".join(w["text"] for w in stage1["weak"]) or "none"
            lines += [
                f"Rotation error {e['rotation_deg']:.2f}°, translation {e['translation_cm']:.1f} cm "
                f"(translation from the {stage1['translation_source']}); weak: {weak}.",
                "",
                f"![trajectories]({world}/stage1/trajectories.png)",
                "",
            ]
        lines += ["### Overlays: initial error (red) and after Stage 4 (green)", ""]
        for name in stage4["results"]:
            slug = re.sub(r"[^A-Za-z0-9]+", "_", name).strip("_")
            lines += [f"{name.split(':')[0]}: ![overlay]({world}/stage4/overlay_{slug}.png)", ""]
            if name != "uniform":
                lines += [
                    f"support map ({name.split(':')[0]}): ![support]({world}/stage4/support_{slug}.png)",
                    "",
                ]
        lines += [
            "### Matcher residuals by class (Experiments 1 and 2)",
            "",
            f"![classes]({world}/classes/residuals_by_class.png)",
            "",
        ]
    lines += [
        "## Conventions on real data: contour alignment, reference vs 1° perturbations",
        "",
        "| scene | contour points | reference | perturbed mean | ratio |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| {n} | {r['contour_points']} | {r['reference']:.3f} | {r['perturbed_mean']:.3f} | "
        f"{r['ratio']:.2f} |"
        for n, r in contours.items()
    ]
    return "\n".join(lines) + "\n"
