"""``supportnet demo``: the whole pipeline on a small default, with a report a person reads.

1. A small vineyard and urban sequence (held-out seed: the shipped predictor never saw them),
   rendered at the small 624x188 size (``load_synth_config(small=True)``), not the worlds'
   full-resolution default: the demo must stay fast, and the shipped models were trained on it.
2. Stage 2 + 3 offline: EdgeMatcher residuals under the reference, support maps (Eq. 2), and the
   paper's class-wise residual chart (Experiments 1 and 2).
3. Stage 1 from motion (KISS-ICP, OpenCV, hand–eye), or its report of what the motion cannot tell.
4. Stage 4 from a 10 cm / 2° error: uniform vs SGIS with the offline map vs SGIS with the map the
   shipped predictor makes from the image alone, paired runs.
5. The conventions checked on every real fixture (when ``../shared/realdata`` is found): contour
   alignment under the reference against 1° perturbations, with overlays.

Writes ``report.md`` and the self-contained ``report.html`` (the same document: tables, figures
with colour bars and captions, a comment on every surprising number; :mod:`supportnet.report.demo_page`),
the figures under ``figures/``, and every stage's own output folder beside them.
"""

from __future__ import annotations

import contextlib
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from rich.console import Console
from rich.progress import track
from rich.table import Table

from calib.data import Frame, open_dataset
from calib.data.real_fixtures import real_scenes, realdata_root
from calib.features import contour_check
from calib.geometry import perturb
from calib.projection import ProjectedScan, project_scan
from supportnet.cli.console import make_console
from supportnet.cli.output_dir import atomic_output, claim_output, write_json
from supportnet.report.demo_page import (
    SceneCheck,
    WorldRun,
    build_demo_page,
    caption_colour_problems,
    class_chart_figure,
    drive_speed,
    projection_figure,
    support_figure,
    write_demo_page,
)
from supportnet.report.document import Document, Figure, to_markdown
from supportnet.report.pictures import trajectories_chart

__all__ = ["run_demo", "synthetic_scenes"]

DEMO_SEED = 9
SEQUENCE = "09"
DRIVES = {"vineyard": {}, "urban": {"start_before_turn_m": 1.0}}
"""The vineyard drives down a row (Stage 1 refuses it, and says why); the urban car turns a corner."""


def synthetic_scenes(workdir: Path, frames: int = 3) -> list[tuple[str, Frame, np.ndarray | None]]:
    """One frame of a small (624x188) synthetic sequence of each world, written and read back."""
    from calib.synth.generate import Synthesizer, write_sequence
    from calib.synth.synth_config import load_synth_config

    scenes = []
    for world in ("vineyard", "urban"):
        write_sequence(
            Synthesizer(load_synth_config(world, small=True), frames, seed=0), workdir / world, "00"
        )
        with open_dataset(workdir / world, sequence="00") as seq:
            scenes.append((f"synthetic {world}", seq[frames - 1], None))
    return scenes


def run_demo(out: Path, overwrite: bool = False, frames: int = 40, runs: int = 3) -> None:
    claim_output(Path(out), overwrite)
    console = make_console(stderr=False)
    realdata = realdata_root()
    start = time.perf_counter()
    with atomic_output(out, overwrite, command="demo") as tmp, tempfile.TemporaryDirectory() as work:
        worlds = [run_pipeline(world, tmp / world, frames, runs, console) for world in ("vineyard", "urban")]
        with console.status("drawing the figures"):
            for world in worlds:
                world_figures(tmp, world)
        with console.status("generating synthetic sequences"):
            scenes = synthetic_scenes(Path(work))
        if realdata is not None:
            scenes += real_scenes(realdata, Path(work))
        else:
            console.print("real fixtures not found (set SUPPORTNET_REALDATA): synthetic scenes only")
        table = Table(title="Contour alignment: reference vs 1° perturbations (higher = on image edges)")
        for col in ("scene", "contour pts", "reference", "perturbed mean", "ratio"):
            table.add_column(col, justify="left" if col == "scene" else "right")
        checks = []
        for name, frame, ring in track(scenes, description="checking conventions", console=console):
            check = contour_check(frame, ring)
            table.add_row(
                name,
                str(check["contour_points"]),
                f"{check['reference']:.3f}",
                f"{check['perturbed_mean']:.3f}",
                f"{check['ratio']:.2f}",
            )
            checks.append(SceneCheck(name, check, convention_figure(tmp, name, frame)))
        console.print(table)
        write_json(tmp / "contour_alignment.json", {c.name: c.result for c in checks})
        doc = build_demo_page(
            worlds, checks, runs, time.perf_counter() - start, str(realdata) if realdata else None
        )
        for problem in caption_colour_problems(tmp, doc.figures()):
            console.print(f"report: {problem}", markup=False, highlight=False, soft_wrap=True)
        write_demo_page(doc, tmp)
    stage4 = next(s for s in doc.sections if s.title.startswith("Stage 4"))
    console.print(to_markdown(Document("Stage 4", blocks=stage4.blocks[:1])), markup=False, highlight=False)
    console.print(
        f"report written to [bold]{out / 'report.html'}[/] and [bold]{out / 'report.md'}[/] "
        f"in {time.perf_counter() - start:.0f} s"
    )


