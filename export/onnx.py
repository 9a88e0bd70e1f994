"""``supportnet export``: a training checkpoint → an ONNX support predictor that is checked.

The graph takes the *normalised* image (the contract in the metadata says how to make it), has
dynamic batch, height and width, and is verified three ways before it is written: ``onnx.checker``,
onnxruntime against torch on a shape other than the export shape (max abs diff of the logits),
and the metadata read back through :class:`supportnet.predictor.SupportPredictor`.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path

import numpy as np
import onnx
import torch

from calib.errors import DataError, NumericalError
from supportnet.contract import METADATA_KEY, Contract
from supportnet.model import ModelConfig, SupportUNet
from supportnet.predictor import SupportPredictor

__all__ = ["export_network", "export_onnx", "load_checkpoint"]

EXPORT_SHAPE = (1, 3, 128, 320)
CHECK_SHAPE = (2, 3, 97, 203)
"""Parity is checked on this shape: another batch, and sizes that are not multiples of the stride."""


def load_checkpoint(ckpt: Path) -> tuple[SupportUNet, Contract]:
    """The network (eval mode) and its contract from a ``supportnet train`` checkpoint."""
    ckpt = Path(ckpt)
    if not ckpt.is_file():
        raise DataError(ckpt, "checkpoint not found")
    try:
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        hparams = state["hyper_parameters"]
        model_config = ModelConfig(**hparams["model"])
        weights = {k.removeprefix("net."): v for k, v in state["state_dict"].items() if k.startswith("net.")}
    except Exception as exc:  # torch raises many types for a file that is not a checkpoint
        raise DataError(
            ckpt, f"is not a supportnet training checkpoint ({type(exc).__name__}: {exc})"
        ) from None
    net = SupportUNet(model_config)
    net.load_state_dict(weights)
    return net.eval(), net.contract(hparams.get("target", "agreement"))


def export_onnx(
    ckpt: Path, out: Path, opset: int = 17, overwrite: bool = False, tolerance: float = 1e-4
) -> dict:
    """Export the network of a training checkpoint, check it and write ``out``; returns the
    checks' figures.

    Raises:
        DataError: ``out`` exists (without ``overwrite``) or the checkpoint is unusable.
        NumericalError: onnxruntime and torch disagree by more than ``tolerance``.
    """
    if Path(out).exists() and not overwrite:
        raise DataError(out, "already exists; pass --overwrite to replace it")
    if opset < 17:
        raise DataError("--opset", f"must be 17 or newer, got {opset}")
    net, contract = load_checkpoint(ckpt)
    return export_network(net, contract, Path(out), opset, tolerance, {"source_checkpoint": str(ckpt)})


def export_network(
    net: SupportUNet,
    contract: Contract,
    out: Path,
    opset: int = 17,
    tolerance: float = 1e-4,
    props: dict | None = None,
) -> dict:
    """Export ``net`` (eval mode) with ``contract`` in its metadata, check it, write ``out``."""
    net = net.eval()
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".onnx", dir=out.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notice
            torch.onnx.export(
                net,
                (torch.zeros(EXPORT_SHAPE),),
                str(tmp),
                opset_version=opset,
                input_names=["image"],
                output_names=["logits"],
                dynamic_axes={name: {0: "batch", 2: "height", 3: "width"} for name in ("image", "logits")},
                dynamo=False,
            )
        model = onnx.load(str(tmp))
        onnx.checker.check_model(model, full_check=True)
        model.doc_string = "supportnet support predictor: normalised RGB (NCHW) -> support logits"
        onnx.helper.set_model_props(model, {METADATA_KEY: contract.to_json(), **(props or {})})
        onnx.save(model, str(tmp))
        predictor = SupportPredictor(tmp)
        if predictor.contract != contract:
            raise NumericalError(f"{tmp}: the contract read back differs from the one written")
        rng = np.random.default_rng(0)
        images = rng.integers(0, 256, (CHECK_SHAPE[0], *CHECK_SHAPE[2:], 3), dtype=np.uint8)
        x = contract.preprocess(images)
        with torch.no_grad():
            expected = net(torch.from_numpy(x)).numpy()
        (actual,) = predictor.session.run(None, {predictor.input_name: x})
        diff = float(np.abs(actual - expected).max())
        if actual.shape != expected.shape or not diff <= tolerance:
            raise NumericalError(
                f"onnxruntime and torch disagree on {CHECK_SHAPE}: shapes {actual.shape}/{expected.shape}, "
                f"max abs diff {diff:.2e} > {tolerance:.0e}"
            )
        tmp.chmod(0o644)  # mkstemp made it private
        tmp.replace(out)
    finally:
        tmp.unlink(missing_ok=True)
    return {
        "model": str(out),
        "bytes": out.stat().st_size,
        "opset": opset,
        "parity_shape": list(CHECK_SHAPE),
        "max_abs_diff": diff,
        "contract": contract.to_json(),
    }
