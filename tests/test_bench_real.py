"""benchmarks/bench_real.py's bookkeeping (start draws, success, merging) and its README table in
benchmarks/report.py, without running a calibration."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_real  # noqa: E402
import pair_runs  # noqa: E402
import report  # noqa: E402

from calib.geometry import calibration_error  # noqa: E402


def _T() -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]
    T[:3, 3] = [0.1, -0.2, 0.3]
    return T


@pytest.mark.parametrize("shell", [False, True])
def test_starts_lie_in_the_ball_or_on_its_shell(shell):
    generator = torch.Generator().manual_seed(3)
    sizes = []
    for _ in range(200):
        e = calibration_error(bench_real.draw_start(_T(), 50.0, 10.0, generator, shell), _T())
        sizes.append((e.translation_cm, e.rotation_deg))
    cm, deg = np.array(sizes).T
    if shell:
        np.testing.assert_allclose(cm, 50.0, atol=1e-6)
        np.testing.assert_allclose(deg, 10.0, atol=1e-6)
    else:
        assert cm.max() <= 50.0 + 1e-9 and deg.max() <= 10.0 + 1e-9
        # uniform in the ball: P(size <= r/2) = 1/8
        assert 0.05 < np.mean(cm <= 25.0) < 0.22 and 0.05 < np.mean(deg <= 5.0) < 0.22


def test_same_seed_same_start():
    draws = [
        bench_real.draw_start(_T(), 10.0, 2.0, torch.Generator().manual_seed(7), False) for _ in range(2)
    ]
    np.testing.assert_array_equal(*draws)


def test_a_nudged_start_lies_its_nudge_from_the_start_it_nudges():
    """--nudge N: the start drawn as without it, moved N µm and N µ° more; the same key, the same
    start; no nudge, bench_real's draw itself."""
    plain, nudged = bench_real.Starts(), bench_real.Starts(nudge_um=2.0)
    T_plain = plain.draw(_T(), 10.0, 2.0, "kitti/2/3")
    T_nudged = nudged.draw(_T(), 10.0, 2.0, "kitti/2/3")
    e = calibration_error(T_nudged, T_plain)
    assert e.translation_cm == pytest.approx(2e-4, rel=1e-3) and e.rotation_deg == pytest.approx(
        2e-6, rel=1e-3
    )
    np.testing.assert_array_equal(T_nudged, nudged.draw(_T(), 10.0, 2.0, "kitti/2/3"))
    generator = torch.Generator().manual_seed(bench_real.zlib.crc32(b"kitti/2/3"))
    np.testing.assert_array_equal(T_plain, bench_real.draw_start(_T(), 10.0, 2.0, generator, False))


def _file(finals: dict[int, tuple[float, float]], frames: int = 6) -> dict:
    runs = [
        {"run": i, "final": {"cm": cm, "deg": deg}, "seconds": 10.0 + i} for i, (cm, deg) in finals.items()
    ]
    return {
        "success_cm_deg": bench_real.SUCCESS,
        "real": {"kitti": {"frames": frames, "levels": {"2": {"packaged": {"runs": runs}}}}},
    }