def run_pipeline(world: str, out: Path, frames: int, runs: int, console: Console) -> WorldRun:
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
            synth = Synthesizer(load_synth_config(world, small=True, drive=DRIVES[world]), frames, DEMO_SEED)
            write_sequence(synth, data, SEQUENCE, workers=2)
        maps = run_maps(data, SEQUENCE, Path("maps"), load_maps_config(), console=console)
        classes = run_analyze(
            data, [SEQUENCE], Path("classes"), load_maps_config(), maps=maps, console=console
        )
        try:
            stage1 = run_init_calib(data, SEQUENCE, Path("stage1"), load_stage1_config(), console=console)
        except NumericalError as exc:  # the motion cannot tell: the report says what, and the demo goes on
            stage1 = {"refused": str(exc)}
            console.print(f"Stage 1: {exc}", markup=False, highlight=False, soft_wrap=True)
        stage4 = run_calibrate(
            data,
            SEQUENCE,
            "uniform,offline:maps,onnx",
            "perturb:10,2",
            Path("stage4"),
            load_calibrate_config(),
            runs,
            console=console,
        )
        with open_dataset(data, sequence=SEQUENCE) as seq:
            speed = drive_speed(seq.poses, seq.timestamps)
    return WorldRun(world, out.name, SEQUENCE, DEMO_SEED, frames, stage1, stage4, classes, speed_mps=speed)


