"""``supportnet calibrate``: Stage 4 on a sequence, with several supports side by side.

Every run draws one initial extrinsic (``--init``) and gives it, with the same sampling seed, to
every support: a paired comparison, as the paper's Experiment 3. Writes ``result.json``
(DESIGN.md's schema for the first support, and every support under ``results``), ``summary.md``,
Fig. 1-style overlays before and after, the support maps used, and the resolved ``config.yaml``.
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from rich.console import Console

from calib.data import open_dataset
from calib.data.io import write_image
from calib.data.types import Frame
from calib.errors import DataError
from calib.geometry import calibration_error, perturb
from calib.init.motion_init import initial_calibration
from calib.projection import project_scan
from calib.refine.passes import CalibrateConfig, load_calibrate_config, refine_passes
from supportnet.cli.output_dir import atomic_output, progress_bar, resolved_config, write_json
from supportnet.report.pictures import colourise, draw_projection
from supportnet.runtime.matcher_factory import build_matcher
from supportnet.runtime.support_predictor import SHIPPED_MODEL, SupportPredictor

__all__ = ["Support", "load_calibrate_config", "parse_init", "parse_supports", "run_calibrate"]

@dataclass(frozen=True)
class Support:
    """One ``--support`` value: its name and the map it gives every frame (``None``: uniform).

    Attributes:
        name: as given on the command line.
        map: one ``(H, W)`` map for every frame (offline maps of the whole sequence), or ``None``.
        predictor: predicts a map per frame from its image (``onnx``), or ``None``.
    """

    name: str
    map: np.ndarray | None = None
    predictor: SupportPredictor | None = None
    _predicted: dict = field(default_factory=dict, repr=False, compare=False)

    def __call__(self, frame: Frame) -> np.ndarray | None:
        if self.predictor is not None:
            if frame.index not in self._predicted:
                self._predicted[frame.index] = self.predictor.predict(frame.image)[0]
            return self._predicted[frame.index]
        if self.map is not None and self.map.shape != frame.image_size:
            raise DataError(self.name, f"map is {self.map.shape}, images are {frame.image_size}")
        return self.map


def parse_supports(text: str, config: CalibrateConfig) -> list[Support]:
    """``uniform``, ``offline:MAPS`` (a ``supportnet maps`` folder), ``onnx[:MODEL]`` (bare:
    the shipped model), comma-separated."""
    supports = []
    for item in (s.strip() for s in text.split(",") if s.strip()):
        kind, _, arg = item.partition(":")
        if kind == "uniform" and not arg:
            supports.append(Support("uniform"))
        elif kind == "offline" and arg:
            path = Path(arg) / "sequence.npz"
            if not path.is_file():
                raise DataError(path, "not found; make offline maps with `supportnet maps`")
            supports.append(Support(item, map=np.load(path)[config.support_map].astype(np.float32)))
        elif kind == "onnx":
            supports.append(Support(item, predictor=SupportPredictor(Path(arg) if arg else SHIPPED_MODEL)))
        else:
            raise DataError("--support", f"{item!r} is not uniform, offline:MAPS or onnx[:MODEL]")
    if not supports or len({s.name for s in supports}) != len(supports):
        raise DataError("--support", f"needs one or more distinct values, got {text!r}")
    return supports


def parse_init(text: str) -> tuple[str, object]:
    """``perturb:CM,DEG`` → ``("perturb", (cm, deg))``; ``file:PATH`` → ``("file", T (4, 4))``
    from a text file of 12 or 16 numbers or a ``result.json``; ``stage1`` → ``("stage1", None)``
    (Stage 1 from the sequence's motion, ``configs/init_calib.yaml``)."""
    kind, _, arg = text.partition(":")
    if kind == "perturb":
        match = re.fullmatch(r"\s*([0-9.]+)\s*,\s*([0-9.]+)\s*", arg)
        if not match:
            raise DataError("--init", f"perturb takes CM,DEG (e.g. perturb:10,2), got {arg!r}")
        return "perturb", (float(match[1]), float(match[2]))
    if kind == "file" and arg:
        path = Path(arg)
        if not path.is_file():
            raise DataError(path, "not found")
        try:
            values = (
                np.asarray(json.loads(path.read_text())["T_cam_lidar"], np.float64)
                if path.suffix == ".json"
                else np.loadtxt(path, dtype=np.float64).ravel()
            )
        except (ValueError, KeyError) as exc:
            raise DataError(path, f"does not hold an extrinsic ({exc})") from None
        if values.size not in (12, 16):
            raise DataError(path, f"expected 12 or 16 numbers (T_cam_lidar), got {values.size}")
        T = np.eye(4)
        T[:3] = values.reshape(-1, 4)[:3]
        return "file", T
    if kind == "stage1" and not arg:
        return "stage1", None
    raise DataError("--init", f"{text!r} is not perturb:CM,DEG, file:PATH or stage1")


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
        draw_projection(frame.image, project_scan(frame.points, T, frame.K, frame.image_size))
        for T in (T_before, T_after)
    ]
    return np.concatenate(panels, axis=0)


