"""``supportnet info``: what a dataset holds, and what is wrong with it."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.progress import track
from rich.table import Table

from calib.data import Sequence, open_dataset
from calib.data.classes import class_name
from calib.errors import DataError

__all__ = ["describe", "info"]


def _extrinsic_summary(T: np.ndarray | None) -> str:
    if T is None:
        return "none (no reference in the data)"
    angle = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1, 1)))
    rows = "\n".join("  [" + " ".join(f"{v:+.6f}" for v in row) + "]" for row in T)
    return f"rotation {angle:.3f}°, translation {np.round(T[:3, 3], 4).tolist()} m\n{rows}"


def describe(seq: Sequence, check_all: bool = False) -> dict:
    """Facts about a sequence; loads the first frame (every frame with ``check_all``)."""
    problems = list(seq.problems)
    indices = range(len(seq)) if check_all else range(min(1, len(seq)))
    first, labels, image_labels = None, Counter(), False
    for i in track(indices, description="checking frames", disable=not check_all):
        try:
            frame = seq[i]
        except DataError as exc:
            problems.append(str(exc))
            continue
        first = first or frame
        if frame.labels is not None:
            labels.update(np.unique(frame.labels).tolist())
        image_labels |= frame.image_labels is not None
    times = seq.timestamps
    K = seq.calibration.K
    return {
        "name": seq.name,
        "layout": seq.layout,
        "camera": seq.camera or None,
        "fingerprint": seq.fingerprint(),
        "frames": len(seq),
        "image_size": first.image_size if first else seq.calibration.image_size,
        "points_first_frame": len(first.points) if first else None,
        "K": K,
        "T_cam_lidar": seq.calibration.T_cam_lidar,
        "time_span": (float(times[0]), float(times[-1])) if len(times) else None,
        "rate_hz": float((len(times) - 1) / (times[-1] - times[0]))
        if len(times) > 1 and times[-1] > times[0]
        else None,
        "label_classes": sorted(labels),
        "image_labels": image_labels,
        "poses": seq.poses is not None,
        "notes": list(seq.notes),
        "problems": problems,
    }


def info(path: Path, sequence: str | None, camera: str | None, check_all: bool, console: Console) -> int:
    """Print :func:`describe` of ``path``; returns the exit code.

    Args:
        camera: where the dataset has several: a KITTI index or a bag's image topic (``None``:
            the layout's default).

    Raises:
        DataError: after listing them, for the first problem found (exit code 2): unpaired or
            broken files, NaN or non-increasing time stamps, NaN poses, images of another size.
    """
    with open_dataset(path, sequence, camera=camera, strict=False) as seq:
        facts = describe(seq, check_all)
    table = Table(show_header=False, box=None, pad_edge=False)
    table.add_column(style="bold cyan")
    table.add_column(overflow="fold")
    K = facts["K"]
    size = facts["image_size"]
    table.add_row("data", f"{escape(str(path))}  (layout: {facts['layout']})")
    table.add_row("sequence", escape(facts["name"]))
    if facts["camera"]:
        table.add_row("camera", escape(facts["camera"]))
    table.add_row("frames", str(facts["frames"]))
    table.add_row("image", f"{size[1]} x {size[0]} (W x H)" if size else "unknown")
    table.add_row(
        "points",
        f"{facts['points_first_frame']} in the first scan" if facts["points_first_frame"] else "unknown",
    )
    table.add_row("intrinsics", f"fx {K[0, 0]:.3f}  fy {K[1, 1]:.3f}  cx {K[0, 2]:.3f}  cy {K[1, 2]:.3f}")
    table.add_row("T_cam_lidar", _extrinsic_summary(facts["T_cam_lidar"]))
    if facts["time_span"]:
        t0, t1 = facts["time_span"]
        rate = f", {facts['rate_hz']:.2f} Hz" if facts["rate_hz"] else ""
        table.add_row("time span", f"{t1 - t0:.3f} s ({t0:.6f} .. {t1:.6f}){rate}")
    classes = ", ".join(f"{c} {class_name(c)}" for c in facts["label_classes"])
    table.add_row("point labels", classes or "none")
    table.add_row("image labels", "yes" if facts["image_labels"] else "none")
    table.add_row("poses", "ground truth present" if facts["poses"] else "none")
    table.add_row("fingerprint", facts["fingerprint"])
    for note in facts["notes"]:
        table.add_row("note", escape(note))
    console.print(table)
    if facts["problems"]:
        console.print(f"[bold red]{len(facts['problems'])} problem(s):[/]")
        for problem in facts["problems"]:
            console.print(f"  - {escape(problem)}", soft_wrap=True)
        path_part, _, problem = facts["problems"][0].partition(": ")
        raise DataError(path_part, problem)
    console.print(
        "[green]no problems found[/]"
        + ("" if check_all else " (first frame read; --check-all reads every frame)")
    )
    return 0
