"""``supportnet demo``: the pipeline so far, on a small default.

Today that is the foundation and the test bench: a small synthetic vineyard and urban sequence
generated and read back, every real fixture (when ``../shared/realdata`` is found) read through
its layout reader, the extrinsic conventions checked by contour alignment (reference vs the same
calibration perturbed by 1°), and overlays written for a person to look at. Later stages extend this.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import torch
from rich.console import Console
from rich.progress import track
from rich.table import Table

from calib.data import Frame, open_dataset
from calib.data.io import read_pcd_fields, write_image
from calib.features import contour_alignment, depth_discontinuities, horizontal_gradient
from calib.geometry import perturb
from calib.projection import project_scan
from supportnet.fixtures import (
    AMZ_DRIVE,
    PJLAB_SCENES,
    custom_from_pjlab,
    kitti_object_from_mmdet,
    realdata_root,
)
from supportnet.outputs import atomic_output, write_json
from supportnet.viz import draw_projection

__all__ = ["contour_check", "real_scenes", "run_demo", "synthetic_scenes"]

PERTURBATIONS = 8


def synthetic_scenes(workdir: Path, frames: int = 3) -> list[tuple[str, Frame, np.ndarray | None]]:
    """One frame of a small synthetic sequence of each world, written and read back."""
    from calib.synth.config import load_synth_config
    from calib.synth.generate import Synthesizer, write_sequence

    scenes = []
    for world in ("vineyard", "urban"):
        write_sequence(Synthesizer(load_synth_config(world), frames, seed=0), workdir / world, "00")
        with open_dataset(workdir / world, sequence="00") as seq:
            scenes.append((f"synthetic {world}", seq[frames - 1], None))
    return scenes


def real_scenes(realdata: Path, workdir: Path) -> list[tuple[str, Frame, np.ndarray | None]]:
    """Every real fixture frame as ``(name, frame, ring or None)``, read through the readers."""
    scenes = []
    with open_dataset(realdata / AMZ_DRIVE) as seq:
        scenes += [(f"kitti-raw {f.name}", f, None) for f in seq]
    with open_dataset(kitti_object_from_mmdet(realdata, workdir / "kitti_object")) as seq:
        scenes += [(f"kitti-object {f.name}", f, None) for f in seq]
    for scene in PJLAB_SCENES:
        with open_dataset(custom_from_pjlab(realdata, scene, workdir / f"pjlab{scene}")) as seq:
            ring = read_pcd_fields(seq.scan_paths[0])[0]["ring"].astype(np.int64)
            scenes.append((f"pjlab {scene}", seq[0], ring))
    return scenes


def contour_check(frame: Frame, ring: np.ndarray | None, seed: int = 0) -> dict:
    """Contour alignment under the reference and under ``PERTURBATIONS`` seeded 1° rotations."""
    T = frame.calibration.T_cam_lidar
    contour, _ = depth_discontinuities(frame.points, ring)
    generator = torch.Generator().manual_seed(seed)
    edges = horizontal_gradient(frame.image)
    reference = contour_alignment(edges, frame.points, contour, T, frame.K)
    perturbed = [
        contour_alignment(edges, frame.points, contour, perturb(T, 0.0, 1.0, generator), frame.K)
        for _ in range(PERTURBATIONS)
    ]
    return {
        "contour_points": len(contour),
        "reference": reference,
        "perturbed_mean": float(np.mean(perturbed)),
        "perturbed_max": float(np.max(perturbed)),
        "ratio": reference / float(np.mean(perturbed)),
    }


def run_demo(out: Path, overwrite: bool = False) -> None:
    console = Console()
    realdata = realdata_root()
    with atomic_output(out, overwrite) as tmp, tempfile.TemporaryDirectory() as work:
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
        lines = [
            "# supportnet demo",
            "",
            "| scene | contour points | reference | perturbed mean | ratio |",
            "|---|---|---|---|---|",
        ]
        lines += [
            f"| {n} | {r['contour_points']} | {r['reference']:.3f} | "
            f"{r['perturbed_mean']:.3f} | {r['ratio']:.2f} |"
            for n, r in results.items()
        ]
        (tmp / "summary.md").write_text("\n".join(lines) + "\n")
    console.print(f"report written to [bold]{out}[/]")
