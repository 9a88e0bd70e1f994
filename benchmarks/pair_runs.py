"""Two ``bench_real.py`` (or two ``bench_time_offset.py``) results files compared run by run: the
same datasets, levels and draws under two codes, two variants or two start nudges
(``bench_real.py --nudge``). Per dataset, level and variant present in both (for
``bench_time_offset.py``: per world, offset and variant, its ``--first-run`` numbering the draws):
how far each run's answer moved between the two (median, 90th percentile and largest, in cm and
°), how many ended where they did (within 0.005 cm and 0.0005°, the printed digits), how many moved
nearer the reference in translation and in rotation, and both files' success counts, medians,
median time-offset errors (where estimated) and seconds over the runs they share. ``--plot PNG`` draws each
pair's two answers (translation against rotation error) joined by a line, a panel per dataset,
level and variant: where one side lies up and to the left of the other, the two trade rotation for
translation.

Two runs of one code from starts a micrometre apart (``--nudge 1``) end apart by what a comparison
of two variants cannot resolve on that many draws: the checks that end each level compare the
median residuals of two matchings, and a pass that leaves them nearly equal is kept or undone by a
hair, after which the two calibrations take different paths. Prints a table and, with ``--json``,
writes it there.

    .venv/bin/python benchmarks/pair_runs.py A.json B.json [--variant NAME | --variants A,B]
        [--json OUT.json] [--plot OUT.png]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

SAME_CM, SAME_DEG = 0.005, 0.0005
"""Two answers this close are the same run (what bench_real prints)."""


TIME_OFFSET_SUCCESS = (2.0, 0.2)
"""``bench_time_offset.py``'s success line (its sequences have ten frames or more)."""


def _time_offset_runs(results: dict) -> dict[tuple[str, str, str], tuple[dict[int, dict], tuple]]:
    """A ``bench_time_offset.py`` file's rows as :func:`runs_of` gives them: draw ``first_run + i``
    is the row's ``i``-th run, its answer and its time-offset error."""
    first = int(results.get("first_run", 0))
    out = {}
    for row in results["rows"]:
        key = (row["world"], f"{row['offset_ms']:g} ms", row["variant"])
        runs = {
            first + i: {
                "final": {"cm": r["translation_cm"], "deg": r["rotation_deg"]},
                "seconds": r["seconds"],
                "dt_error_ms": r["time_offset_error_ms"],
            }
            for i, r in enumerate(row["per_run"])
        }
        out[key] = (runs, TIME_OFFSET_SUCCESS)
    return out


def runs_of(results: dict) -> dict[tuple[str, str, str], tuple[dict[int, dict], tuple]]:
    """``{(dataset, level, variant): ({run: run}, success)}`` of a results file, runs that returned;
    ``success`` the ``(cm, °)`` line a run must end within."""
    if "rows" in results:
        return _time_offset_runs(results)
    out = {}
    for part in ("real", "synthetic"):
        for dataset, row in results.get(part, {}).items():
            success = tuple(results["success_cm_deg"]["multi" if row["frames"] > 1 else "single"])
            for level, variants in row["levels"].items():
                for variant, entry in variants.items():
                    runs = {int(r["run"]): r for r in entry["runs"] if r.get("final") is not None}
                    out[(dataset, level, variant)] = (runs, success)
    return out


def _dt_median(runs: dict[int, dict], shared: list[int]) -> float | None:
    """The median |time-offset error| (ms) of the shared runs; ``None`` where one did not estimate it."""
    errors = [runs[i].get("dt_error_ms") for i in shared]
    return None if None in errors else float(np.median(np.abs(errors)))


def compared(a: dict[int, dict], b: dict[int, dict], success: tuple[float, float]) -> dict | None:
    """The runs both hold, compared (``None`` where they share none)."""
    shared = sorted(set(a) & set(b))
    if not shared:
        return None
    final = {
        side: np.array([[runs[i]["final"]["cm"], runs[i]["final"]["deg"]] for i in shared])
        for side, runs in (("a", a), ("b", b))
    }
    moved = np.abs(final["a"] - final["b"])
    ok = {side: int(np.sum((f[:, 0] <= success[0]) & (f[:, 1] <= success[1]))) for side, f in final.items()}
    return {
        "runs": len(shared),
        "moved_cm": {
            "median": float(np.median(moved[:, 0])),
            "p90": float(np.percentile(moved[:, 0], 90)),
            "max": float(moved[:, 0].max()),
        },
        "moved_deg": {
            "median": float(np.median(moved[:, 1])),
            "p90": float(np.percentile(moved[:, 1], 90)),
            "max": float(moved[:, 1].max()),
        },
        "same": int(np.sum((moved[:, 0] < SAME_CM) & (moved[:, 1] < SAME_DEG))),
        "b_nearer_cm": int(np.sum(final["b"][:, 0] < final["a"][:, 0] - SAME_CM)),
        "b_nearer_deg": int(np.sum(final["b"][:, 1] < final["a"][:, 1] - SAME_DEG)),
        "success": ok,
        "cm_median": {side: float(np.median(f[:, 0])) for side, f in final.items()},
        "deg_median": {side: float(np.median(f[:, 1])) for side, f in final.items()},
        "seconds_median": {
            side: float(np.median([runs[i]["seconds"] for i in shared]))
            for side, runs in (("a", a), ("b", b))
        },
        "dt_error_ms_median": {side: _dt_median(runs, shared) for side, runs in (("a", a), ("b", b))},
        "finals": {"run": shared, **{side: f.tolist() for side, f in final.items()}},
    }


