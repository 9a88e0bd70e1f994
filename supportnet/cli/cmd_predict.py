"""``supportnet predict``: Stage 3 online over a sequence, the learned support of every frame.

Writes ``frames/NNNNNN.npz`` (``support``, the predicted map), ``sequence.npz`` (their mean),
PNG previews (image, prediction and, with ``--maps``, the offline map), and ``summary.json`` (with
the dataset's fingerprint, like offline maps).
With ``--maps`` (offline maps of the same sequence) the predictions are scored against them, per
frame and for the whole sequence, weighted by the coverage as in training.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from rich.console import Console

from calib.data import open_dataset
from calib.data.io import write_image
from calib.errors import DataError
from calib.support.map_files import (
    check_maps_fingerprint,
    dataset_identity,
    load_frame_maps,
    load_sequence_maps,
)
from supportnet.cli.console import make_console
from supportnet.cli.output_dir import atomic_output, claim_output, progress_bar, write_json
from supportnet.nets.map_targets import agreement_scores, offline_target
from supportnet.report.pictures import colour_bar, colourise, map_picture
from supportnet.runtime.support_predictor import SHIPPED_MODEL, SupportPredictor
from supportnet.runtime.support_sources import predict_frame

__all__ = ["run_predict"]


def _offline(stored: dict[str, np.ndarray], kind: str, shape: tuple[int, int], where: Path):
    """The offline target and weight of ``kind`` from loaded raw sums, checked against ``shape``."""
    if stored["raw"].shape != shape:
        raise DataError(where, f"maps are {stored['raw'].shape}, the predictions {shape} (H, W)")
    return offline_target(stored["raw"], stored["coverage"], kind)


def _nanmean(values: list[float]) -> float:
    """The mean of the finite values; NaN (without numpy's warning) when there are none."""
    finite = [v for v in values if np.isfinite(v)]
    return float(np.mean(finite)) if finite else float("nan")


def run_predict(
    model: Path | None,
    data: Path,
    sequence: str | None,
    out: Path,
    maps: Path | None = None,
    overwrite: bool = False,
    console: Console | None = None,
    camera: str | None = None,
) -> dict:
    """Predict every frame's support; returns ``summary.json``'s content.

    ``maps`` must have been made from this dataset (:func:`check_maps_fingerprint`); other maps
    are refused before anything is predicted. ``summary.json`` carries the dataset's fingerprint.
    """
    console = console or make_console()
    claim_output(Path(out), overwrite, [data, maps, model])
    maps = Path(maps) if maps is not None else None
    scores, seconds, total = [], [], None
    with open_dataset(data, sequence=sequence, camera=camera) as seq:
        if maps is not None:
            check_maps_fingerprint(maps, seq)
        predictor = SupportPredictor(model or SHIPPED_MODEL)
        kind = predictor.contract.target
        with atomic_output(out, overwrite, [data, maps, model], command="predict") as tmp:
            (tmp / "frames").mkdir()
            (tmp / "previews").mkdir()
            with progress_bar(f"predict {seq.name}", console) as progress:
                task = progress.add_task("predict", total=len(seq))
                for i in range(len(seq)):
                    frame = seq[i]
                    image = frame.image
                    t0 = time.perf_counter()
                    support = predict_frame(predictor, frame)
                    seconds.append(time.perf_counter() - t0)
                    total = support.astype(np.float64) if total is None else total + support
                    np.savez_compressed(tmp / "frames" / f"{i:06d}.npz", support=support)
                    panels = [image, colourise(support)]
                    if maps is not None:
                        where = maps / "frames" / f"{i:06d}.npz"
                        target, weight = _offline(load_frame_maps(maps, i), kind, support.shape, where)
                        scores.append(agreement_scores(support, target, weight))
                        panels.append(colourise(np.where(weight > 0, target, 0)))
                    bar = colour_bar(image.shape[1], "viridis", "0", "1", "support (maps below the image)")
                    write_image(tmp / "previews" / f"{i:06d}.png", np.concatenate([*panels, bar], axis=0))
                    progress.advance(task)
            if total is None:
                raise DataError(data, "holds no frames")
            mean = (total / len(seq)).astype(np.float32)
            np.savez_compressed(tmp / "sequence.npz", support=mean)
            write_image(tmp / "sequence_support.png", map_picture(mean, "mean predicted support"))
            summary = {
                "model": str(predictor.path),
                "target": kind,
                "data": str(data),
                "sequence": sequence,
                **dataset_identity(seq),
                "ms_per_frame_median": 1000 * float(np.median(seconds)),
            }
            if scores:
                summary["per_frame"] = {
                    key: _nanmean([s[key] for s in scores]) for key in ("mae", "pearson", "spearman")
                }
                stored = load_sequence_maps(maps, ("raw", "coverage"))
                target = _offline(stored, kind, mean.shape, maps / "sequence.npz")
                summary["sequence_map"] = agreement_scores(mean, *target)
            write_json(tmp / "summary.json", summary)
    line = f"predicted {len(seq)} frames ({summary['ms_per_frame_median']:.1f} ms each) into {out}"
    if scores:
        line += (
            f"; against the offline maps: Pearson r {summary['per_frame']['pearson']:.3f} per frame, "
            f"{summary['sequence_map']['pearson']:.3f} for the sequence map"
        )
    console.print(line, markup=False, highlight=False, soft_wrap=True)
    return summary
