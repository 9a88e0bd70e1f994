"""``supportnet calibrate --online``: a stream calibrated window by window (Stage 2 matcher,
Stage 3 support, Stage 4 SGIS refinement), fused into a running estimate with its uncertainty
(:mod:`calib.refine.tracking`), with a drift alarm.

Writes ``estimates.csv`` and ``estimates.json`` (one row per window: the window's own estimate,
the running one, its standard deviations, the drift flag, and the error against the truth where
the data carries it), ``parameters.png`` (the six parameters over time) and ``config.yaml``.
"""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import numpy as np
import torch
from rich.console import Console

from calib.data import open_dataset
from calib.errors import ConfigError, DataError
from calib.geometry import calibration_error, perturb
from calib.pipeline import OnlineCalibrator
from calib.refine.passes import CalibrateConfig
from calib.refine.tracking import departure
from calib.results import SCHEMA_VERSION
from calib.support.map_files import check_maps_fingerprint
from supportnet.cli.cmd_calibrate import parse_init, support_paths
from supportnet.cli.console import make_console
from supportnet.cli.output_dir import atomic_output, claim_output, progress_bar, resolved_config, write_json
from supportnet.runtime.matcher_factory import build_matcher
from supportnet.runtime.support_sources import offline_maps_folders, parse_supports

__all__ = ["run_online", "true_extrinsics"]

PARAMETERS = ("tx cm", "ty cm", "tz cm", "rx °", "ry °", "rz °")


def true_extrinsics(data: Path, sequence: str | None) -> np.ndarray | None:
    """``(F, 4, 4)`` per-frame true extrinsics of a synthetic sequence (or bag) written with
    ``--drift`` (``meta.json``'s ``true_T_cam_lidar``), or ``None``."""
    candidates = [Path(data) / "sequences" / (sequence or "") / "meta.json", Path(data) / "meta.json"]
    meta = next((m for m in candidates if m.is_file()), None)
    if meta is None:
        return None
    try:
        value = json.loads(meta.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise DataError(meta, "is not a text file (not UTF-8)") from None
    except ValueError as exc:
        raise DataError(meta, f"is not valid JSON ({exc})") from None
    if not isinstance(value, dict):
        raise DataError(meta, f"must hold a JSON object, not a {type(value).__name__}")
    rows = value.get("true_T_cam_lidar")
    if rows is None:
        return None
    shape = "a list with one row of 12 numbers (3x4 [R | t]) per frame"
    if not isinstance(rows, list) or not rows:
        raise DataError(meta, f"'true_T_cam_lidar' must be {shape}")
    for i, row in enumerate(rows):
        if (
            not isinstance(row, list)
            or len(row) != 12
            or any(isinstance(v, bool) or not isinstance(v, int | float) for v in row)
        ):
            raise DataError(meta, f"'true_T_cam_lidar' row {i} is not 12 numbers; expected {shape}")
    try:
        values = np.asarray(rows, np.float64)
    except OverflowError:
        values = np.full((1, 1), np.inf)
    if not np.isfinite(values).all():
        raise DataError(meta, "'true_T_cam_lidar' holds NaN, infinite or out-of-range values")
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3] = values.reshape(-1, 3, 4)
    return T


def _readable(x: np.ndarray) -> list[float]:
    """A twist as (cm, cm, cm, °, °, °)."""
    return [*(100 * x[:3]).tolist(), *np.degrees(x[3:]).tolist()]


