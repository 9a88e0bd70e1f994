"""``supportnet synth``: write a synthetic vineyard or urban sequence in the KITTI odometry layout."""

from __future__ import annotations

import json
import re
import shutil
import tempfile
import time
from pathlib import Path

from rich.console import Console

from calib.data.rosbag import write_bag
from calib.errors import DataError
from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config
from supportnet.cli.output_dir import progress_bar, resolved_config

__all__ = ["parse_drift", "run_synth"]


def parse_drift(text: str | None) -> tuple[float, float]:
    """``CM,DEG`` → ``(cm, deg)``; ``None`` → no drift."""
    if text is None:
        return (0.0, 0.0)
    try:
        cm, deg = (float(v) for v in text.split(","))
    except ValueError:
        raise DataError("--drift", f"{text!r} is not CM,DEG (e.g. 5,1)") from None
    if cm < 0 or deg < 0:
        raise DataError("--drift", f"sizes must be non-negative, got {text!r}")
    return cm, deg


def run_synth(
    world: str,
    frames: int,
    seed: int,
    out: Path,
    sequence: str = "00",
    config: Path | None = None,
    overwrite: bool = False,
    workers: int = 2,
    console: Console | None = None,
    drift: tuple[float, float] = (0.0, 0.0),
    fmt: str = "kitti",
) -> Path:
    """Generate ``out/sequences/<sequence>`` (and ``out/poses/<sequence>.txt``) atomically, or
    with ``fmt="bag"`` the same frames as a ROS 2 bag folder ``out/<sequence>_bag`` (image,
    camera_info, PointCloud2, /tf_static; ``meta.json`` and ``config.yaml`` inside).

    Other sequences already in ``out`` are kept, so several seeds can share one dataset root.

    Returns:
        The sequence folder (or the bag folder).
    """
    console = console or Console(stderr=True)
    if frames < 1:
        raise DataError("--frames", f"must be at least 1, got {frames}")
    if not re.fullmatch(r"[A-Za-z0-9_-]+", sequence):
        raise DataError("--sequence", f"{sequence!r} is not a folder name (letters, digits, - and _)")
    if fmt not in ("kitti", "bag"):
        raise DataError("--format", f"{fmt!r} is not kitti or bag")
    out = Path(out)
    seq_dir, pose_file = out / "sequences" / sequence, out / "poses" / f"{sequence}.txt"
    if fmt == "bag":
        seq_dir = out / f"{sequence}_bag"
    if seq_dir.exists() and not overwrite:
        raise DataError(seq_dir, "already exists; pass --overwrite to replace it")
    cfg = load_synth_config(world, config)
    start = time.perf_counter()
    synth = Synthesizer(cfg, frames, seed, drift)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".synth-{sequence}.", dir=out))
    try:
        with progress_bar(f"{world} seq {sequence}", console) as progress:
            task = progress.add_task("render", total=frames)
            if fmt == "bag":
                rendered = []
                for item in synth.frames(workers):
                    rendered.append(item.frame)
                    progress.advance(task)
                written = write_bag(tmp / seq_dir.name, rendered, ros_version=2)
                (written / "meta.json").write_text(json.dumps(synth.meta(), indent=2) + "\n")
            else:
                written = write_sequence(synth, tmp, sequence, workers, lambda n: progress.advance(task, n))
        (written / "config.yaml").write_text(resolved_config(cfg))
        if seq_dir.exists():
            shutil.rmtree(seq_dir)
        seq_dir.parent.mkdir(parents=True, exist_ok=True)
        written.rename(seq_dir)
        if fmt == "kitti":
            pose_file.parent.mkdir(parents=True, exist_ok=True)
            (tmp / "poses" / f"{sequence}.txt").replace(pose_file)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    seconds = time.perf_counter() - start
    console.print(
        f"wrote {frames} {world} frames (seed {seed}) to {seq_dir} "
        f"in {seconds:.1f} s ({frames / seconds:.1f} frames/s)",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    return seq_dir
