"""``supportnet export``: a training checkpoint → a checked ONNX model (support predictor or flow
matcher, told apart by the checkpoint).

The graph takes *normalised* inputs (the contract in the metadata says how to make them), has
dynamic batch, height and width, and is verified three ways before it is written: ``onnx.checker``,
onnxruntime against torch on a shape other than the export shape (max abs diff of the output),
and the metadata read back the way the run-time classes read it. A support predictor can then be
quantised to 8 bits (:func:`quantise_onnx`), checked against the float model the same way.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from calib.errors import ConfigError, DataError, NumericalError
from supportnet.cli.output_dir import claim_output, temp_path
from supportnet.nets.contract import METADATA_KEY, Contract
from supportnet.nets.flow_net import LIDAR_CHANNELS, FlowConfig, FlowNet
from supportnet.nets.support_unet import CoarseLogits, ModelConfig, SupportUNet
from supportnet.runtime.support_predictor import open_model

__all__ = [
    "OPSETS",
    "check_opset",
    "export_network",
    "export_onnx",
    "load_checkpoint",
    "quantise_onnx",
    "run_time_images",
]

EXPORT_SIZE = (128, 320)
CHECK_SHAPE = (2, 3, 97, 203)
"""Parity is checked on this shape: another batch, and sizes that are not multiples of the stride."""
OPSETS = range(17, 21)
"""ONNX opsets an export may ask for: from 17 (the oldest the networks are checked with) to 20, the
newest torch's TorchScript exporter (``dynamo=False``, used here) supports."""


def check_opset(opset: int) -> int:
    """``opset`` when it is in :data:`OPSETS`; else a one-line ConfigError naming the range."""
    if opset not in OPSETS:
        raise ConfigError(
            "--opset",
            f"must be from {OPSETS[0]} to {OPSETS[-1]} (what torch's ONNX exporter supports), got {opset}",
        )
    return opset


def load_checkpoint(ckpt: Path) -> tuple[nn.Module, Contract]:
    """The network (eval mode) and its contract from a ``supportnet train`` or ``train-flow``
    checkpoint."""
    ckpt = Path(ckpt)
    if not ckpt.is_file():
        raise DataError(ckpt, "checkpoint not found")
    try:
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        hparams = state["hyper_parameters"]
        if "near_m" in hparams:
            net = FlowNet(FlowConfig(**hparams["model"]))
            contract = net.contract(hparams["near_m"], hparams["working_focal_px"])
        else:
            net = SupportUNet(ModelConfig(**hparams["model"]))
            contract = net.contract(hparams.get("target", "agreement"), hparams.get("working_focal_px"))
        weights = {k.removeprefix("net."): v for k, v in state["state_dict"].items() if k.startswith("net.")}
    except Exception as exc:  # torch raises many types for a file that is not a checkpoint
        raise DataError(
            ckpt, f"is not a supportnet training checkpoint ({type(exc).__name__}: {exc})"
        ) from None
    net.load_state_dict(weights)
    return net.eval(), contract


def export_onnx(
    ckpt: Path, out: Path, opset: int = 17, overwrite: bool = False, tolerance: float = 1e-4
) -> dict:
    """Export the network of a training checkpoint, check it and write ``out``; returns the
    checks' figures.

    Raises:
        DataError: ``out`` exists (without ``overwrite``) or the checkpoint is unusable.
        ConfigError: ``opset`` is not in :data:`OPSETS`.
        NumericalError: onnxruntime and torch disagree by more than ``tolerance``.
    """
    check_opset(opset)
    claim_output(Path(out), overwrite, [ckpt], file=True)
    net, contract = load_checkpoint(ckpt)
    return export_network(net, contract, Path(out), opset, tolerance, {"source_checkpoint": str(ckpt)})


DOCS = {
    "logits": "supportnet support predictor: normalised RGB (NCHW) -> support logits",
    "flow": "supportnet flow matcher: normalised RGB and LiDAR image (NCHW) -> flow in pixels",
}


