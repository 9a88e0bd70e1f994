"""``supportnet synth``: write a synthetic vineyard or urban sequence in the KITTI odometry layout."""

from __future__ import annotations

import os
import re
import shutil
import time
from pathlib import Path

from rich.console import Console

from calib.data import detect_layout
from calib.data.rosbag import write_bag
from calib.errors import ConfigError, DataError
from calib.seeds import check_seed
from calib.synth.generate import MAX_DRIFT, MAX_FRAMES, Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config
from supportnet.cli.console import make_console
from supportnet.cli.options import in_range
from supportnet.cli.output_dir import (
    claim_output,
    make_parents,
    make_temp_dir,
    progress_bar,
    remove_empty,
    replace_atomically,
    resolved_config,
    sweep_leftovers,
    write_json,
    write_marker,
)

__all__ = ["parse_drift", "run_synth"]

MAX_WORKERS = 256
"""Rendering processes at most (each holds a copy of the world)."""


def parse_drift(text: str | None) -> tuple[float, float]:
    """``CM,DEG`` → ``(cm, deg)``, each from 0 to :data:`MAX_DRIFT` (NaN and infinity refused:
    they would hang the ray caster); ``None`` → no drift."""
    if text is None:
        return (0.0, 0.0)
    try:
        cm, deg = (float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError("--drift", f"{text!r} is not CM,DEG (e.g. 5,1)") from None
    if not (0 <= cm <= MAX_DRIFT[0] and 0 <= deg <= MAX_DRIFT[1]):  # False for NaN too
        raise ConfigError(
            "--drift", f"sizes must be 0 to {MAX_DRIFT[0]:g} cm and 0 to {MAX_DRIFT[1]:g}°, got {text!r}"
        )
    return cm, deg


LAYOUT_WORDS = {
    "rosbag": "a ROS bag",
    "kitti_odometry": "a KITTI odometry sequence folder",
    "kitti_raw": "a KITTI raw drive or date folder",
    "kitti_object": "a KITTI object split",
    "nuscenes": "a nuScenes root",
    "custom": "a custom dataset folder",
}
"""How the one-line refusal names each layout of :func:`calib.data.detect_layout`."""


def refuse_dataset_out(out: Path) -> None:
    """Refuse an existing ``--out`` that holds a dataset other than a KITTI odometry root
    (``sequences/``): synth writes ``sequences/`` and ``poses/`` into it. A new or empty folder,
    any folder of no known layout and a KITTI odometry root (other sequences kept) are fine."""
    if not out.is_dir():
        return
    try:
        layout = detect_layout(out)
    except (DataError, OSError):  # no known layout (or unreadable: claim_output says so)
        return
    if layout == "kitti_odometry" and (out / "sequences").is_dir():
        return
    raise DataError(
        out,
        f"--out is {LAYOUT_WORDS.get(layout, layout)}; synth would write sequences/ and poses/ into "
        "that dataset: give a new or empty folder or a KITTI odometry root",
    )


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
    small: bool = False,
    camera_offset_ms: float | None = None,
    motion_distortion: bool | None = None,
    clock_drift_ms: float | None = None,
) -> Path:
    """Generate ``out/sequences/<sequence>`` (and ``out/poses/<sequence>.txt``) atomically, or
    with ``fmt="bag"`` the same frames as a ROS 2 bag folder ``out/<sequence>_bag`` (image,
    camera_info, PointCloud2, /tf_static; ``meta.json`` and ``config.yaml`` inside).

    Other sequences already in ``out`` are kept, so several seeds can share one dataset root.
    The packaged worlds render at real pixel scale (urban 1242x375, vineyard 960x540); ``small``
    renders 624x188 instead (:data:`~calib.synth.synth_config.SMALL_CAMERA`, ``--small``).
    ``camera_offset_ms`` (camera exposure minus LiDAR stamp), ``clock_drift_ms`` (how much that
    offset changes, linearly, by the last frame) and ``motion_distortion`` (each beam cast from
    the pose at its own time, with per-point times written) replace the world's.

    Returns:
        The sequence folder (or the bag folder).
    """
    console = console or make_console()
    if not 1 <= frames <= MAX_FRAMES:
        raise ConfigError("--frames", f"must be from 1 to {MAX_FRAMES}, got {frames}")
    check_seed(seed, "--seed")
    if not 1 <= workers <= MAX_WORKERS:
        raise ConfigError("--workers", f"must be from 1 to {MAX_WORKERS}, got {workers}")
    if not re.fullmatch(r"[A-Za-z0-9_-]+", sequence):
        raise DataError("--sequence", f"{sequence!r} is not a folder name (letters, digits, - and _)")
    if fmt not in ("kitti", "bag"):
        raise DataError("--format", f"{fmt!r} is not kitti or bag")
    out = Path(out)
    refuse_dataset_out(out)
    seq_dir, pose_file = out / "sequences" / sequence, out / "poses" / f"{sequence}.txt"
    if fmt == "bag":
        seq_dir = out / f"{sequence}_bag"
    claim_output(seq_dir, overwrite)
    if fmt == "kitti" and os.path.lexists(pose_file) and not os.path.lexists(seq_dir):
        raise DataError(
            pose_file, f"already exists without {seq_dir}; remove it or choose another --sequence"
        )
    timing = {}
    for option, key, ms in (
        ("--camera-offset-ms", "camera_offset_s", camera_offset_ms),
        ("--clock-drift-ms", "camera_offset_drift_s", clock_drift_ms),
    ):
        if in_range(option, -1000, 1000)(ms) is not None:
            timing[key] = ms / 1000
    if motion_distortion is not None:
        timing["motion_distortion"] = motion_distortion
    cfg = load_synth_config(world, config, small=small, **({"timing": timing} if timing else {}))
    start = time.perf_counter()
    synth = Synthesizer(cfg, frames, seed, drift)
    sweep_leftovers(out, f"synth-{sequence}")
    created = make_parents(out)
    try:
        tmp = make_temp_dir(out, f"synth-{sequence}", "synth")
    except BaseException:
        remove_empty(created)
        raise
    try:
        with progress_bar(f"{world} seq {sequence}", console) as progress:
            task = progress.add_task("render", total=frames)
            if fmt == "bag":
                rendered = []
                for item in synth.frames(workers):
                    rendered.append(item.frame)
                    progress.advance(task)
                written = write_bag(tmp / seq_dir.name, rendered, ros_version=2)
                write_json(written / "meta.json", synth.meta())
            else:
                written = write_sequence(synth, tmp, sequence, workers, lambda n: progress.advance(task, n))
        (written / "config.yaml").write_text(resolved_config(cfg))
        write_marker(written, "synth", world=world, seed=seed, frames=frames)
        claim_output(seq_dir, overwrite)  # again: another run may have written it meanwhile
        moves = [(written, seq_dir)]
        if fmt == "kitti":
            moves.append((tmp / "poses" / f"{sequence}.txt", pose_file))
        replace_atomically(moves)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        remove_empty(created)  # the dataset root, if this run made it and nothing else is there
        raise
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
