"""``supportnet calibrate``: Stage 4 on a sequence, with several supports side by side.

Every run draws one initial extrinsic (``--init``) and gives it, with the same sampling seed, to
every support: a paired comparison, as the paper's Experiment 3. The work is the library's
(:class:`calib.pipeline.Calibrator`); this module parses, calls it and writes ``result.json``
(from :meth:`CalibrationResult.to_dict`, the first support's first run at the top level, every
run and support under ``runs`` and ``results``), ``summary.md``, Fig. 1-style overlays before and
after, the support maps used, and the resolved ``config.yaml``.

Unless told not to (``check=False``), the top-level answer is then checked without ground truth
(:func:`calib.verify.check_extrinsic`, as ``supportnet check`` does) on the frames it was
calibrated on: a run that ended in a wrong minimum (it can end farther off than it started) says
so in ``result.json``'s ``check`` and on the console, instead of looking like any other answer.
"""

from __future__ import annotations

import re
import time
from collections.abc import Sequence
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import torch
from rich.console import Console

from calib.data import open_dataset
from calib.data.extrinsic_file import read_extrinsic
from calib.data.io import write_image
from calib.data.types import Frame
from calib.errors import ConfigError, DataError
from calib.geometry import perturb
from calib.init.lidar_odometry import SequenceMotions
from calib.init.motion_init import initial_calibration, load_stage1_config
from calib.pipeline import Calibrator
from calib.projection import project_scan
from calib.refine.passes import CalibrateConfig
from calib.results import SCHEMA_VERSION, CalibrationResult
from calib.support.map_files import check_maps_fingerprint
from calib.verify import CheckResult, OutOfView, check_extrinsic, inverse_hint
from supportnet.cli.cmd_check import RigCamera, check_line, open_rig, rig_cameras
from supportnet.cli.console import make_console
from supportnet.cli.output_dir import atomic_output, claim_output, progress_bar, resolved_config, write_json
from supportnet.report.pictures import draw_projection, map_picture
from supportnet.runtime.matcher_factory import build_matcher, coarse_matcher
from supportnet.runtime.support_sources import offline_maps_folders, parse_supports

__all__ = ["MAX_PERTURBATION", "paired_wins", "parse_init", "run_calibrate"]

MAX_PERTURBATION = (500.0, 90.0)
"""Largest ``perturb:CM,DEG`` accepted: 5 m and 90° (beyond that no extrinsic is being tested)."""

_NUMBER = r"\s*([0-9]+(?:\.[0-9]*)?|\.[0-9]+)\s*"


def parse_init(text: str) -> tuple[str, object]:
    """``perturb:CM,DEG`` → ``("perturb", (cm, deg))``; ``file:PATH`` → ``("file", T (4, 4))``
    from a text file of 12 or 16 numbers or a ``result.json`` (:func:`read_extrinsic`);
    ``stage1`` → ``("stage1", None)`` (Stage 1 from the sequence's motion).

    Raises:
        ConfigError: a malformed or out-of-range value. DataError: an unusable extrinsic file.
    """
    kind, _, arg = text.partition(":")
    if kind == "perturb":
        match = re.fullmatch(f"{_NUMBER},{_NUMBER}", arg)
        if not match:
            raise ConfigError(
                "--init", f"perturb takes CM,DEG, two non-negative numbers (e.g. perturb:10,2), got {arg!r}"
            )
        cm, deg = float(match[1]), float(match[2])
        if cm > MAX_PERTURBATION[0] or deg > MAX_PERTURBATION[1]:
            limit = f"at most {MAX_PERTURBATION[0]:g} cm and {MAX_PERTURBATION[1]:g}°"
            raise ConfigError("--init", f"perturb:{arg} is out of range ({limit})")
        return "perturb", (cm, deg)
    if kind == "file" and arg:
        return "file", read_extrinsic(Path(arg))
    if kind == "stage1" and not arg:
        return "stage1", None
    raise ConfigError("--init", f"{text!r} is not perturb:CM,DEG, file:PATH or stage1")


def _summary(runs: list[dict]) -> dict:
    """Mean, median and std of both errors over runs (empty without a reference)."""
    if runs[0]["error"] is None:
        return {}
    out = {}
    for key in ("translation_cm", "rotation_deg"):
        values = np.array([r["error"][key] for r in runs])
        out[key] = {"mean": values.mean(), "median": np.median(values), "std": values.std()}
    return out


