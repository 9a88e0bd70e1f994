"""``supportnet export``: registered with the ``supportnet`` command line through the
``supportnet.commands`` entry point (``pyproject.toml``), so the CLI never imports ``export``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from supportnet.cli.options import Overwrite

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


def register(app: typer.Typer) -> None:
    """Add ``export`` to ``app``."""
    app.command()(export)