def export_network(
    net: nn.Module,
    contract: Contract,
    out: Path,
    opset: int = 17,
    tolerance: float = 1e-4,
    props: dict | None = None,
) -> dict:
    """Export a support predictor or a flow matcher (eval mode; ``contract.output`` says which) with
    ``contract`` in its metadata, check it, write ``out``. A :class:`SupportUNet` is exported
    without its final upsampling (:class:`CoarseLogits`; the run time does it, as the contract's
    ``output_stride`` says).

    Raises:
        ConfigError: a :class:`SupportUNet`'s contract names another ``output_stride`` than the
            network's stem stride (the run time would upsample its output wrongly).
    """
    check_opset(opset)
    if isinstance(net, SupportUNet) and contract.output_stride != net.config.stem_stride:
        raise ConfigError(
            "contract",
            f"output_stride {contract.output_stride} is not the network's stem stride "
            f"{net.config.stem_stride}: use SupportUNet.contract()",
        )
    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, (CHECK_SHAPE[0], *CHECK_SHAPE[2:], 3), dtype=np.uint8)
    check = {"image": contract.preprocess(images)}
    if contract.output == "flow":
        lidar = rng.random((CHECK_SHAPE[0], len(LIDAR_CHANNELS), *CHECK_SHAPE[2:]), dtype=np.float32)
        check["lidar"] = lidar * (lidar[:, :1] > 0.9)  # sparse, as a projected scan is
    if isinstance(net, SupportUNet):
        net = CoarseLogits(net)
    return _export(net, contract, out, check, contract.output, opset, tolerance, props)


def _export(
    net: nn.Module,
    contract: Contract,
    out: Path,
    check: dict[str, np.ndarray],
    output: str,
    opset: int,
    tolerance: float,
    props: dict | None,
) -> dict:
    """Trace ``net`` on inputs named as ``check``'s keys, write it with its contract, and compare
    onnxruntime with torch on ``check``."""
    net = net.eval()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path(out)  # written with the umask's mode, removed on failure (or by a later run)
    names = list(check)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notice
            torch.onnx.export(
                net,
                tuple(torch.zeros(1, x.shape[1], *EXPORT_SIZE) for x in check.values()),
                str(tmp),
                opset_version=opset,
                input_names=names,
                output_names=[output],
                dynamic_axes={name: {0: "batch", 2: "height", 3: "width"} for name in [*names, output]},
                dynamo=False,
            )
        model = onnx.load(str(tmp))
        onnx.checker.check_model(model, full_check=True)
        model.doc_string = DOCS[output]
        onnx.helper.set_model_props(model, {METADATA_KEY: contract.to_json(), **(props or {})})
        onnx.save(model, str(tmp))
        with torch.no_grad():
            expected = net(*(torch.from_numpy(x) for x in check.values())).numpy()
        diff = _check_written(tmp, output, contract, check, expected, tolerance, "onnxruntime and torch")
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


def _sigmoid(logits: np.ndarray) -> np.ndarray:
    return 1 / (1 + np.exp(-logits))


def _check_written(
    path: Path,
    output: str,
    contract: Contract,
    inputs: dict[str, np.ndarray],
    expected: np.ndarray,
    tolerance: float,
    what: str,
    read: Callable[[np.ndarray], np.ndarray] = lambda x: x,
) -> float:
    """Open the model written at ``path`` as the run time does: its contract must read back as
    ``contract``, and its output on ``inputs`` (through ``read``) lie within ``tolerance`` of
    ``expected`` everywhere. Returns the largest difference.

    Raises:
        NumericalError: naming ``what`` was compared, the shape and the difference.
    """
    session, read_back = open_model(path, output)
    if read_back != contract:
        raise NumericalError(f"{path}: the contract read back differs from the one written")
    actual = read(session.run(None, inputs)[0])
    diff = float(np.abs(actual - expected).max())
    if actual.shape != expected.shape or not diff <= tolerance:
        shape = next(iter(inputs.values())).shape
        raise NumericalError(
            f"{what} disagree on {shape}: shapes {actual.shape}/{expected.shape}, "
            f"max abs diff {diff:.2e} > {tolerance:.0e}"
        )
    return diff