def run_online(
    data: Path,
    sequence: str | None,
    support_text: str,
    init_text: str,
    out: Path,
    config: CalibrateConfig,
    seed: int = 0,
    overwrite: bool = False,
    console: Console | None = None,
    camera: int | str | None = None,
) -> dict:
    """Calibrate ``data`` as a stream (:class:`calib.pipeline.OnlineCalibrator`); returns what
    ``estimates.json`` holds."""
    console = console or make_console()
    inputs = [data, *support_paths(support_text)]
    claim_output(out, overwrite, inputs)
    online = config.online
    supports = parse_supports(support_text, config.support_map)
    if len(supports) != 1:
        raise ConfigError("--support", "online calibration takes one support, not a comma-separated list")
    support = supports[0]
    init_kind, init_arg = parse_init(init_text)
    if init_kind == "stage1":
        raise ConfigError("--init", "online calibration starts from perturb:CM,DEG or file:PATH")
    matcher = build_matcher(config.matcher, config.edge, config.flow_model)
    truth = true_extrinsics(data, sequence)
    start = time.perf_counter()
    rows = []
    with open_dataset(data, sequence=sequence, camera=camera) as seq:
        for maps in offline_maps_folders(supports):
            check_maps_fingerprint(maps, seq)
        T_file = seq.calibration.T_cam_lidar
        if T_file is None and init_kind != "file":
            raise DataError(data, "has no calibration on file; start from --init file:PATH")
        if init_kind == "perturb":
            T_init = perturb(T_file, *init_arg, torch.Generator().manual_seed(seed))
        else:
            T_init = init_arg
        T_file = T_file if T_file is not None else T_init
        if len(seq) < online.window:
            raise DataError(data, f"has {len(seq)} frames, fewer than one window ({online.window})")
        if truth is not None and len(truth) < len(seq):
            raise DataError(
                data, f"meta.json's 'true_T_cam_lidar' has {len(truth)} rows for {len(seq)} frames"
            )
        calibrator = OnlineCalibrator(T_init, support, matcher, config, T_file=T_file, seed=seed)
        windows = (len(seq) - online.window) // online.step + 1
        with progress_bar("online", console) as progress:
            task = progress.add_task("windows", total=windows)
            for frame in seq:
                estimate = calibrator.push(frame)
                if estimate is None:
                    continue
                middle = estimate.first_frame + online.window // 2
                row = {
                    **estimate.to_dict(),
                    "window_estimate": _readable(departure(estimate.window_T_cam_lidar, T_file)),
                    "running_estimate": _readable(departure(estimate.T_cam_lidar, T_file)),
                    "std_cm_deg": list(estimate.std),
                }
                lidar_stamps = getattr(seq, "lidar_timestamps", None)
                if lidar_stamps is not None and lidar_stamps[middle] is not None:  # δt as the stamps say
                    row["time_offset_truth_s"] = float(seq.timestamps[middle] - lidar_stamps[middle])
                if truth is not None:
                    row["truth"] = _readable(departure(truth[middle], T_file))
                    row["error"] = calibration_error(estimate.T_cam_lidar, truth[middle]).to_dict()
                    row["error_of_file"] = calibration_error(T_file, truth[middle]).to_dict()
                rows.append(row)
                progress.advance(task)
    flagged = [r["window"] for r in rows if r["drift"]]
    output = {
        "windows": rows,
        "T_cam_lidar": rows[-1]["T_cam_lidar"],
        "std_cm_deg": rows[-1]["std_cm_deg"],
        "drift": bool(rows[-1]["drift"]),
        "first_drift_window": flagged[0] if flagged else None,
        "schema_version": SCHEMA_VERSION,
        "support": support.name,
        "data": str(data),
        "sequence": sequence,
        "init": init_text,
        "seed": seed,
        "wall_s": time.perf_counter() - start,
        "config": config.model_dump(mode="json"),
    }
    with atomic_output(out, overwrite, inputs, command="calibrate --online") as tmp:
        write_json(tmp / "estimates.json", output)
        _write_csv(rows, tmp / "estimates.csv")
        _plot(
            rows,
            tmp / "parameters.png",
            f"{Path(data).name} {sequence or ''}: online estimate ({support.name})",
        )
        (tmp / "config.yaml").write_text(resolved_config(config))
    last = rows[-1]
    line = (
        f"{len(rows)} windows of {online.window} frames; running estimate ± "
        f"{last['std_cm_deg'][0]:.2f} cm / {last['std_cm_deg'][1]:.3f}°"
    )
    if "error" in last:
        error = last["error"]
        line += f"; error against the truth {error['translation_cm']:.2f} cm / {error['rotation_deg']:.3f}°"
    line += (
        f"; drift flagged from window {output['first_drift_window']}"
        if flagged
        else "; no drift from the calibration on file"
    )
    console.print(line, markup=False, highlight=False, soft_wrap=True)
    return output