def test_paired_runs_move_as_their_answers_do():
    """Runs 0-3 in both files (4 only in one): run 0 the same, run 1 0.5 cm nearer, run 2 2 cm
    farther and across the success line, run 3 0.1° apart."""
    a = _file({0: (1.0, 0.1), 1: (1.5, 0.1), 2: (1.0, 0.1), 3: (1.0, 0.05), 4: (9.0, 1.0)})
    b = _file({0: (1.0, 0.1), 1: (1.0, 0.1), 2: (3.0, 0.1), 3: (1.0, 0.15)})
    row = pair_runs.pair(a, b)["kitti/2/packaged"]
    assert row["runs"] == 4 and row["same"] == 1 and row["b_nearer_cm"] == 1 and row["b_nearer_deg"] == 0
    assert row["finals"]["run"] == [0, 1, 2, 3] and row["finals"]["b"][3] == [1.0, 0.15]
    assert row["moved_cm"]["max"] == pytest.approx(2.0) and row["moved_cm"]["median"] == pytest.approx(0.25)
    assert row["moved_deg"]["max"] == pytest.approx(0.1)
    assert row["success"] == {"a": 4, "b": 3}
    assert row["seconds_median"] == {"a": 11.5, "b": 11.5}
    single = pair_runs.pair(_file({0: (4.0, 0.4)}, frames=1), _file({0: (6.0, 0.4)}, frames=1))
    assert single["kitti/2/packaged"]["success"] == {"a": 1, "b": 0}  # one frame: within 5 cm / 0.5°
    assert pair_runs.pair(a, _file({7: (1.0, 0.1)})) == {}  # no run in common
    assert pair_runs.table(pair_runs.pair(a, b))[2].startswith("| kitti/2/packaged | 4 | 0.25 / ")
    assert "| 1 / 0 | 4 / 3 |" in pair_runs.table(pair_runs.pair(a, b))[2]
    flipped = pair_runs.pair(b, a)["kitti/2/packaged"]  # A's run 3 nearer in rotation than B's
    assert flipped["b_nearer_cm"] == 1 and flipped["b_nearer_deg"] == 1
    other = _file({0: (1.0, 0.1)})
    other["real"]["kitti"]["levels"]["2"]["tol3"] = other["real"]["kitti"]["levels"]["2"].pop("packaged")
    assert pair_runs.pair(a, other) == {}  # no variant in common
    across = pair_runs.pair(a, other, "packaged", "tol3")  # one variant against another
    assert (
        list(across) == ["kitti/2/packaged against tol3"]
        and across["kitti/2/packaged against tol3"]["same"] == 1
    )


def _time_offset_file(answers: list[tuple[float, float, float | None]], first_run: int = 0) -> dict:
    """A bench_time_offset.py results file: one vineyard row, its runs' (cm, °, δt error ms)."""
    runs = [
        {"translation_cm": cm, "rotation_deg": deg, "time_offset_error_ms": dt, "seconds": 60.0}
        for cm, deg, dt in answers
    ]
    return {
        "first_run": first_run,
        "rows": [{"world": "vineyard", "offset_ms": 20.0, "variant": "odometry", "per_run": runs}],
    }


def test_pair_runs_pairs_time_offset_files_by_their_draws():
    """bench_time_offset.py parts: draw first_run + i is a row's i-th run; the δt errors' medians
    are compared; a side that kept δt fixed reads '–'."""
    a = _time_offset_file([(1.2, 0.06, -0.1), (1.6, 0.08, 0.3), (1.0, 0.05, 0.2), (3.0, 0.3, 0.5)])
    b = _time_offset_file([(0.9, 0.07, 0.4), (1.6, 0.08, 0.3)], first_run=2)  # draws 2 and 3
    row = pair_runs.pair(a, b)["vineyard/20 ms/odometry"]
    assert row["finals"]["run"] == [2, 3] and row["finals"]["a"] == [[1.0, 0.05], [3.0, 0.3]]
    assert row["b_nearer_cm"] == 2 and row["b_nearer_deg"] == 1
    assert row["success"] == {"a": 1, "b": 2}  # within 2 cm / 0.2°: A's draw 3 is not
    assert row["dt_error_ms_median"] == {"a": pytest.approx(0.35), "b": pytest.approx(0.35)}
    fixed = _time_offset_file([(1.0, 0.05, None), (3.0, 0.3, None)], first_run=2)
    line = pair_runs.table(pair_runs.pair(fixed, b))[2]
    assert pair_runs.pair(fixed, b)["vineyard/20 ms/odometry"]["dt_error_ms_median"]["a"] is None
    assert "| – / 0.35 |" in line


