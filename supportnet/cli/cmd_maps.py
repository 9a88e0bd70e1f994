"""``supportnet maps``: Stage 3 offline support maps of one sequence under its reference calibration.

Writes ``frames/NNNNNN.npz`` (per-frame ``support``, ``coverage``, ``agreement``, the U-Net's
training targets, and the raw sums), ``sequence.npz`` (the whole-sequence maps), PNG previews,
``summary.json`` and the resolved ``config.yaml``. Work goes to ``<out>.partial`` and is renamed
when complete; a run interrupted there resumes with ``--resume`` when its config is unchanged.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np
from rich.console import Console

from calib.data import open_dataset
from calib.data.io import write_image
from calib.errors import DataError
from calib.support.support_maps import MapsConfig, SupportMaps, support_maps
from supportnet.cli.output_dir import progress_bar, resolved_config, write_json
from supportnet.report.pictures import colourise
from supportnet.runtime.matcher_factory import build_matcher

__all__ = ["run_maps"]

def _preview(image: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The image above the map (viridis), stacked vertically."""
    return np.concatenate([image, colourise(values)], axis=0)


def run_maps(
    data: Path,
    sequence: str | None,
    out: Path,
    config: MapsConfig,
    overwrite: bool = False,
    resume: bool = False,
    console: Console | None = None,
) -> Path:
    """Match every frame under the reference calibration and accumulate support maps."""
    console = console or Console(stderr=True)
    out = Path(out)
    matcher = build_matcher(config.matcher, config.edge, config.flow_model)
    if out.exists() and not overwrite:
        raise DataError(out, "already exists; pass --overwrite to replace it")
    partial = out.with_name(out.name + ".partial")
    resolved = resolved_config(config)
    stored_config = partial / "config.yaml"
    same_config = stored_config.is_file() and stored_config.read_text() == resolved
    if partial.exists() and not (resume and same_config):
        if resume:
            raise DataError(partial, "was written with another config; remove it or run without --resume")
        shutil.rmtree(partial)
    (partial / "frames").mkdir(parents=True, exist_ok=True)
    (partial / "previews").mkdir(exist_ok=True)
    (partial / "config.yaml").write_text(resolved)
    start, matched, total = time.perf_counter(), 0, None
    with open_dataset(data, sequence=sequence) as seq:
        if seq.calibration.T_cam_lidar is None:
            raise DataError(data, "has no reference calibration; offline support maps need one")
        with progress_bar(f"maps {seq.name}", console) as progress:
            task = progress.add_task("maps", total=len(seq))
            for i in range(len(seq)):
                path = partial / "frames" / f"{i:06d}.npz"
                if path.is_file():
                    stored = np.load(path)
                    maps = SupportMaps(stored["raw"], stored["coverage"], config.support.min_coverage)
                else:
                    frame = seq[i]
                    corr = matcher.match(frame, frame.calibration.T_cam_lidar)
                    maps = support_maps(corr, config.support)
                    matched += len(corr)
                    tmp = path.with_suffix(".tmp.npz")
                    np.savez_compressed(tmp, **maps.arrays(np.float32))
                    tmp.replace(path)
                    write_image(partial / "previews" / f"{i:06d}.png", _preview(frame.image, maps.agreement))
                total = maps if total is None else total + maps
                progress.advance(task)
    if total is None:
        raise DataError(data, "holds no frames")
    np.savez_compressed(partial / "sequence.npz", **total.arrays())
    for name in ("support", "agreement"):
        write_image(partial / f"sequence_{name}.png", colourise(getattr(total, name)))
    seconds = time.perf_counter() - start
    write_json(
        partial / "summary.json",
        {
            "data": str(data),
            "sequence": sequence,
            "frames": len(seq),
            "correspondences_matched_this_run": matched,
            "runtime_s": seconds,
        },
    )
    if out.exists():
        shutil.rmtree(out)
    partial.rename(out)
    console.print(
        f"wrote support maps of {len(seq)} frames to {out} in {seconds:.1f} s",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    return out