def _write_csv(rows: list[dict], path: Path) -> None:
    names = [p.replace(" ", "_").replace("°", "deg") for p in PARAMETERS]
    header = ["window", "first_frame", "last_frame", "time_s", "drift"]
    header += [f"window_{n}" for n in names] + [f"running_{n}" for n in names]
    header += ["std_cm", "std_deg"] + ([f"truth_{n}" for n in names] if "truth" in rows[0] else [])
    header += [
        "window_time_offset_ms",
        "window_time_offset_taken",
        "running_time_offset_ms",
        "time_offset_std_ms",
        "time_offset_rate_ppm",
        "stamps_time_offset_ms",
    ]
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        for r in rows:
            writer.writerow(
                [r["window"], r["first_frame"], r["last_frame"], f"{r['time_s']:.3f}", int(r["drift"])]
                + [f"{v:.4f}" for v in (*r["window_estimate"], *r["running_estimate"], *r["std_cm_deg"])]
                + [f"{v:.4f}" for v in r.get("truth", [])]
                + [_ms(r["window_time_offset_s"]), int(r["window_time_offset_taken"])]
                + [_ms(r[k]) for k in ("time_offset_s", "time_offset_std_s")]
                + [f"{1e6 * r['time_offset_rate']:.1f}"]
                + [_ms(r.get("time_offset_truth_s"))]
            )


def _ms(seconds: float | None) -> str:
    return "" if seconds is None else f"{1e3 * seconds:.3f}"


def _plot(rows: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.array([r["time_s"] for r in rows])
    running = np.array([r["running_estimate"] for r in rows])
    window = np.array([r["window_estimate"] for r in rows])
    std = np.array([r["std_cm_deg"] for r in rows])
    fig, axes = plt.subplots(2, 4, figsize=(17, 6), sharex=True)
    for j, ax in enumerate(axes[:, :3].ravel()):
        band = 2 * std[:, 0 if j < 3 else 1]
        ax.fill_between(t, running[:, j] - band, running[:, j] + band, alpha=0.25, label="running ± 2σ")
        ax.plot(t, running[:, j], "-", label="running estimate")
        ax.plot(t, window[:, j], ".", ms=5, label="window estimate")
        if "truth" in rows[0]:
            ax.plot(t, [r["truth"][j] for r in rows], "k--", lw=1, label="truth")
        for r in rows:
            if r["drift"]:
                ax.axvspan(r["time_s"] - 0.05, r["time_s"] + 0.05, color="red", alpha=0.15, lw=0)
        ax.set_title(f"{PARAMETERS[j]} from the calibration on file", fontsize=9)
        ax.grid(alpha=0.3)
    dt = 1e3 * np.array([r["time_offset_s"] for r in rows])
    dt_band = 2e3 * np.array([r["time_offset_std_s"] for r in rows])
    ax = axes[0, 3]
    ax.fill_between(t, dt - dt_band, dt + dt_band, alpha=0.25)
    ax.plot(t, dt, "-")
    fitted = [
        (r["time_s"], 1e3 * r["window_time_offset_s"], r["window_time_offset_taken"])
        for r in rows
        if r["window_time_offset_s"] is not None
    ]
    for taken, marker, label in ((True, ".", "window fit"), (False, "x", "window fit, outside the gate")):
        shown_fits = [(t, v) for t, v, k in fitted if k == taken]
        if shown_fits:
            ax.plot(*zip(*shown_fits, strict=True), marker, ms=5, color="C1", label=label)
    if fitted:
        ax.legend(fontsize=7)
    shown = [*dt, *(v for _, v, _ in fitted)]
    if all("time_offset_truth_s" in r for r in rows):
        stamps = [1e3 * r["time_offset_truth_s"] for r in rows]
        ax.plot(t, stamps, "k--", lw=1)
        shown += stamps
    # the band starts at the prior's ±100 ms: scale to the estimates, and the band up to 5 ms past them
    ax.set_ylim(min(shown) - 5.0, max(shown) + 5.0)
    ax.set_title("δt ms, camera minus LiDAR (dashed: stamps)", fontsize=9)
    ax.grid(alpha=0.3)
    axes[1, 3].axis("off")
    for ax in axes[1, :3]:
        ax.set_xlabel("time s")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(title + " (red: drift flagged)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
