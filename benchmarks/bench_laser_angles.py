"""How large each laser's angle error is on the real LiDARs, measured from their own scans
(:func:`calib.laser_angles.laser_angle_errors`), and whether the measurement recovers the synthetic
worlds' known errors (``lidar.laser_angle_std_deg``).

Per scan, each line's elevation error is read from the ground and each pair of neighbouring
lines' azimuth difference from oblique walls. A scan's estimates mix the lasers' errors with its
scene (the road's shape, surfaces that are not quite vertical); the lasers' part is what scans of
*different places* agree on. So the estimate of the lasers' spread is the covariance between two
such scans, ``√cov``, the median over the pairs (elevation: the part that changes from line to
line, :func:`calib.laser_angles.high_pass`; azimuth: per laser, the steps' ``√cov / √2``). On the
synthetic worlds, whose rig draws each laser's error once (std ``laser_angle_std_deg``, zero-mean),
the table also gives the truth's spread measured the same way and each scan's correlation with it.

Real rigs: KITTI's HDL-64 (the six 2011_09_28 raw frames, three places: 34 and 1, 35, 6 and 19,
185 as the realdata README pairs them; and object frame 000114, another drive), nuScenes' HDL-32E
(one scan) and PJLab's Pandar64 (three scenes). Writes ``benchmarks/results/bench_laser_angles.json``
and a picture of each KITTI frame's per-line estimates, ``bench_laser_angles.png``.

    .venv/bin/python benchmarks/bench_laser_angles.py [--seeds 301,302] [--frames 0,5,9]
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from results_io import RESULTS, save_results
from rich.console import Console
from rich.table import Table

from calib.data import open_dataset
from calib.data.real_fixtures import check_fixtures, realdata_root
from calib.laser_angles import LaserAngles, high_pass, laser_angle_errors
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import SMALL_CAMERA, load_synth_config

console = Console(stderr=True, highlight=False, soft_wrap=True)

KITTI_PLACES = {"0000000034": "a", "0000000001": "a", "0000000035": "b", "0000000006": "b", "0000000019": "b"}
"""KITTI raw 2011_09_28 frames that show one place (realdata README); any other frame is its own."""


def spread(per_scan: list[np.ndarray], places: list[str]) -> tuple[float, int]:
    """``√(median covariance)`` over the pairs of scans from different places, each pair over the
    lines both see, and the number of such pairs (NaN, 0 with none)."""
    covariances = []
    for (a, pa), (b, pb) in itertools.combinations(zip(per_scan, places, strict=True), 2):
        both = np.isfinite(a) & np.isfinite(b)
        if pa != pb and both.sum() >= 8:
            covariances.append(float(np.mean((a[both] - a[both].mean()) * (b[both] - b[both].mean()))))
    if not covariances:
        return float("nan"), 0
    return float(np.sqrt(max(np.median(covariances), 0.0))), len(covariances)


def _shift(lines_deg: np.ndarray, reference_deg: np.ndarray) -> int:
    """The whole number of lines (−3 to 3) that best lines up elevations ``lines_deg`` with
    ``reference_deg`` (median absolute difference over the lines both have)."""

    def mismatch(shift: int) -> float:
        k = np.arange(len(lines_deg))
        inside = (k + shift >= 0) & (k + shift < len(reference_deg))
        return float(np.median(np.abs(lines_deg[inside] - reference_deg[k[inside] + shift])))

    return min(range(-3, 4), key=mismatch)


def aligned(angles: list[LaserAngles]) -> tuple[list[np.ndarray], list[np.ndarray], int]:
    """Each scan's high-passed elevation errors and azimuth steps on the lines of the scan with the
    most lines (NaN where a scan has no such line), and their number. A scan's lines are its
    lasers in stored order, but a scan can start with a partial line (KITTI: a few returns at
    3.9°), so each is shifted by the whole number of lines that best matches its lines'
    elevations to the reference's."""
    reference = max(angles, key=lambda a: len(a.line_elevation_deg)).line_elevation_deg
    width = len(reference)
    elevation, steps = [], []
    for a in angles:
        shift = _shift(a.line_elevation_deg, reference)
        el, st = np.full(width, np.nan), np.full(width - 1, np.nan)
        values = zip(high_pass(a.elevation_deg), [*a.azimuth_step_deg, np.nan], strict=True)
        for k, (e, s) in enumerate(values):
            if 0 <= k + shift < width:
                el[k + shift] = e
            if 0 <= k + shift < width - 1:
                st[k + shift] = s
        elevation.append(el)
        steps.append(st)
    return elevation, steps, width


def summarise(
    name: str, angles: list[LaserAngles], places: list[str], truth: np.ndarray | None = None
) -> dict:
    """One row: the lasers' elevation and azimuth spread (°) as the scans show it."""
    elevation, steps, width = aligned(angles)
    el, el_pairs = spread(elevation, places)
    az, az_pairs = spread(steps, places)
    row = {
        "scans": len(angles),
        "lines": width,
        "lines_on_ground": int(np.median([np.isfinite(a.elevation_deg).sum() for a in angles])),
        "steps_on_walls": int(np.median([np.isfinite(a.azimuth_step_deg).sum() for a in angles])),
        "elevation_deg": el,
        "azimuth_deg": az / np.sqrt(2),
        "pairs": min(el_pairs, az_pairs),
    }
    if truth is not None:  # (2, lines) the rig's own errors, lines in scan order
        true_el, true_steps = high_pass(truth[0]), np.diff(truth[1])
        corr = lambda x, t: float(np.corrcoef(x[np.isfinite(x)], t[np.isfinite(x)])[0, 1])  # noqa: E731
        row["truth_elevation_deg"] = float(np.std(true_el[np.isfinite(elevation[0])]))
        row["truth_azimuth_deg"] = float(np.std(true_steps) / np.sqrt(2))
        row["corr_elevation"] = float(np.median([corr(e, true_el) for e in elevation]))
        row["corr_azimuth"] = float(np.median([corr(s, true_steps) for s in steps]))
    console.print(f"{name}: {row}")
    return row


