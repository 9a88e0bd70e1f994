"""benchmarks/bench_online.py's summary and variants, without running a calibration."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_online  # noqa: E402


def _window(cm: float, deg: float, dt_ms: float, truth_ms: float, fitted: bool) -> dict:
    return {
        "error": {"translation_cm": cm, "rotation_deg": deg},
        "time_offset_s": dt_ms / 1e3,
        "time_offset_truth_s": truth_ms / 1e3,
        "window_time_offset_s": dt_ms / 1e3 if fitted else None,
        "error_of_file": {"translation_cm": 3.0, "rotation_deg": 1.0},
    }


def test_the_summary_leaves_out_the_first_window_and_counts_the_goals():
    windows = [
        _window(9.0, 0.5, 0.0, 5.0, False),  # the first: not counted
        _window(0.5, 0.05, 5.5, 5.0, True),
        _window(0.8, 0.2, 6.0, 6.5, False),
        _window(2.0, 0.05, 10.0, 7.0, True),
    ]
    s = bench_online.summary(windows)
    assert s["windows"] == 4 and s["windows_fitting_dt"] == 2
    assert s["cm"]["median"] == pytest.approx(0.8) and s["cm"]["max"] == pytest.approx(2.0)
    assert s["dt_error_ms"]["median"] == pytest.approx(0.5) and s["dt_error_ms"]["max"] == pytest.approx(3.0)
    assert s["within_extrinsic"] == pytest.approx(1 / 3) and s["within_dt"] == pytest.approx(2 / 3)


def test_variants_merge_into_the_packaged_config_and_validate():
    assert not bench_online.configured("no-moving").outliers.moving.enabled
    smooth = bench_online.configured("smooth")
    assert smooth.online.process_std == (0.3, 0.05) and smooth.online.window == 10
    finest = bench_online.configured("finest")  # one key of a group; the group's others kept
    packaged_config = bench_online.load_calibrate_config()
    assert finest.edge.working_focal_px == 721.5 and finest.edge.intensity_weight == 0.25
    assert finest.edge.window == packaged_config.edge.window
    # the variant is the packaged finest level's: a change there must change it too
    assert (finest.edge.working_focal_px, finest.edge.intensity_weight) == (
        packaged_config.finest_focal_px,
        packaged_config.fine_intensity_weight,
    )
    inside = bench_online.configured("border-inside")
    assert inside.edge.border == "inside"
    assert inside.edge.model_copy(update={"border": "zero"}) == packaged_config.edge
    own = bench_online.configured("carry-own")
    assert own.edge.carry == "own"
    assert own.edge.model_copy(update={"carry": "nearer"}) == packaged_config.edge
    assert bench_online.configured("packaged") == packaged_config
    unmatched = bench_online.configured("no-matched")  # the matched-count rules off, the rest packaged
    assert (unmatched.level_min_share, unmatched.check_gain, unmatched.matched_below_px) == (0.0, None, None)
    assert (
        unmatched.model_copy(
            update={
                k: getattr(packaged_config, k) for k in ("level_min_share", "check_gain", "matched_below_px")
            }
        )
        == packaged_config
    )
