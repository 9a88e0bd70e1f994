"""``supportnet check``: is this extrinsic right? No ground truth needed (:mod:`calib.verify`).

Writes ``check.json`` (strict JSON: verdict, scores per frame and overall, the suggested
correction with its bootstrap scatter, the smallest error this data shows), ``check.md`` (the
same, short), ``overlay.png`` (the scan on the first frame's image under the extrinsic checked and,
unless it is good, under the suggested correction) and the resolved ``config.yaml``.

Exit codes: 0 ``good``; 1 ``bad`` or ``suspect`` (``check.json`` says which: a suspect extrinsic
is one the data could not confirm, so a script stops to look at it); 2 bad input (one line).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.console import Console

from calib.data import open_dataset
from calib.data.extrinsic_file import read_extrinsic
from calib.data.io import write_image
from calib.data.rig import rig_frames
from calib.data.types import Frame
from calib.data.types import Sequence as DataSequence
from calib.pipeline import select_frames
from calib.projection import project_scan
from calib.verify import CheckConfig, CheckResult, OutOfView, check_extrinsic
from calib.yaml_io import read_yaml, validate
from supportnet.cli.console import make_console
from supportnet.cli.output_dir import atomic_output, claim_output, resolved_config, write_json
from supportnet.report.pictures import draw_projection, tag

__all__ = [
    "CONFIRMS_DEG_CM",
    "RigCamera",
    "check_line",
    "confirms",
    "weak_data_note",
    "load_check_config",
    "open_rig",
    "rig_cameras",
    "run_check",
]


def load_check_config(path: Path | None = None, **overrides: object) -> CheckConfig:
    """``path`` (a YAML of :class:`~calib.verify.CheckConfig` keys) or the defaults, with
    ``overrides`` (``None`` values ignored), validated."""
    values = dict(read_yaml(Path(path))) if path is not None else {}
    values.update({k: v for k, v in overrides.items() if v is not None})
    return validate(CheckConfig, values, path if path is not None else "check config")


@dataclass(frozen=True)
class RigCamera:
    """One more camera of ``--data``'s rig: a dataset of one camera (``--rig PATH``), or another
    camera of ``--data``'s own dataset (``--rig-camera NAME``: ``camera`` and ``sequence`` set)."""

    path: Path
    camera: str | None = None
    sequence: str | None = None

    @property
    def name(self) -> str:
        """The camera's name in overlay names."""
        return self.camera or self.path.name

    @property
    def label(self) -> str:
        """The camera in messages."""
        return str(self.path) if self.camera is None else f"{self.path} ({self.camera})"

    def to_dict(self) -> dict:
        return {"data": str(self.path), "camera": self.camera}


def rig_cameras(
    data: Path, sequence: str | None, paths: Sequence[Path] = (), names: Sequence[str] = ()
) -> list[RigCamera]:
    """The rig's other cameras: the datasets at ``paths``, then the cameras ``names`` of
    ``data``'s own dataset (its ``sequence``)."""
    return [RigCamera(Path(p)) for p in paths] + [RigCamera(Path(data), str(n), sequence) for n in names]


