"""Is a real fixture's reference extrinsic itself right? The matcher's answer, rotation only.

Under a right reference the EdgeMatcher's residuals scatter around zero; under one that is turned
they share a direction. For each fixture this matches every frame under the reference, fits the
small rotation ``δR`` (``T' = δR · T_ref``, the translation held: one frame tells little of it) that
takes the projected points onto their matches (Gauss–Newton on the linearised projection,
Cauchy-weighted at 2 working px, as Stage 4's loss), then matches again under ``T'``, and again
(``--rounds``) while the median residual measured anew falls: a correction that the data support
lowers it, not only the fitted one. The matcher's own leans are in the answer too (KITTI raw:
about 0.2° of roll from the intensity edges along its scan lines, see the README), so a
correction counts as the reference's error only where the picture shows it.

``--picture NAME --crop x0,y0,x1,y1`` also draws that image region (full-resolution pixels) with
the LiDAR's returns coloured by intensity, under the reference (left) and under ``T'`` (right):
painted road markings show the offset by eye (the default crop is a dashed lane line of pjlab-1).
``--compare PATH`` sets another answer beside the reference (a joint calibration's result.json):
each ``--views`` crop is drawn under the reference, under the reference turned to the answer's
rotation with its own translation (what the rotation alone does), and under the answer, the
returns nearer than ``--near-m`` coloured by depth. Near objects at the image's sides show an
error along the optical axis, which moves them apart or together (``(u − c) Δz / z``), where a
rotation moves every point alike. Prints a table and writes
``benchmarks/results/bench_reference.json`` (and the pictures beside it).

    .venv/bin/python benchmarks/bench_reference.py [--fixtures pjlab-1,pjlab-2,pjlab-3]
        [--picture pjlab-1 --crop 450,840,780,1090] [--compare result.json --views NAME:x0,y0,x1,y1 ...]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")  # a benchmark shares its machine: timings comparable

import cv2
import numpy as np
import torch
from results_io import RESULTS, save_results
from rich.console import Console

from calib.data import Frame, open_dataset
from calib.data.extrinsic_file import read_extrinsic
from calib.data.real_fixtures import check_fixtures, realdata_root
from calib.match.correspondences import Correspondences, match_frames
from calib.match.edge_matcher import EdgeMatcher
from calib.projection import project_points, transform_points
from calib.refine.passes import load_calibrate_config
from calib.refine.solver import reprojection_jacobian, robust_weight

console = Console(stderr=True, highlight=False, soft_wrap=True)


def _camera_points(corr: Correspondences, T: np.ndarray) -> np.ndarray:
    return np.asarray(corr.points_lidar, np.float64)[:, :3] @ T[:3, :3].T + T[:3, 3]


def rotation_fit(matched: list[Correspondences], T: np.ndarray, K: np.ndarray, scale_px: float) -> np.ndarray:
    """``(3,)`` rotation vector ``ω`` (camera frame, rad) of ``δR = exp([ω]×)`` minimising the
    Cauchy loss (scale ``scale_px``) of ``residual − A ω`` over every correspondence, where
    ``A`` is the rotation part of Stage 4's :func:`~calib.refine.solver.reprojection_jacobian`
    (the projection's response to a small turn of each point in the camera frame)."""
    q = torch.as_tensor(np.concatenate([_camera_points(c, T) for c in matched]))
    r = torch.as_tensor(np.concatenate([c.residual for c in matched]), dtype=torch.float64)
    A = reprojection_jacobian(q, K)[..., 3:]  # (N, 2, 3): d(uv)/dω for exp(ω) · q
    omega = torch.zeros(3, dtype=torch.float64)
    for _ in range(20):  # iteratively reweighted least squares
        e = r - A @ omega
        _, w = robust_weight((e**2).sum(1), "cauchy", scale_px)
        H = torch.einsum("n,nki,nkj->ij", w, A, A)
        g = torch.einsum("n,nki,nk->i", w, A, r)
        step = torch.linalg.solve(H, g) - omega
        omega += step
        if torch.linalg.norm(step) < 1e-9:
            break
    return omega.numpy()


def turned(T: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """``δR · T`` with ``δR = exp([ω]×)``."""
    R, _ = cv2.Rodrigues(omega)
    out = np.array(T, np.float64)
    out[:3] = R @ out[:3]
    return out


def _median(matched: list[Correspondences]) -> float:
    return float(np.median(np.linalg.norm(np.concatenate([c.residual for c in matched]), axis=1)))


def picture(
    frame: Frame,
    Ts: list[np.ndarray],
    crop: tuple[int, int, int, int],
    path: Path,
    near_m: float | None = None,
    zoom: int = 3,
) -> None:
    """Side by side, the crop (zoomed ``zoom`` times) with the scan's returns under each of ``Ts``:
    coloured by intensity, or (``near_m``) by depth, only those nearer than ``near_m``."""
    x0, y0, x1, y1 = crop
    panels = []
    for T in Ts:
        uv, depth = project_points(
            transform_points(torch.as_tensor(T), torch.as_tensor(frame.points[:, :3], dtype=torch.float64)),
            torch.as_tensor(frame.K),
        )
        uv, depth = uv.numpy(), depth.numpy()
        inside = (depth > 0.5) & (uv[:, 0] >= x0) & (uv[:, 0] < x1) & (uv[:, 1] >= y0) & (uv[:, 1] < y1)
        if near_m is None:
            intensity = frame.points[inside, 3]
            scale = np.percentile(intensity, 98) if len(intensity) else 1.0
            level, colour_map = np.clip(255 * intensity / max(scale, 1e-6), 0, 255), cv2.COLORMAP_HOT
        else:
            inside &= depth < near_m
            level, colour_map = np.clip(255 * depth[inside] / near_m, 0, 255), cv2.COLORMAP_JET
        colours = (  # OpenCV maps an empty array to None: a crop without returns draws none
            cv2.applyColorMap(level.astype(np.uint8)[:, None], colour_map)[:, 0]
            if len(level)
            else np.zeros((0, 3), np.uint8)
        )
        panel = cv2.resize(
            cv2.cvtColor(frame.image[y0:y1, x0:x1], cv2.COLOR_RGB2BGR),
            None,
            fx=zoom,
            fy=zoom,
            interpolation=cv2.INTER_NEAREST,
        )
        for (u, v), c in zip(uv[inside], colours, strict=True):
            cv2.circle(panel, (int((u - x0) * zoom), int((v - y0) * zoom)), 2, tuple(int(k) for k in c), -1)
        panels.append(panel)
    gap = np.full((panels[0].shape[0], 16, 3), 255, np.uint8)
    cv2.imwrite(str(path), np.hstack([p for panel in panels for p in (gap, panel)][1:]))


def with_rotation_of(T: np.ndarray, T_other: np.ndarray) -> np.ndarray:
    """``T`` with the rotation of ``T_other`` (its translation kept): what a rotation alone does."""
    out = np.array(T, np.float64)
    out[:3, :3] = T_other[:3, :3]
    return out


def _crop(text: str, form: str = "x0,y0,x1,y1") -> tuple[int, int, int, int]:
    """``x0,y0,x1,y1`` as four integers.

    Raises:
        ValueError: not four integers with x0 < x1 and y0 < y1 (the message names ``form``).
    """
    try:
        x0, y0, x1, y1 = (int(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"expected {form} (four integers)") from None
    if x1 <= x0 or y1 <= y0:
        raise ValueError(f"expected {form} with x0 < x1 and y0 < y1")
    return x0, y0, x1, y1


def _views(text: str) -> list[tuple[str, tuple[int, int, int, int]]]:
    """``NAME:x0,y0,x1,y1 NAME:...`` as ``(name, crop)`` pairs.

    Raises:
        ValueError: an item without a name, or whose crop is not four integers with x0 < x1, y0 < y1.
    """
    views = []
    for item in text.split():
        name, _, crop = item.partition(":")
        try:
            if not name:
                raise ValueError("expected NAME:x0,y0,x1,y1 (a name)")
            views.append((name, _crop(crop, "NAME:x0,y0,x1,y1")))
        except ValueError as error:
            raise ValueError(f"{item!r}: {error}") from None
    return views


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--fixtures", default="pjlab-1,pjlab-2,pjlab-3", help="comma-separated; 'all' for every one"
    )
    parser.add_argument("--rounds", type=int, default=5, help="match-and-fit rounds at most")
    parser.add_argument("--picture", default="pjlab-1", help="fixture to draw ('' for none)")
    parser.add_argument("--crop", default="450,840,780,1090", help="x0,y0,x1,y1 in its first frame's pixels")
    parser.add_argument(
        "--compare",
        type=Path,
        help="an answer to set beside the reference (a result.json, or 12 or 16 numbers, as --init "
        "file: takes): each --views crop is drawn under the reference, the reference turned to the "
        "answer's rotation (its translation kept), and the answer, with the returns nearer than "
        "--near-m coloured by depth (0: every return, by intensity: road paint)",
    )
    parser.add_argument(
        "--views",
        default="pjlab-1:1720,480,1920,780 pjlab-2:80,620,220,800",
        help="space-separated NAME:x0,y0,x1,y1 crops of a fixture's first frame for --compare (the "
        "default: a tree trunk at the right edge of pjlab-1, a car at the left edge of pjlab-2)",
    )
    parser.add_argument(
        "--near-m",
        type=float,
        default=30.0,
        help="--compare pictures: returns nearer than this (0: every return, coloured by intensity)",
    )
    args = parser.parse_args()
    root = realdata_root()
    if root is None:
        raise SystemExit("real fixtures absent (../shared/realdata, SUPPORTNET_REALDATA)")
    answer = read_extrinsic(args.compare) if args.compare is not None else None
    try:
        views = _views(args.views) if answer is not None else []
        crop = _crop(args.crop)
    except ValueError as error:
        parser.error(f"--views or --crop: {error}")
    chosen = None if args.fixtures == "all" else set(args.fixtures.split(","))
    if chosen is not None and (missing := {name for name, _ in views} - chosen):
        parser.error(f"--views names fixtures not in --fixtures: {', '.join(sorted(missing))}")
    RESULTS.mkdir(parents=True, exist_ok=True)  # the pictures go there
    config = load_calibrate_config().edge
    matcher = EdgeMatcher(config)
    clock = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory() as work:
        fixtures = check_fixtures(root, Path(work))
        for fixture in fixtures:
            if chosen is not None and fixture.name not in chosen:
                continue
            with open_dataset(fixture.path, camera=fixture.camera) as seq:
                frames = [seq[i] for i in range(len(seq))]
            T_ref, K = frames[0].calibration.T_cam_lidar, frames[0].K
            scale_px = 2.0 * K[0, 0] / min(K[0, 0], config.working_focal_px)
            before = after = match_frames(matcher, frames, T_ref)
            T_fit, rounds = T_ref, 0
            while rounds < args.rounds:  # match, fit, and again while the median falls
                T_next = turned(T_fit, rotation_fit(after, T_fit, K, scale_px))
                matched = match_frames(matcher, frames, T_next)
                if _median(matched) >= _median(after):
                    break
                T_fit, after, rounds = T_next, matched, rounds + 1
            omega = cv2.Rodrigues(T_fit[:3, :3] @ T_ref[:3, :3].T)[0].ravel()
            row = {
                "dataset": fixture.name,
                "frames": len(frames),
                "correspondences": int(sum(len(c) for c in before)),
                "correction_deg_xyz": np.degrees(omega).round(3).tolist(),
                "correction_deg": round(float(np.degrees(np.linalg.norm(omega))), 3),
                "median_px_reference": round(_median(before), 2),
                "median_px_corrected": round(_median(after), 2),
                "correspondences_corrected": int(sum(len(c) for c in after)),
                "rounds": rounds,  # accepted: each lowered the median residual
            }
            rows.append(row)
            console.print(
                f"{fixture.name}: {row['correction_deg']:.3f}° in {time.perf_counter() - clock:.0f} s"
            )
            for k, (name, crop) in enumerate(views):
                if name == fixture.name:
                    path = RESULTS / f"bench_reference_{name}_compare{k}.png"
                    Ts = [T_ref, with_rotation_of(T_ref, answer), answer]
                    picture(frames[0], Ts, crop, path, near_m=args.near_m or None)
                    row.setdefault("compare_pictures", []).append(str(path))
            if fixture.name == args.picture:
                path = RESULTS / f"bench_reference_{fixture.name}.png"
                picture(frames[0], [T_ref, T_fit], crop, path)
                row["picture"] = str(path)
    print(
        f"{'dataset':24} {'corr':>6} {'δR x / y / z (°, camera)':>26} {'|δR| °':>7} "
        f"{'ref px':>7} {'δR px':>7} rounds"
    )
    for r in rows:
        xyz = " / ".join(f"{v:+.3f}" for v in r["correction_deg_xyz"])
        print(
            f"{r['dataset']:24} {r['correspondences']:6d} {xyz:>26} {r['correction_deg']:7.3f} "
            f"{r['median_px_reference']:7.2f} {r['median_px_corrected']:7.2f} {r['rounds']:6d}"
        )
    print("δR: the rotation the matcher's residuals under the reference ask for (translation held);")
    print("ref px / δR px: median residual matched under the reference / under δR · reference")
    save_results(
        "bench_reference",
        {"rows": rows, "machine": platform.machine(), "seconds": round(time.perf_counter() - clock, 1)},
    )


if __name__ == "__main__":
    main()
