"""Stage 2 and 3 speed: EdgeMatcher ms per 624x188 frame (``small=True``), map accumulation
frames/s (matcher excluded); and the EdgeMatcher on the real full-resolution KITTI raw frames
(1224x370, f = 707) at each working focal length the refinement uses (its own, 707 px: the
finest level at full resolution; the pyramid's 360, 180 and 90), the first match of a frame
(its scan's features and its image's edges computed) and the matches after it (as a refinement
matches the same frames again). Prints a table and writes benchmarks/results/matcher.json."""

from __future__ import annotations

import time

import numpy as np
from results_io import save_results

from calib.data import open_dataset
from calib.data.real_fixtures import AMZ_DRIVE, AMZ_DRIVE_MORE, realdata_root
from calib.match.edge_matcher import EdgeMatcher, EdgeMatcherConfig
from calib.refine.passes import load_calibrate_config
from calib.support.support_maps import support_maps
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config

FRAMES = 10
FULL_RESOLUTION = load_calibrate_config().finest_focal_px
"""The packaged finest level's working focal length: KITTI's 707 px frames as they are."""


def real_frames_ms() -> dict | None:
    """Median ms per match on the six real KITTI raw frames at each working focal length: the
    first match of each frame and the repeated ones (three more per frame, under the reference)."""
    root = realdata_root()
    if root is None:
        return None
    frames = []
    for folder in (AMZ_DRIVE, AMZ_DRIVE_MORE):
        with open_dataset(root / folder) as seq:
            frames += [seq[i] for i in range(len(seq))]
    rows = {
        "size": f"{frames[0].image_size[1]}x{frames[0].image_size[0]}",
        "focal_px": float(frames[0].K[0, 0]),
    }
    for focal in (FULL_RESOLUTION, 360.0, 180.0, 90.0):
        matcher = EdgeMatcher(EdgeMatcherConfig(working_focal_px=focal))
        first, again = [], []
        for f in frames:
            for times in (first, again, again, again):
                start = time.perf_counter()
                matcher.match(f, f.calibration.T_cam_lidar)
                times.append(time.perf_counter() - start)
        rows[f"{focal:g}"] = {
            "first_ms": 1000 * float(np.median(first)),
            "again_ms": 1000 * float(np.median(again)),
        }
    return rows


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
    real = real_frames_ms()
    if real is not None:
        print(f"real KITTI raw, {real['size']}: working focal px, ms first match / again")
        for focal in (f"{FULL_RESOLUTION:g}", "360", "180", "90"):
            print(f"{focal:>6} {real[focal]['first_ms']:>8.0f} / {real[focal]['again_ms']:.0f}")
        rows["kitti-raw-full-resolution"] = real
    save_results("matcher", rows)


if __name__ == "__main__":
    main()
