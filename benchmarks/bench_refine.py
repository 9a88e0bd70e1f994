"""Stage 4 speed: SGIS sampling plus Eq. 4 refinement of 10 frames x 2,000 correspondences (drawn
from 20,000 candidates per frame), from a 10 cm / 2° start, with exact matches plus 0.5 px
noise; also uniform sampling. Prints a table and writes benchmarks/results/refine.json."""

from __future__ import annotations

import time

import numpy as np
import torch
from results_io import save_results

from calib.geometry import calibration_error, perturb
from calib.refine.passes import SamplingConfig, draw
from calib.refine.solver import refine_extrinsic

FRAMES, CANDIDATES, PER_FRAME, REPEATS = 10, 20_000, 2000, 7
SAMPLING = SamplingConfig(per_frame=PER_FRAME, floor=0.01)
K = np.array([[360.0, 0.0, 311.5], [0.0, 360.0, 93.5], [0.0, 0.0, 1.0]])
T_REF = np.array([[0.0, -1.0, 0.0, 0.01], [0.0, 0.0, -1.0, -0.08], [1.0, 0.0, 0.0, -0.27], [0, 0, 0, 1.0]])


def candidates(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    points = np.column_stack(
        [rng.uniform(3, 40, CANDIDATES), rng.uniform(-12, 12, CANDIDATES), rng.uniform(-1.6, 3, CANDIDATES)]
    )
    q = points @ T_REF[:3, :3].T + T_REF[:3, 3]
    uv = (q @ K.T)[:, :2] / q[:, 2:3] + rng.normal(0, 0.5, (CANDIDATES, 2))
    return points, uv, rng.random(CANDIDATES)


def one_run(
    frames: list, sampler: str, rng: np.random.Generator, T_init: np.ndarray
) -> tuple[float, np.ndarray]:
    start = time.perf_counter()
    points, uv, weights = [], [], []
    for p, u, s in frames:
        index, w = draw(s if sampler == "sgis" else None, len(s), SAMPLING, rng)  # Stage 4's own draw
        points.append(p[index])
        uv.append(u[index])
        weights.append(w)
    result = refine_extrinsic(np.concatenate(points), np.concatenate(uv), np.concatenate(weights), K, T_init)
    return time.perf_counter() - start, result.T_cam_lidar


def main() -> None:
    rng = np.random.default_rng(0)
    frames = [candidates(rng) for _ in range(FRAMES)]
    T_init = perturb(T_REF, 10.0, 2.0, torch.Generator().manual_seed(0))
    rows = {}
    for sampler in ("sgis", "uniform"):
        one_run(frames, sampler, rng, T_init)  # warm-up
        times, T = zip(*(one_run(frames, sampler, rng, T_init) for _ in range(REPEATS)), strict=True)
        error = calibration_error(T[-1], T_REF)
        rows[sampler] = {
            "seconds_median": float(np.median(times)),
            "seconds_max": float(np.max(times)),
            "translation_cm": error.translation_cm,
            "rotation_deg": error.rotation_deg,
        }
    print(
        f"sampling + refinement, {FRAMES} frames x {PER_FRAME} of {CANDIDATES} candidates (target <= 0.5 s)"
    )
    print(f"{'sampler':10} {'s median':>9} {'s max':>7} {'error':>18}")
    for name, r in rows.items():
        print(
            f"{name:10} {r['seconds_median']:>9.3f} {r['seconds_max']:>7.3f} "
            f"{r['translation_cm']:>8.3f} cm {r['rotation_deg']:.4f}°"
        )
    save_results("refine", rows)


if __name__ == "__main__":
    main()