def test_pair_runs_cli_prints_the_table_and_draws_the_pairs(tmp_path, capsys, monkeypatch):
    a = _file({0: (1.0, 0.1), 1: (1.5, 0.1), 2: (1.0, 0.1)})
    b = _file({0: (1.0, 0.1), 1: (1.0, 0.2), 2: (3.0, 0.05)})
    paths = [tmp_path / "a.json", tmp_path / "b.json"]
    for path, results in zip(paths, (a, b), strict=True):
        path.write_text(json.dumps(results))
    png = tmp_path / "pairs.png"
    monkeypatch.setattr(sys, "argv", ["pair_runs.py", *map(str, paths), "--plot", str(png)])
    pair_runs.main()
    out = capsys.readouterr().out
    assert "| kitti/2/packaged | 3 |" in out and "| 1 / 1 |" in out and f"wrote {png}" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def _run(cm, deg, raised=None):
    final = None if raised else {"cm": cm, "deg": deg}
    return {
        "start": {"cm": 8.0, "deg": 1.5},
        "final": final,
        "seconds": 2.0,
        "converged": False,
        "raised": raised,
    }


def test_success_thresholds_and_raised_runs():
    runs = [_run(1.0, 0.1), _run(3.0, 0.3), _run(10.0, 0.1), _run(0, 0, raised="DataError: no points")]
    multi, single = bench_real.summarise(runs, frames=6), bench_real.summarise(runs, frames=1)
    assert multi["success_rate"] == 0.25 and single["success_rate"] == 0.5
    assert multi["raised"] == 1 and multi["runs"] == 4
    assert multi["cm_median"] == 3.0  # of the three runs that returned
    assert multi["threshold_cm_deg"] == [2.0, 0.2] and single["threshold_cm_deg"] == [5.0, 0.5]
    assert multi["std_cm_median"] is None  # none of these runs recorded its std


def test_summary_takes_the_reported_std_of_runs_that_kept_it():
    runs = [{**_run(1.0, 0.1), "std": {"cm": c, "deg": c / 10}} for c in (0.2, 0.4, 0.9)]
    summary = bench_real.summarise([*runs, _run(2.0, 0.2)], frames=6)
    assert summary["std_cm_median"] == 0.4 and summary["std_deg_median"] == pytest.approx(0.04)


def _result(name: str, runs: int) -> dict:
    summary = bench_real.summarise([_run(1.0, 0.1)] * runs, frames=6)
    return {
        "levels": {"2": [10.0, 2.0]},
        "success_cm_deg": bench_real.SUCCESS,
        "variants": {"dense": "dense"},
        "configs": {},
        "notes": {},
        "runs": runs,
        "seconds": 1.0,
        "start_draw": "ball",
        "real": {name: {"frames": 6, "levels": {"2": {"dense": {"summary": summary, "runs": []}}}}},
        "synthetic": {},
    }


def test_merge_keeps_the_other_datasets():
    out = bench_real.merged(_result("a", 5), _result("b", 2))
    assert set(out["real"]) == {"a", "b"} and out["runs"] == [5, 2]


def test_merge_keeps_the_other_variants_and_levels_of_one_dataset():
    other = _result("a", 5)
    other["real"]["a"]["levels"]["2"] = {"global": other["real"]["a"]["levels"]["2"]["dense"]}
    other["real"]["a"]["levels"]["10"] = {"global": other["real"]["a"]["levels"]["2"]["global"]}
    out = bench_real.merged(other, _result("a", 2))
    assert set(out["real"]["a"]["levels"]["2"]) == {"dense", "global"}
    assert set(out["real"]["a"]["levels"]["10"]) == {"global"}


def test_report_has_a_real_data_table(monkeypatch):
    monkeypatch.setattr(
        report, "_load", lambda name: _result("kitti-raw-0928-all6", 5) if name == "bench_real" else None
    )
    text = "\n".join(report.real_data())
    assert "### Real data" in text
    assert (
        "| kitti-raw-0928-all6 | 6 | 2° / 10 cm | dense | 5 | 100% | 1.00 / 1.00 | 0.100 / 0.100 | 0 |"
        in text
    )