def paired_wins(runs: list[dict], baseline: list[dict]) -> dict:
    """In how many paired runs ``runs`` ended with the smaller error than ``baseline``."""
    return {
        "runs": len(runs),
        "translation_wins": sum(
            a["error"]["translation_cm"] < b["error"]["translation_cm"]
            for a, b in zip(runs, baseline, strict=True)
        ),
        "rotation_wins": sum(
            a["error"]["rotation_deg"] < b["error"]["rotation_deg"]
            for a, b in zip(runs, baseline, strict=True)
        ),
    }


def _overlay(frame: Frame, T_before: np.ndarray, T_after: np.ndarray) -> np.ndarray:
    """Fig. 1 style: the scan coloured by depth on the image, before (top) and after (bottom)."""
    panels = [
        draw_projection(
            frame.image,
            project_scan(frame.points, frame.calibration.camera_extrinsic(T), frame.K, frame.image_size),
        )
        for T in (T_before, T_after)
    ]
    return np.concatenate(panels, axis=0)


def _markdown(result: dict) -> str:
    lines = [
        f"# supportnet calibrate: {result['data']} {result['sequence'] or ''}".rstrip(),
        "",
        f"{result['runs_requested']} run{'s' if result['runs_requested'] != 1 else ''} from "
        f"`--init {result['init']}`, seed {result['seed']}, "
        f"{result['frames']} frames, up to {result['config']['passes']} passes.",
        "",
        "| support | translation cm mean | median | std | rotation ° mean | median | std |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in result["results"].items():
        s = r["summary"]
        if s:
            t, q = s["translation_cm"], s["rotation_deg"]
            lines.append(
                f"| {name} | {t['mean']:.3f} | {t['median']:.3f} | {t['std']:.3f} "
                f"| {q['mean']:.4f} | {q['median']:.4f} | {q['std']:.4f} |"
            )
    for name, p in result["paired_vs_uniform"].items():
        lines.append("")
        lines.append(
            f"{name} beat uniform in translation in {p['translation_wins']} of {p['runs']} runs "
            f"and in rotation in {p['rotation_wins']} of {p['runs']}."
        )
    rig = result.get("rig")
    if rig is not None:
        lines += [
            "",
            f"A rig of {len(rig)} cameras calibrated together: the answer is "
            f"{rig[0]['camera'] or result['data']}'s extrinsic; each camera's is in result.json's rig.",
        ]
    if result["check"] is not None:
        cameras = f" on the rig's {len(rig)} cameras" if rig is not None else ""
        lines += [
            "",
            f"Check of the answer{cameras} ({result['support']}, run 1; no ground truth): "
            + _check_line(result["check"], stage1_helps=rig is None and result["init"] != "stage1"),
        ]
    return "\n".join(lines) + "\n"


DROP_IN_RESULT = ("schema_version", "exit_code", "T_cam_lidar")  # result.json has its own


def _check_summary(result: CheckResult) -> dict:
    """What ``result.json`` keeps of a check of the answer (``check.json`` of ``supportnet check``
    without its per-frame table and config)."""
    full = result.to_dict()
    keep = (
        "verdict",
        "reasons",
        "score",
        "best_score",
        "alignment",
        "significance",
        "peak_share",
        "peak_shell_deg",
        "detectable_error",
        "search_at_bound",
        "inverse_hint",
        "suggested_correction",
        "suggested_T_cam_lidar",
        "runtime_s",
    )
    return {key: full[key] for key in keep}


def _check_line(check: dict, stage1_helps: bool) -> str:
    """:func:`check_line` of the answer's check, with what to try when it is not good
    (``stage1_helps``: the answer came from neither Stage 1 nor a rig, which it cannot start)."""
    line = check_line(check)
    if check["verdict"] != "good":
        other = "another start (or --init stage1)" if stage1_helps else "another start"
        line += f". This answer is likely wrong: calibrate again from {other}"
    return line


def support_paths(text: str) -> list[Path]:
    """The maps folders and models ``--support`` reads (an output may not replace them)."""
    items = (item.strip().partition(":") for item in text.split(","))
    return [Path(arg) for kind, _, arg in items if kind in ("offline", "onnx") and arg]


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", name).strip("_")


def run_calibrate(
    data: Path,
    sequence: str | None,
    supports_text: str,
    init_text: str,
    out: Path,
    config: CalibrateConfig,
    runs: int = 1,
    seed: int = 0,
    overwrite: bool = False,
    console: Console | None = None,
    camera: int | str | None = None,
    check: bool = True,
    rig: Sequence[Path] = (),
    rig_camera: Sequence[str] = (),
) -> dict:
    """Paired runs of Stage 4 for every support, the top-level answer checked (``check``);
    returns what ``result.json`` holds. ``rig``: datasets of the other cameras of ``data``'s rig
    (the same scans, paired by position), ``rig_camera``: other cameras of ``data``'s own dataset,
    calibrated together with it (:mod:`calib.data.rig`): the answer is ``data``'s camera's
    extrinsic, each other camera's follows from it."""
    console = console or make_console()
    inputs = [data, *rig, *support_paths(supports_text)]
    if init_text.startswith("file:"):
        inputs.append(Path(init_text[len("file:") :]))
    claim_output(out, overwrite, inputs)
    members = rig_cameras(data, sequence, rig, rig_camera)
    if runs < 1:
        raise ConfigError("--runs", f"must be at least 1, got {runs}")
    init_kind, init_arg = parse_init(init_text)
    matcher = build_matcher(config.matcher, config.edge, config.flow_model)
    supports = parse_supports(supports_text, config.support_map)
    if members and (init_kind == "stage1" or offline_maps_folders(supports)):
        what = "--init stage1" if init_kind == "stage1" else "an offline:MAPS support"
        raise ConfigError("--rig", f"{what} takes one camera; give --init perturb:/file: and uniform or onnx")
    start = time.perf_counter()
    with ExitStack() as stack:
        seq = stack.enter_context(open_dataset(data, sequence=sequence, camera=camera))
        for maps in offline_maps_folders(supports):
            check_maps_fingerprint(maps, seq)
        calibrated = seq
        if members:
            positions, calibrated = open_rig(stack, seq, data, members, config.frames)
            config = config.model_copy(update={"frames": len(calibrated)})  # all of them
        T_ref = seq.calibration.T_cam_lidar
        if init_kind == "perturb" and T_ref is None:
            raise DataError(data, "has no reference calibration to perturb; use --init file:PATH")
        stage1 = None
        if init_kind == "stage1":
            with console.status("Stage 1: initial extrinsic from motion"):
                stage1 = initial_calibration(seq, load_stage1_config())
            for weak in stage1.calibration.weak:
                console.print(f"Stage 1 weak: {weak}", markup=False, highlight=False, soft_wrap=True)
            init_kind, init_arg = "file", stage1.T_cam_lidar
            # Stage 4's δt starts where Stage 1's motion put it, unless the user holds it (fixed:MS)
            if stage1.time_offset_s is not None and config.time_offset.mode == "estimate":
                config = config.model_copy(
                    update={
                        "time_offset": config.time_offset.model_copy(
                            update={"initial_s": stage1.time_offset_s}
                        )
                    }
                )
        if init_kind == "file" and (hint := inverse_hint([seq[len(seq) // 2]], np.asarray(init_arg))):
            console.print(f"The initial extrinsic: {hint}", markup=False, highlight=False, soft_wrap=True)
        motions: SequenceMotions | str | None = "time_offset.mode: off"
        if members:  # the Calibrator says why a rig's points stay as measured
            motions = None
        elif config.time_offset.mode != "off":  # the LiDAR's motion around the used frames, once for all runs
            motions = SequenceMotions(seq, config.time_offset.neighbours, config.time_offset.deskew_rounds)
        coarse = coarse_matcher(config)
        calibrators = {
            s.name: Calibrator(support=s, matcher=matcher, config=config, coarse_matcher=coarse)
            for s in supports
        }
        results: dict[str, list[CalibrationResult]] = {name: [] for name in calibrators}
        with progress_bar("calibrate", console) as progress:
            task = progress.add_task("calibrate", total=runs * len(supports))
            for run in range(runs):
                if init_kind == "perturb":
                    T_init = perturb(T_ref, *init_arg, torch.Generator().manual_seed(seed * 1000 + run))
                else:
                    T_init = init_arg
                for name, calibrator in calibrators.items():

                    def stage_done(stage: str, seconds: float, item: str = f"run {run + 1}, {name}") -> None:
                        progress.update(task, stage=f"{item}: {stage} done ({seconds:.0f} s)")

                    # the same sampling draws for every support: a paired comparison
                    results[name].append(
                        calibrator.calibrate(
                            calibrated, T_init, seed=(seed, run), motions=motions, on_stage=stage_done
                        )
                    )
                    progress.advance(task)
        first = results[supports[0].name][0]
        # the first answer's frames, for its check and overlay (of a rig every camera's, the first
        # --data's, whose extrinsic the answer is)
        frames = [calibrated[i] for i in first.frame_indices]
        cameras = [calibrated[i].calibration.T_cam_rig for i in range(len(members) + 1)] if members else None
    checked = None
    if check:
        with console.status(f"Checking the answer on {len(frames)} frame(s) (no ground truth)"):
            try:
                checked = _check_summary(check_extrinsic(frames, first.T_cam_lidar, seed=seed))
            except OutOfView as nothing_seen:  # an answer that ran off: bad, reported so
                checked = {k: v for k, v in nothing_seen.to_dict().items() if k not in DROP_IN_RESULT}
    by_support = {}
    for name, done in results.items():
        run_dicts = [{"run": k, **r.to_dict()} for k, r in enumerate(done)]
        for entry in run_dicts if members else ():  # a rig's frames by their scans' positions in --data
            entry["frame_indices"] = sorted(
                {int(positions[i // (len(members) + 1)]) for i in entry["frame_indices"]}
            )
        by_support[name] = {
            **run_dicts[0],
            "runs": run_dicts,
            "summary": _summary(run_dicts),
            "runtime_s": sum(r.runtime_s for r in done),
        }
    paired = {}
    if "uniform" in by_support and T_ref is not None:
        paired = {
            name: paired_wins(r["runs"], by_support["uniform"]["runs"])
            for name, r in by_support.items()
            if name != "uniform"
        }
    output = {
        **by_support[supports[0].name],
        "schema_version": SCHEMA_VERSION,
        "data": str(data),
        "sequence": sequence,
        "camera": camera,
        "init": init_text,
        "seed": seed,
        "runs_requested": runs,
        "stage1": None
        if stage1 is None
        else {"translation_source": stage1.translation_source, **stage1.calibration.report()},
        "results": by_support,
        "paired_vs_uniform": paired,
        "check": checked,
        "rig": None
        if cameras is None
        else [
            {**member.to_dict(), "T_cam_lidar": (T_cam_rig @ first.T_cam_lidar).tolist()}
            for member, T_cam_rig in zip(
                [RigCamera(Path(data), camera, sequence), *members], cameras, strict=True
            )
        ],
        "config": config.model_dump(mode="json"),
        "wall_s": time.perf_counter() - start,
    }
    with atomic_output(out, overwrite, inputs, command="calibrate") as tmp:
        write_json(tmp / "result.json", output)
        (tmp / "summary.md").write_text(_markdown(output))
        (tmp / "config.yaml").write_text(resolved_config(config))
        for support in supports:
            first = results[support.name][0]
            write_image(
                tmp / f"overlay_{_slug(support.name)}.png",
                _overlay(frames[0], first.initial_T_cam_lidar, first.T_cam_lidar),
            )
            # the rig's other cameras, each under its number (folders may share a name) and name
            for k, (member, frame) in enumerate(zip(members, frames[1 : len(members) + 1], strict=False), 1):
                write_image(
                    tmp / f"overlay_{_slug(support.name)}_{k}_{_slug(member.name)}.png",
                    _overlay(frame, first.initial_T_cam_lidar, first.T_cam_lidar),
                )
            shown = support(frames[0])
            if shown is not None:
                picture = map_picture(shown, f"support ({support.name})")
                write_image(tmp / f"support_{_slug(support.name)}.png", picture)
    console.print(_markdown(output), markup=False, highlight=False)
    return output