def real_rows(root: Path, work: Path) -> tuple[dict, dict[str, LaserAngles]]:
    """The real rigs' rows, and the KITTI frames' estimates for the picture."""
    groups: dict[str, list[tuple[str, LaserAngles]]] = {}
    for fixture in check_fixtures(root, work):
        rig = (
            "KITTI HDL-64"
            if fixture.name.startswith(("kitti-raw", "kitti-object-000114"))
            else "nuScenes HDL-32E"
            if fixture.name == "nuscenes-cam-front"
            else "PJLab Pandar64"
            if fixture.name.startswith("pjlab")
            else None
        )
        if rig is None:  # 000008's scan is cropped to the camera; nuScenes' other cameras share its scan
            continue
        with open_dataset(fixture.path, camera=fixture.camera) as sequence:
            for i in range(len(sequence)):
                frame = sequence[i]
                angles = laser_angle_errors(frame.points)
                if angles is not None:
                    groups.setdefault(rig, []).append((f"{fixture.name}/{frame.name}", angles))
    rows = {}
    for rig, scans in groups.items():
        places = [KITTI_PLACES.get(name.split("/")[-1], name) for name, _ in scans]
        rows[rig] = summarise(rig, [a for _, a in scans], places)
        rows[rig]["frames"] = [name for name, _ in scans]
    return rows, dict(groups.get("KITTI HDL-64", []))


def synthetic_rows(seeds: list[int], frames: list[int]) -> dict:
    rows = {}
    for world in ("urban", "vineyard"):
        for seed in seeds:
            config = load_synth_config(world, camera=SMALL_CAMERA)
            synth = Synthesizer(config, max(frames) + 1, seed=seed)
            lidar = synth.lidar
            # the scan's lines run from the top laser down; the rig's errors are per laser index
            height = [lidar.directions[lidar.ring == k, 2].mean() for k in range(config.lidar.beams)]
            order = np.argsort(-np.array(height))
            truth = lidar.angle_error_deg[:, order]
            angles = [laser_angle_errors(synth.render(i).frame.points) for i in frames]
            if any(a is None or len(a.elevation_deg) != config.lidar.beams for a in angles):
                console.print(
                    f"[yellow]{world} seed {seed}: lines do not split one per laser; skipped[/yellow]"
                )
                continue
            rows[f"synthetic {world}, seed {seed}"] = summarise(
                f"{world} {seed}", angles, [str(i) for i in frames], truth
            )
            rows[f"synthetic {world}, seed {seed}"]["laser_angle_std_deg"] = config.lidar.laser_angle_std_deg
    return rows


def picture(kitti: dict[str, LaserAngles], path: Path) -> None:
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True)
    for name, a in kitti.items():
        top.plot(a.line_elevation_deg, high_pass(a.elevation_deg), ".-", lw=0.8, label=name.split("/")[-1])
        bottom.plot(a.line_elevation_deg[1:], a.azimuth_step_deg, ".-", lw=0.8)
    top.set_ylabel("elevation error, line to line (°)")
    bottom.set_ylabel("azimuth step η(k+1) − η(k) (°)")
    bottom.set_xlabel("line's elevation (°)")
    top.legend(fontsize=7, ncol=4)
    top.set_title(
        "KITTI HDL-64: each laser's angle error as each scan shows it "
        "(what scans of different places agree on is the lasers')"
    )
    for ax in (top, bottom):
        ax.axhline(0, color="k", lw=0.5)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="301,302", help="synthetic rig seeds (unseen, as bench_real)")
    parser.add_argument("--frames", default="0,5,9", help="synthetic frames of each seed")
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    frames = [int(s) for s in args.frames.split(",")]
    rows: dict = {}
    root = realdata_root()
    if root is not None:
        with tempfile.TemporaryDirectory() as work:
            rows, kitti = real_rows(root, Path(work))
        if kitti:
            picture(kitti, RESULTS / "bench_laser_angles.png")
    else:
        console.print("[yellow]no real data (SUPPORTNET_REALDATA): synthetic rows only[/yellow]")
    rows.update(synthetic_rows(seeds, frames))
    table = Table(title="Laser angle errors from the scans themselves (° std per laser)")
    columns = ("rig", "scans", "lines on ground / steps on walls", "elevation", "azimuth", "truth", "corr")
    for column in columns:
        table.add_column(column)
    for name, row in rows.items():
        known = "truth_elevation_deg" in row
        truth = f"{row['truth_elevation_deg']:.3f} / {row['truth_azimuth_deg']:.3f}" if known else ""
        corr = f"{row['corr_elevation']:.2f} / {row['corr_azimuth']:.2f}" if known else ""
        table.add_row(
            name,
            str(row["scans"]),
            f"{row['lines_on_ground']} / {row['steps_on_walls']}",
            f"{row['elevation_deg']:.3f}",
            f"{row['azimuth_deg']:.3f}",
            truth,
            corr,
        )
    Console().print(table)
    console.print(f"wrote {save_results('bench_laser_angles', rows)}")


if __name__ == "__main__":
    main()
