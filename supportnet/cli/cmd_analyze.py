"""``supportnet analyze``: the paper's Experiments 1 and 2, class-wise matcher residuals under the
reference calibration, over one or more sequences.

Writes ``classes.csv`` (one row per sequence and class, and ``all``), ``classes.json`` (the same,
the class-wise averages, the ranking and where classes came from), ``residuals_by_class.png``
(and one chart per sequence when there are several) and the resolved ``config.yaml``.
"""

from __future__ import annotations

import csv
import time
from dataclasses import asdict
from pathlib import Path
from typing import Literal

import numpy as np
from rich.console import Console
from rich.table import Table

from calib.data import Sequence, open_dataset
from calib.data.kitti_odometry import sequence_names
from calib.errors import DataError, SupportnetError
from calib.projection import pixel_lookup
from calib.support.class_residuals import (
    EXG_CLASSES,
    ClassResiduals,
    ClassSource,
    ClassStats,
    class_source,
    classwise_average,
    point_classes,
)
from calib.support.map_files import check_maps_fingerprint, load_sequence_maps
from calib.support.support_maps import MapsConfig
from supportnet.cli.console import make_console
from supportnet.cli.output_dir import atomic_output, claim_output, progress_bar, resolved_config, write_json
from supportnet.report.pictures import class_residual_chart
from supportnet.runtime.matcher_factory import build_matcher

__all__ = ["run_analyze"]

MIN_POINTS = 50  # classes with fewer residuals are listed but left out of the ranking and chart


def _sequence_support(maps: Path, sequence: str, n_sequences: int, seq: Sequence) -> np.ndarray:
    """The whole-sequence support map of ``sequence`` from ``maps``: a maps folder itself (one
    sequence analysed) or a folder holding one maps folder per sequence, named after it; refused
    when made from another dataset than ``seq``."""
    for folder in (maps / sequence, maps) if n_sequences == 1 else (maps / sequence,):
        if (folder / "sequence.npz").is_file():
            check_maps_fingerprint(folder, seq)
            return load_sequence_maps(folder)["support"]
    raise DataError(maps, f"holds no support maps for sequence {sequence} (expected {maps / sequence})")


def _print_table(stats: list[ClassStats], console: Console) -> None:
    table = Table(title="residuals under the reference, by class (px)", title_justify="left")
    for column in ("class", "points", "mean |Δu|", "mean |Δv|", "med |Δu|", "med |Δv|", "med ‖f‖", "depth"):
        table.add_column(column, justify="left" if column == "class" else "right", no_wrap=True)
    average = classwise_average(stats)
    for s in stats:
        cells = [s.mean_du, s.mean_dv]
        marked = [f"[red]{v:.2f}[/red]" if v > a else f"{v:.2f}" for v, a in zip(cells, average, strict=True)]
        medians = (f"{v:.2f}" for v in (s.median_du, s.median_dv, s.median_norm))
        table.add_row(s.name, str(s.points), *marked, *medians, f"{s.median_depth_m:.1f}")
    console.print(table)
    console.print(f"class-wise average: |Δu| {average[0]:.2f} px, |Δv| {average[1]:.2f} px (red: above)")


def run_analyze(
    data: Path,
    sequences: list[str] | None,
    out: Path,
    config: MapsConfig,
    maps: Path | None = None,
    classes: ClassSource | Literal["auto"] = "auto",
    stride: int = 1,
    overwrite: bool = False,
    console: Console | None = None,
    camera: str | None = None,
) -> dict:
    """Match every ``stride``-th frame under the reference and summarise residuals by class.

    Returns:
        What ``classes.json`` holds.
    """
    console = console or make_console()
    claim_output(Path(out), overwrite, [data, maps])
    matcher = build_matcher(config.matcher, config.edge, config.flow_model)
    if stride < 1:
        raise DataError("--stride", f"must be at least 1, got {stride}")
    data = Path(data)
    if not sequences:
        sequences = sequence_names(data) if (data / "sequences").is_dir() else [None]
    start = time.perf_counter()
    total, per_sequence, sources, frames = ClassResiduals(), {}, {}, 0
    for sequence in sequences:
        key = sequence or data.name
        residuals = ClassResiduals()
        with open_dataset(data, sequence=sequence, camera=camera) as seq:
            if seq.calibration.T_cam_lidar is None:
                raise DataError(data, f"sequence {key} has no reference calibration to analyse under")
            support_map = _sequence_support(Path(maps), key, len(sequences), seq) if maps else None
            indices = range(0, len(seq), stride)
            with progress_bar(f"analyze {seq.name}", console) as progress:
                task = progress.add_task("analyze", total=len(indices))
                for i in indices:
                    frame = seq[i]
                    source = class_source(frame, classes)
                    sources.setdefault(key, source)
                    corr = matcher.match(frame, frame.calibration.T_cam_lidar)
                    names = EXG_CLASSES if source == "exg" else seq.class_names
                    support = None
                    if support_map is not None:
                        if support_map.shape != frame.image_size:
                            raise DataError(maps, f"maps are {support_map.shape}, images {frame.image_size}")
                        support = pixel_lookup(support_map, corr.uv)
                    T = frame.calibration.T_cam_lidar
                    depth = corr.points_lidar @ T[2, :3] + T[2, 3]
                    cls = point_classes(frame, corr, source)
                    for acc in (residuals, total):
                        acc.add(cls, corr.residual, depth, names, support)
                    frames += 1
                    progress.advance(task)
        per_sequence[key] = residuals
    overall = [s for s in total.stats() if s.points >= MIN_POINTS]
    if not overall:
        raise SupportnetError(f"no class has {MIN_POINTS} residuals; the matcher found too little signal")
    average = classwise_average(overall)
    result = {
        "data": str(data),
        "sequences": list(per_sequence),
        "frames": frames,
        "stride": stride,
        "class_source": sources,
        "matcher": config.matcher,
        "maps": str(maps) if maps else None,
        "min_points_ranked": MIN_POINTS,
        "classwise_average_du": average[0],
        "classwise_average_dv": average[1],
        "ranking_by_median_norm": [s.name for s in overall],
        "classes": {
            key: [asdict(s) for s in acc.stats()] for key, acc in (("all", total), *per_sequence.items())
        },
        "runtime_s": time.perf_counter() - start,
    }
    with atomic_output(out, overwrite, [data, maps], command="analyze") as tmp:
        write_json(tmp / "classes.json", result)
        with open(tmp / "classes.csv", "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["sequence", *ClassStats.__dataclass_fields__])
            for key, rows in result["classes"].items():
                writer.writerows([key, *row.values()] for row in rows)
        charts = {"residuals_by_class.png": ("all", total)}
        if len(per_sequence) > 1:
            charts.update({f"residuals_by_class_{k}.png": (k, acc) for k, acc in per_sequence.items()})
        for name, (key, acc) in charts.items():
            stats = [s for s in acc.stats() if s.points >= MIN_POINTS]
            which = ", ".join(per_sequence) if key == "all" else key  # never "all": say which sequences
            title = f"{Path(data).resolve().name}, sequence {which}: matcher residuals under the reference"
            class_residual_chart(stats, tmp / name, title)
        (tmp / "config.yaml").write_text(resolved_config(config))
    _print_table(overall, console)
    seconds = result["runtime_s"]
    console.print(f"wrote {out} ({frames} frames in {seconds:.1f} s)", markup=False, highlight=False)
    return result