def _markdown(result: dict) -> str:
    lines = [
        f"# supportnet calibrate: {result['data']} {result['sequence'] or ''}".rstrip(),
        "",
        f"{result['runs_requested']} runs from `--init {result['init']}`, seed {result['seed']}, "
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
    return "\n".join(lines) + "\n"


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
) -> dict:
    """Paired runs of Stage 4 for every support; returns what ``result.json`` holds."""
    console = console or Console(stderr=True)
    matcher = build_matcher(config.matcher, config.edge, config.flow_model)
    if runs < 1:
        raise DataError("--runs", f"must be at least 1, got {runs}")
    supports = parse_supports(supports_text, config)
    init_kind, init_arg = parse_init(init_text)
    start = time.perf_counter()
    with open_dataset(data, sequence=sequence) as seq:
        T_ref = seq.calibration.T_cam_lidar
        if init_kind == "perturb" and T_ref is None:
            raise DataError(data, "has no reference calibration to perturb; use --init file:PATH")
        stage1 = None
        if init_kind == "stage1":
            from calib.init.motion_init import load_stage1_config

            with console.status("Stage 1: initial extrinsic from motion"):
                stage1 = initial_calibration(seq, load_stage1_config())
            for weak in stage1.calibration.weak:
                console.print(f"Stage 1 weak: {weak}", markup=False, highlight=False, soft_wrap=True)
            init_kind, init_arg = "file", stage1.T_cam_lidar
        picks = np.unique(np.linspace(0, len(seq) - 1, min(config.frames, len(seq))).round().astype(int))
        frames = [seq[int(i)] for i in picks]
    results = {s.name: {"support": s.name, "runs": []} for s in supports}
    with progress_bar("calibrate", console) as progress:
        task = progress.add_task("calibrate", total=runs * len(supports))
        for run in range(runs):
            if init_kind == "perturb":
                T_init = perturb(T_ref, *init_arg, torch.Generator().manual_seed(seed * 1000 + run))
            else:
                T_init = init_arg
            for support in supports:
                t0 = time.perf_counter()
                rng = np.random.default_rng([seed, run])  # the same draws for every support
                result = refine_passes(frames, T_init, matcher, support, config, rng)
                results[support.name]["runs"].append(
                    {
                        "run": run,
                        "T_cam_lidar": result.T_cam_lidar.tolist(),
                        "initial_T_cam_lidar": T_init.tolist(),
                        "error": calibration_error(result.T_cam_lidar, T_ref).to_dict()
                        if T_ref is not None
                        else None,
                        "initial_error": calibration_error(T_init, T_ref).to_dict()
                        if T_ref is not None
                        else None,
                        "covariance": result.covariance.tolist(),
                        "passes": result.passes,
                        "correspondences": result.correspondences,
                        "runtime_s": time.perf_counter() - t0,
                    }
                )
                progress.advance(task)
    for r in results.values():
        first = r["runs"][0]
        r.update(
            {
                k: first[k]
                for k in ("T_cam_lidar", "initial_T_cam_lidar", "error", "initial_error", "correspondences")
            }
        )
        r.update(
            frames=len(frames), runtime_s=sum(x["runtime_s"] for x in r["runs"]), summary=_summary(r["runs"])
        )
    paired = {}
    if "uniform" in results and T_ref is not None:
        paired = {
            name: paired_wins(r["runs"], results["uniform"]["runs"])
            for name, r in results.items()
            if name != "uniform"
        }
    head = results[supports[0].name]
    output = {
        **{
            k: head[k]
            for k in (
                "T_cam_lidar",
                "initial_T_cam_lidar",
                "error",
                "initial_error",
                "support",
                "frames",
                "correspondences",
                "runtime_s",
                "runs",
                "summary",
            )
        },
        "reference_T_cam_lidar": T_ref.tolist() if T_ref is not None else None,
        "data": str(data),
        "sequence": sequence,
        "init": init_text,
        "seed": seed,
        "runs_requested": runs,
        "frame_indices": picks.tolist(),
        "stage1": None
        if stage1 is None
        else {"translation_source": stage1.translation_source, **stage1.calibration.report()},
        "results": results,
        "paired_vs_uniform": paired,
        "config": config.model_dump(mode="json"),
        "wall_s": time.perf_counter() - start,
    }
    with atomic_output(out, overwrite) as tmp:
        write_json(tmp / "result.json", output)
        (tmp / "summary.md").write_text(_markdown(output))
        (tmp / "config.yaml").write_text(resolved_config(config))
        for support in supports:
            slug = re.sub(r"[^A-Za-z0-9]+", "_", support.name).strip("_")
            first = results[support.name]["runs"][0]
            write_image(
                tmp / f"overlay_{slug}.png",
                _overlay(frames[0], np.array(first["initial_T_cam_lidar"]), np.array(first["T_cam_lidar"])),
            )
            shown = support(frames[0])
            if shown is not None:
                write_image(tmp / f"support_{slug}.png", colourise(shown))
    console.print(_markdown(output), markup=False, highlight=False)
    return output