def test_report_names_the_worlds_of_a_synthetic_row(monkeypatch):
    """A synthetic row's success depends on its worlds as much as on the method, so the table
    names the seeds its runs drew."""
    result = _result("kitti-raw-0928-all6", 3)
    entry = result["real"].pop("kitti-raw-0928-all6")
    entry["levels"]["2"]["dense"]["runs"] = [{**_run(1.0, 0.1), "seed": s} for s in (202, 201, 202)]
    result["synthetic"]["synth-urban-offset0"] = entry
    monkeypatch.setattr(report, "_load", lambda name: result if name == "bench_real" else None)
    assert "| synth-urban-offset0 (seeds 201, 202) | 6 | 2° / 10 cm | dense | 3 |" in "\n".join(
        report.real_data()
    )


def _fake_run(frames, T_start, T_ref, config, seed):
    """A stand-in for a calibration: its 'final error' is the start's, so runs are told apart."""
    start = calibration_error(T_start, T_ref)
    return {"start": {"cm": start.translation_cm, "deg": start.rotation_deg},
            "final": {"cm": start.translation_cm / 10, "deg": start.rotation_deg / 10},
            "seconds": 0.0, "converged": True, "raised": None}  # fmt: skip


def test_rows_gather_each_level_and_variant_in_run_order(monkeypatch):
    monkeypatch.setattr(bench_real, "one_run", _fake_run)
    dataset = bench_real.Dataset("fake", lambda run: ([], _T(), {"seed": run % 2}), 3)
    levels, configs = ["2", "10"], {"dense": None, "global": None}
    tasks = [("fake", level, i) for level, i in bench_real.level_runs(levels, 4)]
    finished = list(bench_real.run_tasks({"fake": dataset}, tasks, configs, bench_real.Starts(), 1, None))
    done = {tasks[index][1:]: runs for index, runs in reversed(finished)}  # as if they finished out of order
    row = bench_real.dataset_row(dataset, levels, done, "here")
    assert list(row["levels"]) == levels
    for level in levels:
        for variant in configs:
            entry = row["levels"][level][variant]
            assert [r["run"] for r in entry["runs"]] == [0, 1, 2, 3] and entry["where"] == "here"
            assert [r["seed"] for r in entry["runs"]] == [0, 1, 0, 1]
    assert (
        row["levels"]["10"]["dense"]["summary"]["cm_median"]
        > row["levels"]["2"]["dense"]["summary"]["cm_median"]
    )


def test_a_benchmark_in_parts_draws_the_runs_of_one_whole_run():
    whole = bench_real.level_runs(["0", "2"], 6)
    parts = bench_real.level_runs(["2"], 3) + bench_real.level_runs(["2"], 3, first=3)
    assert whole == [("0", 0)] + parts


def test_parts_join_run_by_run_and_are_summarised_again():
    """``--join``: the runs of parts drawn with ``--first-run`` make one row per dataset, level and
    variant, in run order, with the success and medians of all of them."""

    def part(first: int, cms: list[float], day: str, where: str) -> dict:
        result = _result("a", len(cms))
        runs = [{**_run(cm, 0.1), "run": first + k} for k, cm in enumerate(cms)]
        entry = {"summary": bench_real.summarise(runs, 6), "runs": runs, "measured": day, "where": where}
        result["real"]["a"]["levels"]["2"]["dense"] = entry
        return result

    whole = bench_real.joined([part(2, [3.0, 4.0], "d2", "here"), part(0, [1.0, 1.5], "d1", "there")])
    entry = whole["real"]["a"]["levels"]["2"]["dense"]
    assert [r["run"] for r in entry["runs"]] == [0, 1, 2, 3]
    assert entry["summary"]["runs"] == 4 and entry["summary"]["success_rate"] == 0.5
    assert entry["summary"]["cm_median"] == pytest.approx(2.25)
    assert entry["measured"] == "d2, d1" and entry["where"] == "here; there"


