"""``supportnet export``: registered with the ``supportnet`` command line through the
``supportnet.commands`` entry point (``pyproject.toml``), so the CLI never imports ``export``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from supportnet.cli.options import Overwrite, SequenceName

__all__ = ["register"]


def export(
    ckpt: Annotated[Path, typer.Option(help="Checkpoint of `supportnet train` or `train-flow`.")],
    out: Annotated[Path, typer.Option(help="ONNX file to write.")],
    opset: Annotated[int, typer.Option(help="ONNX opset, 17 to 20 (what torch's exporter supports).")] = 17,
    overwrite: Overwrite = False,
) -> None:
    """Export to ONNX and verify it: onnx.checker, onnxruntime against torch on another shape,
    and the pre-processing contract read back from the metadata."""
    from export.onnx_export import export_onnx

    report = export_onnx(ckpt, out, opset, overwrite)
    typer.echo(
        f"wrote {out} ({report['bytes'] / 1e6:.2f} MB, opset {opset}); onnxruntime vs torch on "
        f"{tuple(report['parity_shape'])}: max abs diff {report['max_abs_diff']:.1e}"
    )


def quantize(
    model: Annotated[Path, typer.Option(help="A support predictor of `supportnet export`.")],
    data: Annotated[Path, typer.Option(help="A dataset like the model's: its images set the 8-bit ranges.")],
    out: Annotated[Path, typer.Option(help="ONNX file to write.")],
    sequence: SequenceName = None,
    frames: Annotated[int, typer.Option(min=1, help="Images used, spread over the sequence.")] = 32,
    overwrite: Overwrite = False,
) -> None:
    """Quantise a support predictor to 8 bits (onnxruntime's static quantisation) and check it
    against the float model on another shape: 0.67-0.81x the time on a 2-core AVX-512 machine, the
    same Pearson r against the offline maps (README, "The learned support predictor")."""
    from export.onnx_export import quantise_onnx, run_time_images

    images = run_time_images(model, [(data, sequence)], frames)
    report = quantise_onnx(model, out, images, overwrite)
    diff, shape = report["max_abs_support_diff"], tuple(report["parity_shape"])
    typer.echo(
        f"wrote {out} ({report['bytes'] / 1e6:.2f} MB) from {len(images)} images; its support "
        f"against the float model's on {shape}: max abs diff {diff:.3f}"
    )


def register(app: typer.Typer) -> None:
    """Add ``export`` and ``quantize`` to ``app``."""
    app.command()(export)
    app.command()(quantize)
