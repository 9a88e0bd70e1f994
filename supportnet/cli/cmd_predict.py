"""``supportnet predict``: Stage 3 online over a sequence, the learned support of every frame.

Writes ``frames/NNNNNN.npz`` (``support``, the predicted map), ``sequence.npz`` (their mean),
PNG previews (image, prediction and, with ``--maps``, the offline map), and ``summary.json``.
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
from supportnet.cli.output_dir import atomic_output, progress_bar, write_json
from supportnet.nets.map_targets import agreement_scores, offline_target
from supportnet.report.pictures import colourise
from supportnet.runtime.support_predictor import SHIPPED_MODEL, SupportPredictor

__all__ = ["run_predict"]


def _offline(maps: Path, name: str, kind: str) -> tuple[np.ndarray, np.ndarray]:
    path = maps / name
    if not path.is_file():
        raise DataError(path, "not found; --maps takes a `supportnet maps` folder of this sequence")
    stored = np.load(path)
    return offline_target(stored["raw"], stored["coverage"], kind)


def run_predict(
    model: Path | None,
    data: Path,
    sequence: str | None,
    out: Path,
    maps: Path | None = None,
    overwrite: bool = False,
    console: Console | None = None,
) -> dict:
    """Predict every frame's support; returns ``summary.json``'s content."""
    console = console or Console(stderr=True)
    predictor = SupportPredictor(model or SHIPPED_MODEL)
    kind = predictor.contract.target
    scores, seconds, total = [], [], None
    with atomic_output(out, overwrite) as tmp, open_dataset(data, sequence=sequence) as seq:
        (tmp / "frames").mkdir()
        (tmp / "previews").mkdir()
        with progress_bar(f"predict {seq.name}", console) as progress:
            task = progress.add_task("predict", total=len(seq))
            for i in range(len(seq)):
                image = seq[i].image
                t0 = time.perf_counter()
                support = predictor.predict(image)[0]
                seconds.append(time.perf_counter() - t0)
                total = support.astype(np.float64) if total is None else total + support
                np.savez_compressed(tmp / "frames" / f"{i:06d}.npz", support=support)
                panels = [image, colourise(support)]
                if maps is not None:
                    target, weight = _offline(Path(maps) / "frames", f"{i:06d}.npz", kind)
                    scores.append(agreement_scores(support, target, weight))
                    panels.append(colourise(np.where(weight > 0, target, 0)))
                write_image(tmp / "previews" / f"{i:06d}.png", np.concatenate(panels, axis=0))
                progress.advance(task)
        if total is None:
            raise DataError(data, "holds no frames")
        mean = (total / len(seq)).astype(np.float32)
        np.savez_compressed(tmp / "sequence.npz", support=mean)
        write_image(tmp / "sequence_support.png", colourise(mean))
        summary = {
            "model": str(predictor.path),
            "target": kind,
            "data": str(data),
            "sequence": sequence,
            "frames": len(seq),
            "ms_per_frame_median": 1000 * float(np.median(seconds)),
        }
        if scores:
            summary["per_frame"] = {
                key: float(np.nanmean([s[key] for s in scores])) for key in ("mae", "pearson", "spearman")
            }
            summary["sequence_map"] = agreement_scores(mean, *_offline(Path(maps), "sequence.npz", kind))
        write_json(tmp / "summary.json", summary)
    line = f"predicted {len(seq)} frames ({summary['ms_per_frame_median']:.1f} ms each) into {out}"
    if scores:
        line += (
            f"; against the offline maps: Pearson r {summary['per_frame']['pearson']:.3f} per frame, "
            f"{summary['sequence_map']['pearson']:.3f} for the sequence map"
        )
    console.print(line, markup=False, highlight=False, soft_wrap=True)
    return summary
