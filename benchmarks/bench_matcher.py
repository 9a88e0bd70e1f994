"""Stage 2 and 3 speed: EdgeMatcher ms per 624x188 frame (``small=True``), map accumulation
frames/s (matcher excluded). Prints a table and writes benchmarks/results/matcher.json."""

from __future__ import annotations

import time

import numpy as np
from results_io import save_results

from calib.match.edge_matcher import EdgeMatcher
from calib.support.support_maps import support_maps
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config

FRAMES = 10


def main() -> None:
    rows = {}
    for world in ("vineyard", "urban"):
        synth = Synthesizer(load_synth_config(world, small=True), FRAMES, seed=11)
        frames = [synth.render(i).frame for i in range(FRAMES)]
        matcher = EdgeMatcher()
        matcher.match(frames[0], frames[0].calibration.T_cam_lidar)  # warm-up
        match_s, corrs = [], []
        for f in frames:
            start = time.perf_counter()
            corrs.append(matcher.match(f, f.calibration.T_cam_lidar))
            match_s.append(time.perf_counter() - start)
        start = time.perf_counter()
        total = None
        for c in corrs:
            maps = support_maps(c)
            total = maps if total is None else total + maps
        accumulate_s = time.perf_counter() - start
        rows[world] = {
            "matcher_ms_median": 1000 * float(np.median(match_s)),
            "matcher_ms_max": 1000 * float(np.max(match_s)),
            "correspondences_per_frame": float(np.mean([len(c) for c in corrs])),
            "maps_frames_per_s": FRAMES / accumulate_s,
        }
    print(f"{'world':10} {'matcher ms (median/max)':>24} {'corr/frame':>11} {'maps fps':>9}")
    for world, r in rows.items():
        print(
            f"{world:10} {r['matcher_ms_median']:>15.0f} / {r['matcher_ms_max']:<6.0f} "
            f"{r['correspondences_per_frame']:>11.0f} {r['maps_frames_per_s']:>9.1f}"
        )
    save_results("matcher", rows)


if __name__ == "__main__":
    main()