def run_time_images(model: Path, sources: list[tuple[Path, str | None]], frames: int) -> np.ndarray:
    """``(B, H, W, 3)`` uint8: ``frames`` images spread over each dataset ``(data, sequence)`` of
    ``sources``, as the run time gives them to the support predictor ``model``
    (:func:`~supportnet.runtime.support_sources.model_image`)."""
    from calib.data import open_dataset
    from calib.pipeline import select_frames
    from supportnet.runtime.support_sources import model_image

    _, contract = open_model(Path(model), "logits")
    images = []
    for data, sequence in sources:
        with open_dataset(data, sequence=sequence) as seq:
            images += [model_image(contract, seq[int(i)]) for i in select_frames(len(seq), frames)]
    if len({image.shape for image in images}) > 1:
        raise DataError(Path(sources[0][0]), "the datasets' images differ in size at the model's scale")
    return np.stack(images)


QUANTISED = "supportnet.quantised"
"""Metadata key of a quantised model: how it was quantised, from what, on how many images."""


def quantise_onnx(
    model: Path, out: Path, images: np.ndarray, overwrite: bool = False, tolerance: float = 0.1
) -> dict:
    """Quantise an exported support predictor to 8 bits and write ``out``; returns the checks'
    figures.

    onnxruntime's static quantisation: weights int8 per output channel, activations uint8 with
    ranges observed on ``images`` (the float model run on each, through its contract's
    pre-processing), integer operators (QOperator: the shipped predictor in 0.67–0.81x the float
    model's time on a 2-core AVX-512 machine; as QDQ 0.82x). The contract is carried over; the
    check runs both models on two of ``images`` cropped to :data:`CHECK_SHAPE` (another shape
    than the export's and the images') and compares their support (the sigmoid of the logits).

    Args:
        model: a float support predictor (``supportnet export``). images: ``(B, H, W, 3)`` uint8
            RGB of the data it will see, at its training size.

    Raises:
        DataError: ``out`` exists (without ``overwrite``), ``model`` is unusable or not a support
            predictor, or there are no images.
        NumericalError: the supports differ by more than ``tolerance`` somewhere.
    """
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    model, out = Path(model), Path(out)
    claim_output(out, overwrite, [model], file=True)
    session, contract = open_model(model, "logits")
    images = np.asarray(images)
    if images.ndim != 4 or len(images) == 0 or images.dtype != np.uint8:
        raise DataError(
            model, f"quantising needs (B, H, W, 3) uint8 images, got {images.shape} {images.dtype}"
        )
    name = session.get_inputs()[0].name

    class Images(CalibrationDataReader):
        def __init__(self) -> None:
            self.left = iter(images)

        def get_next(self) -> dict | None:
            image = next(self.left, None)
            return None if image is None else {name: contract.preprocess(image[None])}

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp, prepared = temp_path(out), temp_path(out.with_suffix(".pre.onnx"))
    try:
        root, level = logging.getLogger(), logging.getLogger().level
        root.setLevel(logging.ERROR)  # the quantiser logs each integer shape tensor it leaves as it is
        try:
            quant_pre_process(str(model), str(prepared), skip_symbolic_shape=True)  # folded, shapes known
            quantize_static(
                str(prepared),
                str(tmp),
                Images(),
                quant_format=QuantFormat.QOperator,
                per_channel=True,
                activation_type=QuantType.QUInt8,
                weight_type=QuantType.QInt8,
            )
        finally:
            root.setLevel(level)
        source, quantised = onnx.load(str(model)), onnx.load(str(tmp))
        props = {p.key: p.value for p in source.metadata_props}
        props[QUANTISED] = f"int8 static (QOperator, per channel) of {model.name} on {len(images)} images"
        quantised.doc_string = source.doc_string
        onnx.helper.set_model_props(quantised, props)
        onnx.save(quantised, str(tmp))
        h, w = CHECK_SHAPE[2:]
        check = {name: contract.preprocess(np.ascontiguousarray(images[:2, :h, :w]))}
        expected = _sigmoid(session.run(None, check)[0])
        what = "the 8-bit and the float model's support"
        diff = _check_written(tmp, "logits", contract, check, expected, tolerance, what, _sigmoid)
        tmp.replace(out)
    finally:
        tmp.unlink(missing_ok=True)
        prepared.unlink(missing_ok=True)
    return {
        "model": str(out),
        "from": str(model),
        "bytes": out.stat().st_size,
        "calibration_images": len(images),
        "parity_shape": list(check[name].shape),
        "max_abs_support_diff": diff,
    }