def test_the_packaged_variant_is_the_packaged_config():
    """The README's rows of ``PACKAGED`` measure what ``calibrate`` runs (and what
    ``bench_real.py`` runs by default); ``global-pyramid`` stays the default before full resolution
    (finest passes at 360 px), ``global-pyramid-fullres-iwfine360`` the one before the flow start;
    ``pool3`` the packaged one with three matchings pooled, ``inside`` with ``edge.border: inside``,
    ``own`` with ``edge.carry: own``."""
    from calib.refine.passes import load_calibrate_config

    pooled, inside, own = (f"{bench_real.PACKAGED}-{v}" for v in ("pool3", "inside", "own"))
    names = [bench_real.PACKAGED, pooled, inside, own, "global-pyramid-fullres-iwfine360", "global-pyramid"]
    configs = bench_real.variant_configs(names)
    packaged = load_calibrate_config()
    assert configs[bench_real.PACKAGED] == packaged
    assert configs[pooled] == packaged.model_copy(update={"pool_matchings": 3})
    edge = packaged.edge.model_copy(update={"border": "inside"})
    assert configs[inside] == packaged.model_copy(update={"edge": edge})
    edge = packaged.edge.model_copy(update={"carry": "own"})
    assert configs[own] == packaged.model_copy(update={"edge": edge})
    before = configs["global-pyramid-fullres-iwfine360"]
    assert before == load_calibrate_config().model_copy(
        update={
            "flow_coarse_passes": 0,
            "flow_coarse_frames": None,
            "probe_frames": None,
            "pool_matchings": 1,
        },
    )
    old = configs["global-pyramid"]
    assert old.finest_focal_px is None and old.pyramid_focals_px == (90.0, 180.0)
    assert old.fine_intensity_weight is None and old.time_offset.from_px is None


def test_the_540_px_variant_differs_from_the_full_resolution_one_only_in_its_finest_level():
    names = ["global-pyramid-fullres-f540-iwfine360", "global-pyramid-fullres-iwfine360"]
    config, full = (bench_real.variant_configs(names)[name] for name in names)
    assert config.finest_focal_px == bench_real.MIDRES_FOCAL_PX
    assert config.model_copy(update={"finest_focal_px": 721.5}) == full


def test_realism_table_shows_each_rows_ring_stripes(monkeypatch):
    px = {"median": 1.5, "mean": 2.0, "p90": 4.0}
    row = {"size": "1242x375", "correspondences": 10, "px": px, "mrad": px}
    result = {
        "target_ratio": 1.5,
        "real": {"kitti-raw-0928": {**row, "ring_stripes": 1.34}},
        "synthetic": {"synth-urban (effects)": {**row, "ratio": 1.0, "ring_stripes": None}},
    }
    monkeypatch.setattr(report, "_load", lambda name: result if name == "bench_realism" else None)
    text = "\n".join(report.realism())
    assert "| dataset | size | correspondences | px | mrad median | ratio | ring stripes |" in text
    assert "| kitti-raw-0928 | 1242x375 | 10 | 1.50 / 2.00 / 4.00 | 1.50 |  | 1.34 |" in text
    assert "| synth-urban (effects) | 1242x375 | 10 | 1.50 / 2.00 / 4.00 | 1.50 | 1.00 | – |" in text


def test_the_flow_coarse_variants_are_the_packaged_config_on_every_frame_or_three():
    from calib.refine.passes import load_calibrate_config

    name = "global-flowcoarse-pyramid-fullres-iwfine360"
    config = bench_real.variant_configs([name])[name]
    assert config.flow_coarse_passes == bench_real.FLOW_COARSE_PASSES > 0
    packaged = config.model_copy(
        update={
            "flow_coarse_frames": bench_real.FLOW_COARSE_FRAMES,
            "probe_frames": bench_real.PROBE_FRAMES,
        }
    )
    assert packaged == load_calibrate_config()
    three_frames = name.replace("flowcoarse", "flowcoarse3")
    three = bench_real.variant_configs([three_frames])[three_frames]
    assert three.flow_coarse_frames == bench_real.FLOW_COARSE_FRAMES
    assert three.model_copy(update={"flow_coarse_frames": None}) == config
    probe4 = three_frames.replace("flowcoarse3", "flowcoarse3-probe4")
    four = bench_real.variant_configs([probe4])[probe4]
    assert four.probe_frames == bench_real.PROBE_FRAMES
    assert four.model_copy(update={"probe_frames": None}) == three