def open_rig(
    stack: ExitStack, seq: DataSequence, data: Path, rig: Sequence[RigCamera], count: int
) -> tuple[list[int], list[Frame]]:
    """The scan positions and the frames of ``data``'s camera (``seq``) and of its rig's other
    cameras (each opened in ``stack``): every camera's frame of as many scans, spread over
    ``seq``, as make at least ``count`` frames (:func:`calib.data.rig.rig_frames`)."""
    others = [stack.enter_context(open_dataset(c.path, sequence=c.sequence, camera=c.camera)) for c in rig]
    positions = [int(i) for i in select_frames(len(seq), -(-count // (len(rig) + 1)))]
    names = [RigCamera(Path(data), seq.camera or None).label, *(c.label for c in rig)]
    return positions, rig_frames([seq, *others], names, positions)


def _overlay(frame, result: CheckResult) -> np.ndarray:
    """The scan on the image under the extrinsic checked and, unless it is good, under ``T*``."""
    e = result.correction

    def drawn(T: np.ndarray) -> np.ndarray:  # through the frame's camera where it sits in a rig
        T = frame.calibration.camera_extrinsic(T)
        return draw_projection(frame.image, project_scan(frame.points, T, frame.K, frame.image_size))

    panels = [tag(drawn(result.T_cam_lidar), f"extrinsic checked: {result.verdict}")]
    if result.verdict != "good":
        panels.append(
            tag(
                drawn(result.suggested_T_cam_lidar),
                f"suggested correction: {e.rotation_deg:.2f} deg, {e.translation_cm:.1f} cm",
            )
        )
    return np.concatenate(panels, axis=0)


def _fmt(value: float | None, unit: str, digits: int) -> str:
    space = "" if unit == "°" else " "
    return "not observed" if value is None else f"{value:.{digits}f}{space}{unit}"


CONFIRMS_DEG_CM = (1.0, 20.0)
"""Data that shows errors only from this rotation (°) or translation (cm) up cannot confirm an
extrinsic: its ``good`` says little (one nuScenes sweep shows 2° / 20 cm, and a calibration
31 cm off checks good there; README, stop 75), and the line says so."""


def confirms(detectable: dict) -> bool:
    """Whether data whose smallest shown error is ``detectable`` (``rotation_deg``,
    ``translation_cm``; ``None``: not observed) can confirm an extrinsic (:data:`CONFIRMS_DEG_CM`)."""
    shown = (detectable["rotation_deg"], detectable["translation_cm"])
    return all(
        value is not None and value < limit for value, limit in zip(shown, CONFIRMS_DEG_CM, strict=True)
    )


def check_line(check: dict) -> str:
    """One line of a check's answer, from :meth:`CheckResult.to_dict` (or a dict with its
    ``verdict``, ``suggested_correction``, ``significance``, ``peak_share``, ``peak_shell_deg``
    and ``detectable_error``; ``search_at_bound`` and ``inverse_hint`` where present); a ``good``
    on data that cannot confirm it says so; an extrinsic that puts no point into the image
    (:class:`~calib.verify.OutOfView`) is its reason."""
    if "suggested_correction" not in check:
        return f"{check['verdict']}: {check['reasons'][0]}"
    c, d = check["suggested_correction"], check["detectable_error"]
    bound = " (the search's bound: the error may be larger)" if check.get("search_at_bound") else ""
    line = (
        f"{check['verdict']}: best fit nearby {c['rotation_deg']:.2f}° / {c['translation_cm']:.1f} cm "
        f"away{bound} "
        f"(significance {check['significance']['joint']:.1f}), {check['peak_share']:.0%} of its "
        f"neighbours {check['peak_shell_deg']:g}° away align better; smallest error this data shows "
        f"{_fmt(d['rotation_deg'], '°', 2)} / {_fmt(d['translation_cm'], 'cm', 1)}"
    )
    if check.get("inverse_hint"):
        line += f"; {check['inverse_hint']}"
    if check["verdict"] == "good" and not confirms(d):
        line += (
            ", so it cannot confirm the extrinsic more finely: an error below that checks good "
            "too (more frames, or frames with more depth edges, show smaller ones)"
        )
    return line


def weak_data_note(check: dict) -> str | None:
    """What a ``suspect`` or ``bad`` verdict on data that cannot confirm an extrinsic
    (:func:`confirms`) does not say: there a right extrinsic can read so too (one nuScenes sweep:
    three of its six cameras' references alone; README, "Is this extrinsic right?"). ``None``
    for a ``good`` verdict or data that shows smaller errors."""
    if check["verdict"] == "good" or confirms(check["detectable_error"]):
        return None
    return (
        "data this weak can call a right extrinsic so too: more frames, or the rig's cameras "
        "together (--rig-camera, --rig), tell it apart"
    )


def _markdown(output: dict) -> str:
    c = output["suggested_correction"]
    d = output["detectable_error"]
    s = output["significance"]
    where = f" sequence {output['sequence']}" if output["sequence"] else ""
    lines = [
        f"# supportnet check: {output['verdict']}",
        "",
        f"Data `{output['data']}`{where}"
        + (f" and its rig's {len(output['rig'])} other camera(s)" if output.get("rig") else "")
        + f", extrinsic `{output['extrinsic']}`, {len(output['frames'])} frame(s).",
        "",
        *[f"- {r}" for r in output["reasons"]],
        *([f"- {note}"] if (note := weak_data_note(output)) else []),
        "",
        "| | value |",
        "|---|---|",
        f"| verdict | **{output['verdict']}** (exit code {output['exit_code']}) |",
        f"| score (alignment of contours with image edges) | {output['score']:.4f} |",
        f"| best score nearby | {output['best_score']:.4f} (alignment {output['alignment']:.3f}) |",
        f"| suggested correction | {c['rotation_deg']:.3f}° / {c['translation_cm']:.2f} cm |",
        f"| significance (joint; rotation / translation alone) | {s['joint']:.1f}; "
        f"{s['rotation']:.1f} / {s['translation']:.1f} |",
        f"| share of its neighbours {output['peak_shell_deg']:g}° away that align better "
        f"| {output['peak_share']:.0%} |",
        f"| smallest error this data shows (worst axis) | {_fmt(d['rotation_deg'], '°', 2)} / "
        f"{_fmt(d['translation_cm'], 'cm', 1)} |",
        "",
        "Smallest error shown along each axis alone (LiDAR axes): the smaller of the bootstrap's "
        "and the peak test's (tried at the tolerance times 1, 2, 4, ...; - where none was called bad).",
        "",
        "| axis | shown | bootstrap | peak test |",
        "|---|---|---|---|",
        *[
            f"| {axis} | {d['per_axis'][axis]:.2f} | {d['bootstrap_per_axis'][axis]:.2f} | "
            f"{'-' if d['peak_per_axis'][axis] is None else format(d['peak_per_axis'][axis], '.2f')} |"
            for axis in d["per_axis"]
        ],
        "",
        "| frame | contour samples (vertical, horizontal, silhouettes) | score | best | alignment |",
        "|---|---|---|---|---|",
    ]
    for f in output["frames"]:
        n = f["samples"]
        lines.append(
            f"| {f['name'] or f['index']} | {n['vertical_edges']}, {n['horizontal_edges']}, "
            f"{n['silhouettes']} | {f['score']:.4f} | {f['best_score']:.4f} | {f['alignment']:.3f} |"
        )
    if output["reference"] is not None:
        e = output["reference"]["error"]
        lines += [
            "",
            f"Against the data's own extrinsic: the one checked is {e['rotation_deg']:.3f}° / "
            f"{e['translation_cm']:.2f} cm off.",
        ]
    lines += ["", "`overlay.png`: the scan on the first frame under the extrinsic checked"]
    if output["verdict"] != "good":
        lines[-1] += " (top) and under the suggested correction (bottom)"
    return "\n".join(lines) + ".\n"


def _markdown_out_of_view(output: dict) -> str:
    """``check.md`` of an extrinsic that puts no point into the image: no score, no correction."""
    where = f" sequence {output['sequence']}" if output["sequence"] else ""
    return (
        f"# supportnet check: {output['verdict']}\n\nData `{output['data']}`{where}, extrinsic "
        f"`{output['extrinsic']}`, {len(output['frame_indices'])} frame(s).\n\n"
        + "".join(f"- {r}\n" for r in output["reasons"])
        + f"\nExit code {output['exit_code']}. No score, correction or overlay: the scans show "
        "nothing in the image under this extrinsic.\n"
    )


def _calibrated_elsewhere(
    extrinsic: Path, data: Path, sequence: str | None, camera: str | None
) -> str | None:
    """A note where ``extrinsic`` is a ``result.json`` of ``calibrate`` on other data (its ``data``,
    ``sequence`` and ``camera``, paths resolved from the current folder) than the check reads."""
    try:
        written = json.loads(Path(extrinsic).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(written, dict) or "data" not in written:
        return None

    def where(path: str | Path, seq: object, cam: object) -> str:
        return (
            f"`{Path(path).resolve()}`"
            + (f" sequence {seq}" if seq else "")
            + (f" camera {cam}" if cam else "")
        )

    calibrated = where(written["data"], written.get("sequence"), written.get("camera"))
    checked = where(data, sequence, camera)
    if calibrated == checked:
        return None
    return f"Note: {extrinsic} was calibrated on {calibrated}; this check reads {checked}."


def run_check(
    data: Path,
    sequence: str | None,
    extrinsic: Path,
    out: Path,
    config: CheckConfig | None = None,
    overwrite: bool = False,
    console: Console | None = None,
    camera: str | None = None,
    rig: Sequence[Path] = (),
    rig_camera: Sequence[str] = (),
) -> dict:
    """Check the extrinsic in ``extrinsic`` on ``data``; returns what ``check.json`` holds (its
    ``exit_code`` is the command's). ``rig``: datasets of the other cameras of ``data``'s rig
    (the same scans, paired by position), ``rig_camera``: other cameras of ``data``'s own dataset,
    checked together with it (:mod:`calib.data.rig`): the extrinsic is ``data``'s camera's."""
    console = console or make_console()
    config = config if config is not None else CheckConfig()
    T = read_extrinsic(extrinsic)
    inputs = [data, *rig, extrinsic]
    claim_output(Path(out), overwrite, inputs)
    members = rig_cameras(data, sequence, rig, rig_camera)
    with ExitStack() as stack:
        tmp = stack.enter_context(atomic_output(out, overwrite, inputs, command="check"))
        seq = stack.enter_context(open_dataset(data, sequence=sequence, camera=camera))
        if members:
            picks, frames = open_rig(stack, seq, data, members, config.frames)
        else:
            picks = [int(i) for i in select_frames(len(seq), config.frames)]
            frames = [seq[i] for i in picks]
        with console.status(f"Checking on {len(frames)} frame(s)"):
            try:
                result = check_extrinsic(frames, T, config)
            except OutOfView as nothing_seen:  # a miscalibration found, before any score
                result = nothing_seen
        output = {
            **result.to_dict(),
            "data": str(data),
            "sequence": sequence,
            "camera": camera,
            "extrinsic": str(extrinsic),
            "frame_indices": picks,
            "rig": [c.to_dict() for c in members] or None,
        }
        scored = isinstance(result, CheckResult)  # else OutOfView: nothing scored, no overlay
        write_json(tmp / "check.json", output)
        (tmp / "check.md").write_text(_markdown(output) if scored else _markdown_out_of_view(output))
        (tmp / "config.yaml").write_text(resolved_config(config))
        if scored:
            write_image(tmp / "overlay.png", _overlay(frames[0], result))
    if (other := _calibrated_elsewhere(extrinsic, data, sequence, camera)) is not None:
        console.print(other, markup=False, highlight=False, soft_wrap=True)
    note = weak_data_note(output) if scored else None
    console.print(
        f"{check_line(output)}; {len(frames)} frame(s)"
        + (f" in {result.runtime_s:.1f} s" if scored else "")
        + (f". Note: {note}" if note else ""),
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    return output