def world_figures(root: Path, world: WorldRun) -> None:
    """The figures of one world's run, under ``root / "figures"``, into ``world.figures``: the
    class-wise chart, Stage 1's trajectories, each support map with its colour bar and each
    support's overlay before and after Stage 4 (the first paired run, on the first frame it used)."""
    from calib.refine.passes import load_calibrate_config
    from calib.support.class_residuals import ClassStats
    from supportnet.cli.cmd_analyze import MIN_POINTS
    from supportnet.runtime.support_sources import resolve_support

    root = Path(root).resolve()  # absolute: the support figures are drawn inside chdir(folder)
    w, folder = world.world, root / world.folder
    stats = [ClassStats(**s) for s in world.classes["classes"]["all"] if s["points"] >= MIN_POINTS]
    world.figures["classes"] = class_chart_figure(
        root,
        f"figures/{w}_residuals_by_class.png",
        stats,
        f"{world.label}: {world.classes.get('matcher', 'edge')} matcher residuals under the reference",
        f"Residuals by class, {world.label}, under the reference extrinsic (the paper's Experiments 1 "
        "and 2).",
        alt=f"{w}: matcher residuals by class",
    )
    stage1 = folder / "stage1"
    if "refused" not in world.stage1 and (stage1 / "lidar.kitti").is_file():
        rel = f"figures/{w}_stage1_trajectories.png"
        poses = [_kitti_poses(stage1 / name) for name in ("lidar.kitti", "camera.kitti")]
        trajectories_chart(*poses, root / rel, f"Stage 1 trajectories, {world.label}, camera-0 frame")
        world.figures["trajectories"] = Figure(
            rel,
            f"Stage 1 trajectories, {world.label}, in the camera-0 frame, from above (left) and from "
            "the side (right): the blue line is LiDAR odometry (KISS-ICP), the orange dots are the "
            "visual odometry keyframes, scaled and aligned by the hand–eye solve (both are in "
            f"[`{world.folder}/stage1/`]({world.folder}/stage1/) as KITTI and TUM pose files).",
            alt=f"{w}: Stage 1 trajectories",
        )
    results = world.stage4["results"]
    first_run = {name: r["runs"][0] for name, r in results.items()}
    index = next(iter(first_run.values()))["frame_indices"][0]
    support_map = load_calibrate_config().support_map
    maps = {}
    with contextlib.chdir(folder), open_dataset(Path("data"), sequence=world.sequence) as seq:
        frame = seq[int(index)]
        for name, run in first_run.items():
            slug = "".join(c if c.isalnum() else "_" for c in name).strip("_")
            label = {"uniform": "uniform sampling", "onnx": "SGIS, predicted map"}.get(
                name, "SGIS, offline map"
            )
            before, after = (np.array(run[k]) for k in ("initial_T_cam_lidar", "T_cam_lidar"))
            e0, e1 = run.get("initial_error"), run.get("error")
            errors = (
                f" Error against the reference: {e0['translation_cm']:.1f} cm / {e0['rotation_deg']:.2f}° "
                f"before, {e1['translation_cm']:.1f} cm / {e1['rotation_deg']:.2f}° after."
                if e0 and e1
                else ""
            )
            world.figures[f"overlay:{name}"] = projection_figure(
                root,
                f"figures/{w}_overlay_{slug}.png",
                [
                    (
                        "initial extrinsic (reference moved by 10 cm / 2 deg)",
                        frame.image,
                        _project(frame, before),
                    ),
                    (f"after Stage 4 with {label}", frame.image, _project(frame, after)),
                ],
                f"Stage 4 with {label}, {world.label}, frame {frame.index}: the scan under the initial "
                f"extrinsic (top) and under the estimate (bottom), first paired run.{errors}",
                alt=f"{w}: overlay before and after Stage 4 with {label}",
            )
            if name == "uniform":
                continue
            values = resolve_support(name, support_map)(frame)
            maps[name] = values
            kind = (
                "predicted by the shipped model from the image alone"
                if name.startswith("onnx")
                else ("offline, from the matcher under the reference over the whole sequence (Eq. 2)")
            )
            world.figures[f"support:{name}"] = support_figure(
                root,
                f"figures/{w}_support_{slug}.png",
                frame.image,
                values,
                f"Support map `{name}`, {kind}; {world.label}, frame {frame.index}.",
                alt=f"{w}: support map {name}",
            )
    offline = [v for k, v in maps.items() if k.startswith("offline")]
    predicted = [v for k, v in maps.items() if k.startswith("onnx")]
    if offline and predicted and offline[0].std() > 0 and predicted[0].std() > 0:
        world.map_agreement = float(np.corrcoef(offline[0].ravel(), predicted[0].ravel())[0, 1])


def _kitti_poses(path: Path) -> np.ndarray:
    """``(N, 4, 4)`` poses of a KITTI pose file (one row-major 3x4 matrix a line)."""
    rows = np.loadtxt(path, ndmin=2).reshape(-1, 3, 4)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3] = rows
    return poses


def _project(frame: Frame, T: np.ndarray) -> ProjectedScan:
    return project_scan(frame.points, T, frame.K, frame.image_size)


def convention_figure(root: Path, name: str, frame: Frame) -> Figure:
    """The scan under the reference (top) and rotated by 1° (bottom), on the scene's image."""
    T = frame.calibration.T_cam_lidar
    T_off = perturb(T, 0.0, 1.0, torch.Generator().manual_seed(1))
    slug = "".join(c if c.isalnum() else "_" for c in name)
    return projection_figure(
        root,
        f"figures/conventions_{slug}.png",
        [
            ("reference extrinsic", frame.image, _project(frame, T)),
            ("reference rotated by 1 deg", frame.image, _project(frame, T_off)),
        ],
        f"{name}: the scan under the reference extrinsic, read through its layout's convention (top), "
        "and under the reference rotated by 1° (bottom); under the right convention depth edges meet "
        "image edges.",
        alt=f"{name}: reference and 1 degree perturbed",
    )