def pair(first: dict, second: dict, variant: str | None = None, other: str | None = None) -> dict[str, dict]:
    """Every ``dataset / level / variant`` both files hold (``variant``: only that one), compared;
    with ``other`` too, ``variant`` of the first file against ``other`` of the second (two
    variants of one run, or of two)."""
    a, b = runs_of(first), runs_of(second)
    out = {}
    for key in sorted(a):
        if variant is not None and key[2] != variant:
            continue
        twin = key if other is None else (*key[:2], other)
        if twin not in b:
            continue
        (runs_a, success), (runs_b, _) = a[key], b[twin]
        if (row := compared(runs_a, runs_b, success)) is not None:
            out["/".join(key) if other is None else f"{'/'.join(key)} against {other}"] = row
    return out


def _ms(value: float | None) -> str:
    return "–" if value is None else f"{value:.2f}"


def table(rows: dict[str, dict]) -> list[str]:
    lines = [
        "| dataset / level / variant | runs | moved cm median / p90 / max | moved ° median / p90 / max "
        "| same | B nearer cm / ° | success A / B | cm median A / B | ° median A / B "
        "| δt error ms median A / B | s A / B |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key, r in rows.items():
        cm, deg, ok = r["moved_cm"], r["moved_deg"], r["success"]
        medians, degrees, seconds = r["cm_median"], r["deg_median"], r["seconds_median"]
        lines.append(
            f"| {key} | {r['runs']} | {cm['median']:.2f} / {cm['p90']:.2f} / {cm['max']:.2f} "
            f"| {deg['median']:.3f} / {deg['p90']:.3f} / {deg['max']:.3f} | {r['same']} "
            f"| {r['b_nearer_cm']} / {r['b_nearer_deg']} | {ok['a']} / {ok['b']} "
            f"| {medians['a']:.2f} / {medians['b']:.2f} | {degrees['a']:.3f} / {degrees['b']:.3f} "
            f"| {_ms(r['dt_error_ms_median']['a'])} / {_ms(r['dt_error_ms_median']['b'])} "
            f"| {seconds['a']:.1f} / {seconds['b']:.1f} |"
        )
    return lines


def plot(rows: dict[str, dict], path: Path, names: tuple[str, str] = ("A", "B")) -> Path:
    """Each row's pairs of answers, translation (cm) against rotation (°), A and B joined by a
    line, a panel per row, written to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, axes = plt.subplots(1, len(rows), figsize=(5.5 * len(rows), 4.5), squeeze=False)
    for ax, (key, r) in zip(axes[0], rows.items(), strict=True):
        a, b = np.array(r["finals"]["a"]), np.array(r["finals"]["b"])
        for p, q in zip(a, b, strict=True):
            ax.plot([p[0], q[0]], [p[1], q[1]], color="0.75", lw=0.8, zorder=1)
        ax.scatter(a[:, 0], a[:, 1], c="tab:blue", label=names[0], zorder=2)
        ax.scatter(b[:, 0], b[:, 1], c="tab:red", marker="^", label=names[1], zorder=2)
        ax.set_xscale("log")
        ax.set_yscale("log")
        for axis in (ax.xaxis, ax.yaxis):  # 1-2-5 labels: a narrow span's minor labels collide
            axis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda value, _: f"{value:g}"))
            axis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_title(key, fontsize=8, wrap=True)
        ax.set_xlabel("final translation error (cm)")
        ax.set_ylabel("final rotation error (°)")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "first", type=Path, help="results file A (bench_real.py or bench_time_offset.py --name ...)"
    )
    parser.add_argument("second", type=Path, help="results file B, the same draws")
    parser.add_argument("--variant", default=None, help="only this variant")
    parser.add_argument(
        "--variants", default=None, help="A,B: variant A of the first file against B of the second"
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the comparison here")
    parser.add_argument("--plot", type=Path, default=None, help="also draw the pairs here (PNG)")
    args = parser.parse_args()
    first, second = (json.loads(p.read_text()) for p in (args.first, args.second))
    variant, other = args.variants.split(",", 1) if args.variants else (args.variant, None)
    rows = pair(first, second, variant, other)
    if not rows:
        parser.error("the two files share no dataset, level and variant with runs in common")
    print("\n".join(table(rows)))
    if args.json is not None:
        args.json.write_text(
            json.dumps({"a": str(args.first), "b": str(args.second), "pairs": rows}, indent=2)
        )
        print(f"wrote {args.json}")
    if args.plot is not None:
        names = (variant, other) if other else (args.first.stem, args.second.stem)
        print(f"wrote {plot(rows, args.plot, names)}")


if __name__ == "__main__":
    main()
