"""The benchmark tables as Markdown, from the JSON the benchmarks wrote, with the date they were
measured and the machine. A benchmark that has not run is left out with a note.

``make bench`` runs it last, without ``--readme``: it writes ``benchmarks/results/RESULTS.md``
only. ``make report`` passes ``--readme README.md``: then it also rewrites the README's results
section (between its ``results`` markers); it refuses when no benchmark has run.

    python benchmarks/report.py [--readme README.md]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import statistics
from pathlib import Path

RESULTS = Path(__file__).parent / "results"
START, END = "<!-- results:start -->", "<!-- results:end -->"


def _load(name: str) -> dict | list | None:
    path = RESULTS / f"{name}.json"
    return json.loads(path.read_text()) if path.is_file() else None


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + [
        "| " + " | ".join(r) + " |" for r in rows
    ]


def speed() -> list[str]:
    rows = []
    if synth := _load("synth"):
        for world, r in synth["speed"].items():
            rows.append([f"synthesis, {world}", f"{r['workers_2']:.1f} frames/s (2 workers)"])
        for world, r in synth["odometry"].items():
            rows.append([f"KISS-ICP, {world}", f"{1 / r['seconds_per_scan']:.1f} frames/s"])
    if matcher := _load("matcher"):
        real = matcher.pop("kitti-raw-full-resolution", None)
        for world, r in matcher.items():
            rows.append([f"EdgeMatcher, {world}", f"{r['matcher_ms_median']:.0f} ms/frame"])
            rows.append([f"map accumulation, {world}", f"{r['maps_frames_per_s']:.0f} frames/s"])
        for focal, r in (real or {}).items():
            if isinstance(r, dict):
                rows.append(
                    [
                        f"EdgeMatcher, real KITTI {real['size']}, working focal {focal} px",
                        f"{r['first_ms']:.0f} ms first match of a frame, {r['again_ms']:.0f} ms after",
                    ]
                )
    if predictor := _load("predictor"):
        ort, eager = predictor["backends"]["onnxruntime"], predictor["backends"]["torch eager"]
        for size in ort:
            fast, slow = ort[size]["ms_median"], eager[size]["ms_median"]
            rows.append(
                [
                    f"support predictor, {size}",
                    f"onnxruntime {fast:.1f} ms, torch eager {slow:.1f} ms (ratio {slow / fast:.2f})",
                ]
            )
    if flow := _load("flow_matcher"):
        for name, r in flow["sequences"].items():
            ms = statistics.median(v["ms_per_frame"] for k, v in r.items() if k.endswith("/flow"))
            rows.append([f"flow matcher, {name}", f"{ms:.0f} ms/frame (onnxruntime)"])
    if refine := _load("refine"):
        rows.append(["Stage 4 refinement (one solve)", f"{refine['sgis']['seconds_median']:.2f} s"])
    if whole := _load("speed"):
        s, runs = whole["configs"]["packaged"]["summary"], whole["configs"]["packaged"]["runs"]
        rows.append(
            [
                "one calibration: 10 synthetic urban frames at 1242x375 from 10° / 50 cm, alone",
                f"{s['seconds_median']:.1f} s median, {s['seconds_p90']:.1f} s p90, {s['within_target']} of "
                f"{len(runs)} within {whole['target_s']:g} s; {s['in_reference_matches_median']:.0f} "
                f"full-resolution matches of one frame ({whole['reference_match_ms']:.0f} ms each here)",
            ]
        )
    sources = ("synth", "matcher", "predictor", "flow_matcher", "refine", "speed")
    days = [f"{name} {_day(name)}" for name in sources if (RESULTS / f"{name}.json").is_file()]
    note = ["", f"Measured on (each benchmark's results file): {', '.join(days)}."] if days else []
    return ["### Speed", ""] + (
        _table(["what", "figure"], rows) + note if rows else ["(no speed benchmark has run)"]
    )


def _day(name: str) -> str:
    """The day ``results/NAME.json`` was written."""
    return datetime.date.fromtimestamp((RESULTS / f"{name}.json").stat().st_mtime).isoformat()


def accuracy() -> list[str]:
    lines = ["### Accuracy", ""]
    result = _load("accuracy")
    if result is None:
        return lines + ["(benchmarks/bench_accuracy.py has not run)"]
    rows = []
    for world, supports in result["stage4"].items():
        for name, s in supports.items():
            t, r, wins = s["translation_cm"], s["rotation_deg"], s["vs_uniform"]
            won = (
                f"{wins['translation_wins']}/{wins['runs']}, {wins['rotation_wins']}/{wins['runs']}"
                if wins
                else ""
            )
            rows.append(
                [
                    world,
                    name.replace("_", " "),
                    f"{t['mean']:.2f} / {t['median']:.2f}",
                    f"{r['mean']:.3f} / {r['median']:.3f}",
                    won,
                ]
            )
    lines += [
        f"Stage 4 from a 10 cm / 2° error, {result['runs']} paired runs (held-out seed 9, 80 frames):",
        "",
    ]
    lines += _table(
        [
            "world",
            "support",
            "translation cm mean / median",
            "rotation ° mean / median",
            "beats uniform t, r",
        ],
        rows,
    )
    rows = []
    for world, s in result["stage1"].items():
        if "refused" in s:
            rows.append([world, "refused", "", "", s["refused"]])
        else:
            rows.append(
                [
                    world,
                    f"{s['rotation_deg']:.2f}",
                    f"{s['translation_cm']:.1f} ({s['translation_source']})",
                    f"{s['hand_eye_translation_cm']:.0f}",
                    f"{s['seconds']:.0f} s",
                ]
            )
    lines += ["", f"Stage 1 from motion, {result['stage1_frames']} frames (seed 21):", ""]
    lines += _table(["world", "rotation °", "translation cm", "hand–eye's own translation cm", "time"], rows)
    return lines


def hand_eye() -> list[str]:
    result = _load("hand_eye")
    if result is None:
        return []
    methods = [k for k in result[0] if k not in ("noise_deg", "noise_cm")]
    rows = [
        [f"{r['noise_deg']}° / {r['noise_cm']} cm"]
        + [f"{r[m]['translation_cm']:.2f} / {r[m]['rotation_deg']:.3f}" for m in methods]
        for r in result
    ]
    return ["", "Hand–eye against OpenCV (translation cm / rotation °, mean of 20 draws):", ""] + _table(
        ["noise", *methods], rows
    )


def matchers() -> list[str]:
    result = _load("flow_matcher")
    if result is None:
        return []
    px = lambda v: f"{v:.2f}" if v is not None else "–"  # noqa: E731
    rows = [
        [
            name,
            *key.split("/"),
            f"{px(r['epe_median_px'])} / {px(r['epe_p90_px'])}",
            px(r["toward_reference"]),
            px(r.get("epe_median_common_px")),
            px(r["epe_median_rigid_px"]),
            px(r["epe_median_foliage_px"]),
            px(r["no_matching_median_px"]),
            f"{r['points_per_frame']:.0f}",
        ]
        for name, sequence in result["sequences"].items()
        for key, r in sequence.items()
    ]
    lines = [
        "",
        f"Stage 2, endpoint errors in px under errors of 1-10° ({result['cm_per_deg']:g} cm per degree); "
        "toward: the share of residuals pointing toward the reference:",
        "",
    ]
    lines += _table(
        [
            "sequence",
            "°",
            "matcher",
            "median / p90",
            "toward",
            "common points",
            "rigid",
            "foliage",
            "no matching",
            "points/frame",
        ],
        rows,
    )
    rows = []
    for world, entries in result.get("calibration", {}).items():
        for key, s in entries.items():
            if key.startswith("flow_vs_edge"):
                continue
            matcher, support = key.split("/")
            wins = entries.get(f"flow_vs_edge/{support}") if matcher == "flow" else None
            won = (
                f"{wins['translation_wins']}/{wins['runs']}, {wins['rotation_wins']}/{wins['runs']}"
                if wins
                else ""
            )
            t, r = s["translation_cm"], s["rotation_deg"]
            rows.append(
                [world, matcher, "sgis predicted" if support == "onnx" else support,
                 f"{t['mean']:.2f} / {t['median']:.2f}", f"{r['mean']:.3f} / {r['median']:.3f}", won]
            )  # fmt: skip
    if rows:
        lines += [
            "",
            "Stage 4 with each matcher from 10 cm / 2°, paired runs (held-out seed 9, 80 frames):",
            "",
        ]
        lines += _table(
            ["world", "matcher", "support", "translation cm mean / median", "rotation ° mean / median",
             "flow beats edge t, r"],
            rows,
        )  # fmt: skip
    return lines


def real_data() -> list[str]:
    """Calibration from perturbed starts on the real fixtures and full-resolution synthetic
    sequences (``bench_real.json``)."""
    result = _load("bench_real")
    if result is None:
        return ["### Real data", "", "(benchmarks/bench_real.py has not run)"]
    opt = lambda v, spec: format(v, spec) if v is not None else "–"  # noqa: E731
    multi, single = result["success_cm_deg"]["multi"], result["success_cm_deg"]["single"]
    draw = "uniform in the ball of" if result["start_draw"] == "ball" else "exactly"
    lines = [
        "### Real data",
        "",
        f"Calibration from starts of random direction, {draw} each size (Stages 2–4, uniform support, "
        "edge matcher; global+dense: the global coarse stage, searching with two edge maps, then the "
        "dense passes, which go on from the start, initial or coarse, that their first pass aligns "
        "best; dense: the global coarse stage off; pyramid: the dense passes run first at working "
        "focal lengths of 90 and 180 px, on two frames or more since 2026-11-26 (`pyramid_min_frames`); "
        "at full resolution: the finest passes at 721.5 px after a 360 px level, the probe of the "
        "starts at 360 px, one frame's passes from 360 px on; 360 px on: the intensity edges at 0.25 "
        "from there; flow coarse on 3 frames: two passes of the learned matcher from the initial "
        "extrinsic on three of the frames, one more start; global+flow coarse on 3 frames+pyramid+"
        "dense at full resolution, 360 px on is the packaged config since 2026-11-27, the same "
        "without the flow start from 2026-11-26, global+pyramid+dense from 2026-11-25, global+dense "
        "before); contour: the "
        "experimental contour refinement switched on). "
        f"Success: within {multi[0]:g} cm and {multi[1]:g}° of the reference for several frames, "
        f"{single[0]:g} cm and {single[1]:g}° for one; a run that raises fails. Final errors: median "
        "/ 90th percentile of the runs that returned; seconds: median per calibration; measured: the day "
        "of the run that wrote the row (runs are merged; – : before rows kept their day) and where "
        "(several runs at once on one machine share its memory bandwidth: their seconds are longer "
        "than one run's alone).",
    ]
    for part, title in (("real", "Real fixtures"), ("synthetic", "Synthetic, full resolution, unseen seeds")):
        rows = []
        for name, row in result.get(part, {}).items():
            for level, variants in row["levels"].items():
                cm, deg = result["levels"][level]
                for variant, entry in variants.items():
                    s = entry["summary"]
                    # a synthetic row's success says as much about its worlds as about the method
                    # (README: one config, 85 % on seeds 201-202 and 50 % on 301-304)
                    seeds = sorted({r["seed"] for r in entry["runs"] if "seed" in r})
                    rows.append(
                        [
                            f"{name} (seeds {', '.join(map(str, seeds))})" if seeds else name,
                            str(row["frames"]),
                            f"{deg:g}° / {cm:g} cm",
                            result["variants"][variant],
                            str(s["runs"]),
                            opt(s["success_rate"], ".0%"),
                            f"{opt(s['cm_median'], '.2f')} / {opt(s['cm_p90'], '.2f')}",
                            f"{opt(s['deg_median'], '.3f')} / {opt(s['deg_p90'], '.3f')}",
                            str(s["raised"]),
                            opt(s["seconds_median"], ".1f"),
                            ", ".join(x for x in (entry.get("measured", "–"), entry.get("where")) if x),
                        ]
                    )
        if rows:
            lines += ["", f"{title}:", ""]
            lines += _table(
                ["dataset", "frames", "start", "variant", "runs", "success", "translation cm median / p90",
                 "rotation ° median / p90", "raised", "s", "measured"],
                rows,
            )  # fmt: skip
    for name, note in result.get("notes", {}).items():
        lines += ["", f"{name}: {note}."]
    return lines


def realism() -> list[str]:
    """The matcher's endpoint error under the reference, real fixtures beside full-resolution
    synthetic frames (``bench_realism.json``)."""
    result = _load("bench_realism")
    if result is None:
        return ["### Synthetic against real frames", "", "(benchmarks/bench_realism.py has not run)"]
    lines = [
        "### Synthetic against real frames",
        "",
        "The EdgeMatcher's endpoint error under the reference extrinsic (full-resolution pixels and "
        "milliradians; median / mean / 90th percentile over the correspondences). Ratio: the real KITTI "
        f"median over the synthetic one; the goal is at most {result['target_ratio']:g}. Ring stripes: "
        "how striped along the scan lines the LiDAR's intensity stays once each laser's gain is levelled "
        "(`calib.features.ring_stripes`, median over the frames; about 1 for lasers that differ by a gain "
        "alone).",
        "",
    ]
    rows = []
    for part in ("real", "synthetic"):
        for name, row in result[part].items():
            px, mrad = row["px"], row["mrad"]
            ratio = row.get("ratio")
            rows.append(
                [
                    name,
                    row["size"],
                    str(row["correspondences"]),
                    f"{px['median']:.2f} / {px['mean']:.2f} / {px['p90']:.2f}"
                    if px["median"] is not None
                    else "–",
                    f"{mrad['median']:.2f}" if mrad["median"] is not None else "–",
                    f"{ratio:.2f}" if ratio is not None else "",
                    f"{row['ring_stripes']:.2f}" if row.get("ring_stripes") is not None else "–",
                ]
            )
    header = ["dataset", "size", "correspondences", "px", "mrad median", "ratio", "ring stripes"]
    return lines + _table(header, rows)


def check() -> list[str]:
    """``supportnet check`` on the real fixtures and synthetic worlds (``check.json``)."""
    result = _load("check")
    if result is None:
        return ["### check", "", "(benchmarks/bench_check.py has not run)"]
    config = result["config"]
    lines = [
        "### check",
        "",
        f"`supportnet check` on the reference and on {result['draws']} draws of each error size in random "
        f"directions (verdict bad from a joint significance of {config['m_bad']:g}, suspect from "
        f"{config['m_good']:g}; tolerance {config['rotation_tolerance_deg']:g}° / "
        f"{config['translation_tolerance_cm']:g} cm). Smallest error shown: the worst axis.",
    ]
    for part, title in (("real", "Real fixtures"), ("synthetic", "Synthetic, KITTI pixel scale")):
        rows = []
        for name, row in result.get(part, {}).items():
            ref, big, small = row["reference"], row["1deg_5cm"], row["0.5deg_2.5cm"]
            rows.append(
                [
                    name,
                    str(row["frames"]),
                    ref["verdict"],
                    f"{ref['significance']:.1f}",
                    f"{ref['score']:.3f}",
                    f"{big['bad']:.0%} / {big['suspect']:.0%}",
                    f"{small['bad']:.0%} / {small['suspect']:.0%}",
                    f"{ref['detectable_deg']:.2f}° / {ref['detectable_cm']:.1f} cm",
                ]
            )
        if rows:
            lines += ["", f"{title}:", ""]
            lines += _table(
                ["dataset", "frames", "reference", "m", "score", "1° / 5 cm: bad / suspect",
                 "0.5° / 2.5 cm: bad / suspect", "smallest error shown"],
                rows,
            )  # fmt: skip
    return lines


def measured_on() -> str | None:
    """The day the newest results were written (not today: ``make report`` may run much later)."""
    days = [_day(p.stem) for p in RESULTS.glob("*.json")]
    return max(days) if days else None


def replace_section(readme: str, lines: list[str]) -> str:
    """``readme`` with the results block's ``### `` section of the same title as ``lines`` replaced
    by them (added at the block's end when it has none)."""
    if START not in readme or END not in readme:
        raise SystemExit(f"report.py: the README has no {START} ... {END} section")
    head, rest = readme.split(START, 1)
    block, tail = rest.split(END, 1)
    title = lines[0]
    text = "\n".join(lines) + "\n"
    found = re.search(rf"^{re.escape(title)}\n.*?(?=^### |\Z)", block, flags=re.S | re.M)
    block = block[: found.start()] + text + "\n" + block[found.end() :] if found else block + "\n" + text
    return head + START + block.replace("\n\n\n", "\n\n") + END + tail


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--readme", type=Path, default=None, help="Also rewrite this README's results section."
    )
    parser.add_argument(
        "--only",
        default=None,
        help="comma-separated sections (real, check, realism, speed) to replace in the README, keeping "
        "the others as they are (for a benchmark run on its own)",
    )
    args = parser.parse_args()
    if args.only is not None:
        if args.readme is None:
            raise SystemExit("report.py: --only needs --readme")
        pick = {"real": real_data, "check": check, "realism": realism, "speed": speed}
        if bad := [name for name in args.only.split(",") if name not in pick]:
            raise SystemExit(f"report.py: unknown section(s) {', '.join(bad)}; choose from {', '.join(pick)}")
        readme = args.readme.read_text()
        for name in args.only.split(","):
            readme = replace_section(readme, pick[name]())
        args.readme.write_text(readme)
        return
    day = measured_on()
    if day is None:
        raise SystemExit(f"report.py: no results in {RESULTS}: run `make bench` first")
    machine = f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}"
    machine += f", python {platform.python_version()}"
    body = [
        f"Measured by `make bench` on {day} ({machine}); written here by `make report`.",
        "",
        *speed(),
        "",
        *accuracy(),
        *matchers(),
        *hand_eye(),
        "",
        *realism(),
        "",
        *real_data(),
        "",
        *check(),
    ]
    text = "\n".join(body) + "\n"
    (RESULTS / "RESULTS.md").write_text("# Benchmark results\n\n" + text)
    if args.readme is not None:
        readme = args.readme.read_text()
        if START not in readme or END not in readme:
            raise SystemExit(f"report.py: {args.readme} has no {START} ... {END} section")
        readme = re.sub(
            re.escape(START) + ".*?" + re.escape(END), lambda _: f"{START}\n{text}{END}", readme, flags=re.S
        )
        args.readme.write_text(readme)
    print(text)


if __name__ == "__main__":
    main()
