"""benchmarks/bench_time_offset.py's parts joined into one benchmark, without running a calibration."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_time_offset  # noqa: E402


def _run(cm: float, dt_error_ms: float | None = 0.5) -> dict:
    return {"translation_cm": cm, "rotation_deg": 0.1, "time_offset_error_ms": dt_error_ms, "seconds": 10.0}


def _row(world: str, variant: str, runs: list[dict]) -> dict:
    return {"world": world, "offset_ms": 5.0, "variant": variant, "per_run": runs, "runs": len(runs)}


def test_parts_join_run_by_run_and_are_summarised_again():
    first = [_row("urban", "odometry", [_run(1.0), _run(3.0)]), _row("vineyard", "odometry", [_run(1.5)])]
    second = [_row("urban", "odometry", [_run(1.5, 2.0), _run(4.0)])]
    rows = bench_time_offset.joined([first, second])
    urban = next(r for r in rows if r["world"] == "urban")
    assert [r["translation_cm"] for r in urban["per_run"]] == [1.0, 3.0, 1.5, 4.0]
    assert urban["runs"] == 4 and urban["success"] == 0.5
    assert urban["cm_median"] == pytest.approx(2.25) and urban["dt_within_1ms"] == 0.75
    assert next(r for r in rows if r["world"] == "vineyard")["runs"] == 1


def test_set_changes_the_packaged_config_and_refuses_a_misspelt_key():
    from pydantic import ValidationError

    from calib.refine.passes import load_calibrate_config

    assert bench_time_offset.packaged_with({}) == load_calibrate_config()
    assert bench_time_offset.packaged_with({"settle_px": 0.1}).settle_px == 0.1
    with pytest.raises(ValidationError):
        bench_time_offset.packaged_with({"settle": 0.1})
    # a dotted key reaches into its group and keeps the group's other keys
    packaged = load_calibrate_config()
    changed = bench_time_offset.packaged_with({"edge.carry": "own"})
    assert changed.edge == packaged.edge.model_copy(update={"carry": "own"})
    with pytest.raises(ValidationError):
        bench_time_offset.packaged_with({"edge.cary": "own"})


def test_set_reads_a_list_whole_and_splits_at_the_other_commas():
    changes = bench_time_offset.parse_changes("pyramid_focals_px=[180.0, 360],settle_px=0.1,edge.carry=own")
    assert changes == {"pyramid_focals_px": [180.0, 360], "settle_px": 0.1, "edge.carry": "own"}
    assert bench_time_offset.packaged_with(changes).pyramid_focals_px == (180.0, 360.0)


def test_world_set_nests_keys_into_config_groups_and_reaches_the_world():
    from calib.synth.synth_config import load_synth_config

    changes = bench_time_offset.world_changes("lidar.laser_angle_std_deg=0,timing.camera_offset_s=0.01")
    assert changes == {"lidar": {"laser_angle_std_deg": 0}, "timing": {"camera_offset_s": 0.01}}
    assert bench_time_offset.world_changes(None) == {}
    config = load_synth_config("vineyard", **changes)
    assert config.lidar.laser_angle_std_deg == 0 and config.timing.camera_offset_s == 0.01
    packaged = load_synth_config("vineyard").lidar
    assert packaged.laser_angle_std_deg > 0
    assert config.lidar.model_copy(update={"laser_angle_std_deg": packaged.laser_angle_std_deg}) == packaged
    with pytest.raises(ValueError, match="GROUP.KEY"):
        bench_time_offset.world_changes("laser_angle_std_deg=0")