def test_the_ideal_lidar_world_starts_from_the_draws_of_the_world_it_changes(monkeypatch):
    starts = {}
    monkeypatch.setattr(bench_real, "one_run", lambda frames, T_start, *rest, **kw: {"T": T_start})
    datasets = {d.name: d for d in bench_real.synthetic_datasets((5,))}  # lazy: nothing is rendered
    for name in ("synth-urban-offset0", "synth-urban-ideal-lidar", "synth-urban-offset"):
        dataset = bench_real.Dataset(name, lambda run: ([], _T(), {}), 10, datasets[name].draws_as)
        starts[name] = bench_real.run_all(dataset, "10", 3, {"packaged": None}, bench_real.Starts())[
            "packaged"
        ]["T"]
    np.testing.assert_array_equal(starts["synth-urban-offset0"], starts["synth-urban-ideal-lidar"])
    assert not np.array_equal(starts["synth-urban-offset0"], starts["synth-urban-offset"])
    assert datasets["synth-vineyard-ideal-lidar"].draws_as == "synth-vineyard-offset0"


def test_the_ideal_lidar_world_changes_only_the_lasers_angle_errors():
    from calib.synth.synth_config import load_synth_config

    paired = load_synth_config("urban", **bench_real.SYNTH_VARIANTS["offset0"])
    ideal = load_synth_config("urban", **bench_real.SYNTH_VARIANTS["ideal-lidar"])
    assert paired.lidar.laser_angle_std_deg > 0 and ideal.lidar.laser_angle_std_deg == 0
    assert ideal.model_copy(update={"lidar": paired.lidar}) == paired


def test_results_name_the_numerical_libraries_they_were_measured_with():
    from results_io import NUMERICAL_PACKAGES, cpu_description, package_versions

    versions = package_versions()
    assert list(versions) == list(NUMERICAL_PACKAGES)
    assert versions["torch"] == torch.__version__ and versions["numpy"] == np.__version__
    if Path("/proc/cpuinfo").is_file():  # Linux: the model and its vector extensions
        assert cpu_description()
    a, b, c = (_result(name, 2) for name in "abc")
    a["packages"], b["packages"], c["packages"] = [versions], [{**versions, "numpy": "1.0"}], [versions]
    parts = bench_real.merged(bench_real.merged(a, b), c)
    assert parts["packages"] == [versions, {**versions, "numpy": "1.0"}]  # each install once


def test_the_matched_count_variants_name_their_rules():
    """``keep8c-gain5c`` is the packaged config; ``nomatched`` the same with the matched-count
    rules off (as packaged until stop 68); ``keep8`` and ``keep85c`` set only what they name."""
    p = bench_real.PACKAGED
    names = [p, f"{p}-keep8c-gain5c", f"{p}-nomatched", f"{p}-keep8", f"{p}-keep85c-gain5c"]
    configs = bench_real.variant_configs(names)
    keys = ("level_min_share", "check_gain", "matched_below_px")
    assert configs[names[1]] == configs[p]
    rules = {name: tuple(getattr(configs[name], k) for k in keys) for name in names[2:]}
    assert rules == {
        names[2]: (0.0, None, None),
        names[3]: (0.8, None, None),
        names[4]: (0.85, 0.05, 360.0),
    }
    assert configs[names[2]].model_copy(update={k: getattr(configs[p], k) for k in keys}) == configs[p]


def test_the_coarse_gain_variants_set_it_alone():
    """``cgain5`` sets ``coarse_gain`` 0.5, ``nocgain`` turns it off; nothing else moves."""
    p = bench_real.PACKAGED
    configs = bench_real.variant_configs([p, f"{p}-cgain5", f"{p}-nocgain"])
    assert configs[f"{p}-cgain5"].coarse_gain == 0.5 and configs[f"{p}-nocgain"].coarse_gain is None
    for name in (f"{p}-cgain5", f"{p}-nocgain"):
        assert configs[name].model_copy(update={"coarse_gain": configs[p].coarse_gain}) == configs[p]
