"""``supportnet maps``: Stage 3 offline support maps of one sequence under its reference calibration.

Writes ``frames/NNNNNN.npz`` (per-frame ``support``, ``coverage``, ``agreement``, the U-Net's
training targets, and the raw sums), ``sequence.npz`` (the whole-sequence maps), PNG previews,
``summary.json`` and the resolved ``config.yaml``. Work goes to ``<out>.partial`` and is renamed
when complete. A failed run removes it; an interrupted one (Ctrl-C, SIGTERM) keeps its finished
frames, and ``--resume`` continues them when the config and the dataset's fingerprint are the same
(a later run without ``--resume`` removes them).
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import numpy as np
from rich.console import Console

from calib.data import open_dataset
from calib.data.io import write_image
from calib.errors import DataError
from calib.support.support_maps import MapsConfig, SupportMaps, support_maps
from supportnet.cli.console import make_console
from supportnet.cli.output_dir import (
    claim_output,
    claim_partial,
    make_parents,
    progress_bar,
    remove_empty,
    replace_atomically,
    resolved_config,
    write_json,
    write_marker,
)
from supportnet.report.pictures import map_picture
from supportnet.runtime.matcher_factory import build_matcher

__all__ = ["run_maps"]


def _preview(image: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The image above the map (viridis, 0 to 1, colour bar underneath), stacked vertically."""
    return np.concatenate([image, map_picture(values, "agreement")], axis=0)


def _abandon(partial: Path, resumed: bool, exc: BaseException, frames: int, console: Console) -> None:
    """After a failure: an interrupted run (Ctrl-C, SIGTERM) keeps its finished frames for
    ``--resume``; otherwise what this run started is removed (a resumed folder, holding an earlier
    run's frames, is kept)."""
    done = len(list((partial / "frames").glob("*[0-9].npz"))) if partial.is_dir() else 0
    if isinstance(exc, KeyboardInterrupt) and done:
        console.print(
            f"interrupted: {done} of {frames} frames kept in {partial}; run again with --resume to go on",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )
    elif not resumed:
        shutil.rmtree(partial, ignore_errors=True)


def run_maps(
    data: Path,
    sequence: str | None,
    out: Path,
    config: MapsConfig,
    overwrite: bool = False,
    resume: bool = False,
    console: Console | None = None,
    camera: str | None = None,
) -> Path:
    """Match every frame under the reference calibration and accumulate support maps."""
    console = console or make_console()
    out = Path(out)
    claim_output(out, overwrite, [data])
    partial = out.with_name(out.name + ".partial")
    resolved = resolved_config(config)
    with open_dataset(data, sequence=sequence, camera=camera) as seq:
        if seq.calibration.T_cam_lidar is None:
            raise DataError(data, "has no reference calibration; offline support maps need one")
        fingerprint = seq.fingerprint()
        stored = partial / "config.yaml"
        if resume and partial.is_dir() and not (stored.is_file() and stored.read_text() == resolved):
            raise DataError(partial, "was written with another config; remove it or run without --resume")
        matcher = build_matcher(config.matcher, config.edge, config.flow_model)
        left = os.path.lexists(partial)
        resumed = claim_partial(partial, resume, dataset_fingerprint=fingerprint)
        if left and not resumed:
            console.print(f"removed {partial}, left by an interrupted run", markup=False, highlight=False)
        start, matched, total, created = time.perf_counter(), 0, None, []
        try:
            if not resumed:
                created = make_parents(partial)
                write_marker(partial, "maps", dataset_fingerprint=fingerprint)
            (partial / "frames").mkdir(exist_ok=True)
            (partial / "previews").mkdir(exist_ok=True)
            (partial / "config.yaml").write_text(resolved)
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
                        preview = _preview(frame.image, maps.agreement)
                        write_image(partial / "previews" / f"{i:06d}.png", preview)
                    total = maps if total is None else total + maps
                    progress.advance(task)
            if total is None:
                raise DataError(data, "holds no frames")
            np.savez_compressed(partial / "sequence.npz", **total.arrays())
            for name in ("support", "agreement"):
                write_image(partial / f"sequence_{name}.png", map_picture(getattr(total, name), name))
            seconds = time.perf_counter() - start
            write_json(
                partial / "summary.json",
                {
                    "data": str(data),
                    "sequence": sequence,
                    "frames": len(seq),
                    "dataset_fingerprint": fingerprint,
                    "correspondences_matched_this_run": matched,
                    "runtime_s": seconds,
                },
            )
            claim_output(out, overwrite, [data])
            replace_atomically([(partial, out)])
        except BaseException as exc:
            _abandon(partial, resumed, exc, len(seq), console)
            remove_empty(created[1:])  # the folders above it that this run made
            raise
    console.print(
        f"wrote support maps of {len(seq)} frames to {out} in {seconds:.1f} s",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    return out
