"""``SupportPredictor``: Stage 3 online, the exported U-Net in onnxruntime (numpy and
onnxruntime only: no torch at run time)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnxruntime as ort

from calib.errors import DataError
from supportnet.contract import METADATA_KEY, Contract

__all__ = ["SHIPPED_MODEL", "SupportPredictor"]

SHIPPED_MODEL = Path(__file__).resolve().parent / "assets" / "support_unet.onnx"
"""The small model trained on the synthetic worlds (``make model``), used by ``--support onnx``."""


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
        if not self.path.is_file():
            raise DataError(self.path, "model file not found (make one with `supportnet export`)")
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own types for a non-ONNX file
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise DataError(self.path, f"is not a readable ONNX model ({first})") from None
        meta = self.session.get_modelmeta().custom_metadata_map
        if METADATA_KEY not in meta:
            raise DataError(
                self.path, f"has no '{METADATA_KEY}' metadata; export it with `supportnet export`"
            )
        try:
            self.contract = Contract.from_json(meta[METADATA_KEY])
        except (ValueError, TypeError, KeyError) as exc:
            raise DataError(self.path, f"carries a contract this version cannot read ({exc})") from None
        self.input_name = self.session.get_inputs()[0].name

    def predict(self, images: np.ndarray) -> np.ndarray:
        """Support of every pixel.

        Args:
            images: ``(B, H, W, 3)`` or ``(H, W, 3)`` uint8 RGB, any ``H, W``.

        Returns:
            ``(B, H, W)`` float32 in [0, 1].
        """
        (logits,) = self.session.run(None, {self.input_name: self.contract.preprocess(images)})
        return (1.0 / (1.0 + np.exp(-logits[:, 0]))).astype(np.float32)
