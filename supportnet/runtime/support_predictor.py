"""``SupportPredictor``: Stage 3 online, the exported U-Net in onnxruntime (numpy, OpenCV and
onnxruntime only: no torch at run time)."""

from __future__ import annotations

import threading
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from calib.errors import DataError
from supportnet.nets.contract import METADATA_KEY, Contract

__all__ = ["SHIPPED_FLOAT_MODEL", "SHIPPED_MODEL", "SupportPredictor", "open_model"]

SHIPPED_FLOAT_MODEL = Path(__file__).resolve().parents[1] / "assets" / "support_unet.onnx"
"""The small model trained on the synthetic worlds (``make model``), as exported."""
SHIPPED_MODEL = SHIPPED_FLOAT_MODEL.with_name("support_unet_int8.onnx")
"""The same quantised to 8 bits (``make model``; ``python -m train.recipe support-int8`` from the
float one), used by ``--support onnx``: 0.67-0.81x its time, the same Pearson r against the offline maps."""


class SupportPredictor:
    """Predicts support maps from RGB images with an exported :class:`SupportUNet`.

    Args:
        model: path of the ``.onnx`` file written by ``supportnet export``.
        threads: onnxruntime intra-op threads (0: its default, all cores).

    Raises:
        DataError: the file is missing, is not an ONNX model, or carries no supportnet contract.
    """

    def __init__(self, model: str | Path = SHIPPED_MODEL, threads: int = 0) -> None:
        self.path = Path(model)
        self.session, self.contract = open_model(self.path, "logits", threads)
        self.input_name = self.session.get_inputs()[0].name
        self._input: np.ndarray | None = None  # reused frame after frame (Contract.preprocess)
        self._lock = threading.Lock()  # for that buffer; a run uses every core anyway

    def predict(self, images: np.ndarray) -> np.ndarray:
        """Support of every pixel.

        Args:
            images: ``(B, H, W, 3)`` or ``(H, W, 3)`` uint8 RGB, any ``H, W``.

        Returns:
            ``(B, H, W)`` float32 in [0, 1].
        """
        with self._lock:
            self._input = x = self.contract.preprocess(images, self._input)
            (logits,) = self.session.run(None, {self.input_name: x})
        support = logits[:, 0]
        s = self.contract.output_stride
        if s > 1:  # bilinear, half-pixel centres: torch's upsampling (SupportUNet.forward)
            H, W = x.shape[-2:]
            size = (support.shape[2] * s, support.shape[1] * s)
            support = np.stack([cv2.resize(m, size, interpolation=cv2.INTER_LINEAR)[:H, :W] for m in support])
        # the sigmoid in place, on float32 the predictor owns
        np.negative(support, out=support)
        np.exp(support, out=support)
        support += 1.0
        return np.reciprocal(support, out=support)


def open_model(path: Path, output: str, threads: int = 0) -> tuple[ort.InferenceSession, Contract]:
    """An onnxruntime session of an exported supportnet model and its contract.

    Args:
        path: the ``.onnx`` file. output: what it must produce (``logits``: a support predictor,
            ``flow``: a flow matcher). threads: intra-op threads (0: onnxruntime's default).

    Raises:
        DataError: the file is missing, is not an ONNX model, carries no supportnet contract, or
            is the other kind of model.
    """
    if not path.is_file():
        raise DataError(path, "model file not found (make one with `supportnet export`)")
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.log_severity_level = 3
    # idle intra-op threads wait without spinning: a spinning pool takes a core from the threads
    # that run beside a session (the global search beside the flow passes: 4.2 -> 3.8 s a
    # calibration on 2 cores, median of 6), and one predictor call costs the same either way
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    try:
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own types for a non-ONNX file
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DataError(path, f"is not a readable ONNX model ({first})") from None
    meta = session.get_modelmeta().custom_metadata_map
    if METADATA_KEY not in meta:
        raise DataError(path, f"has no '{METADATA_KEY}' metadata; export it with `supportnet export`")
    try:
        contract = Contract.from_json(meta[METADATA_KEY])
    except (ValueError, TypeError, KeyError) as exc:
        raise DataError(path, f"carries a contract this version cannot read ({exc})") from None
    if contract.output != output:
        raise DataError(path, f"is a model with {contract.output!r} output; this needs {output!r}")
    return session, contract
