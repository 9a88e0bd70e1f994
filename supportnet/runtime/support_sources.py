"""Stage 3 sources by name (``--support``, ``supportnet.Calibrator(support=...)``): ``uniform``,
``offline:MAPS`` (a ``supportnet maps`` folder) and ``onnx[:MODEL]`` (the learned predictor;
bare ``onnx`` = the shipped model). Each implements :class:`calib.support.source.SupportSource`."""

from __future__ import annotations

import threading
from collections import OrderedDict
from pathlib import Path

import cv2
import numpy as np

from calib.data.types import Frame
from calib.errors import ConfigError
from calib.match.correspondences import working_view
from calib.match.edge_matcher import recall
from calib.support.map_files import load_sequence_maps
from calib.support.source import MapSupport, SupportSource, UniformSupport
from supportnet.nets.contract import Contract
from supportnet.runtime.support_predictor import SHIPPED_MODEL, SupportPredictor

__all__ = [
    "PredictedSupport",
    "model_image",
    "offline_maps_folders",
    "parse_supports",
    "predict_frame",
    "resolve_support",
]


class PredictedSupport:
    """The support map the exported U-Net predicts from each frame's image alone (Stage 3
    online), remembered for the last frames seen so passes over the same frames predict once.

    Args:
        name: how results name it. predictor: the onnxruntime model.
    """

    def __init__(self, name: str, predictor: SupportPredictor, remember: int = 64) -> None:
        self.name = name
        self.predictor = predictor
        self._remember = remember
        # each entry holds its image: an id is reused only once its image is gone, so a frame
        # built by a caller (index 0, no name) never meets another image's map
        self._maps: OrderedDict[tuple[int, str, int], tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self._lock = threading.Lock()

    def __call__(self, frame: Frame) -> np.ndarray:
        def make() -> tuple[np.ndarray, np.ndarray]:
            return frame.image, predict_frame(self.predictor, frame)

        key = (frame.index, frame.name, id(frame.image))
        return recall(self._maps, key, make, self._lock, self._remember)[1]


def model_image(contract: Contract, frame: Frame) -> np.ndarray:
    """``frame``'s image as a model of ``contract`` sees it: where the contract names the focal
    length it learned at (``working_focal_px``) and the frame's is longer, resampled down to it
    (:func:`~calib.match.correspondences.working_view`), so a model trained on 624x188 frames sees
    a full-resolution camera's at its own scale."""
    focal = contract.extra.get("working_focal_px")
    return frame.image if focal is None else working_view(frame, float(focal)).image


def predict_frame(predictor: SupportPredictor, frame: Frame) -> np.ndarray:
    """``(H, W)`` the support of ``frame``'s image, predicted on :func:`model_image` and the map
    brought back to the frame's size (bilinear)."""
    support = predictor.predict(model_image(predictor.contract, frame))[0]
    H, W = frame.image_size
    if support.shape == (H, W):
        return support
    return cv2.resize(support, (W, H), interpolation=cv2.INTER_LINEAR)


def resolve_support(spec: str | SupportSource, support_map: str = "support") -> SupportSource:
    """A support source from its name, or ``spec`` itself when it already is one.

    Args:
        spec: ``uniform``, ``offline:MAPS`` or ``onnx[:MODEL]``.
        support_map: which offline map SGIS reads (``support`` or ``agreement``).

    Raises:
        ConfigError: an unknown name. DataError: a missing or unreadable maps folder or model.
    """
    if not isinstance(spec, str):
        if not isinstance(spec, SupportSource):
            raise ConfigError("support", f"{spec!r} is neither a name nor a SupportSource")
        return spec
    kind, _, arg = spec.strip().partition(":")
    if kind == "uniform" and not arg:
        return UniformSupport()
    if kind == "offline" and arg:
        return MapSupport(spec, _offline_map(Path(arg), support_map))
    if kind == "onnx":
        return PredictedSupport(spec, SupportPredictor(Path(arg) if arg else SHIPPED_MODEL))
    raise ConfigError("--support", f"{spec!r} is not uniform, offline:MAPS or onnx[:MODEL]")


def parse_supports(text: str, support_map: str = "support") -> list[SupportSource]:
    """Comma-separated ``--support`` values (paired runs), each resolved; distinct names."""
    names = [s.strip() for s in text.split(",") if s.strip()]
    if not names or len(set(names)) != len(names):
        raise ConfigError("--support", f"needs one or more distinct values, got {text!r}")
    return [resolve_support(name, support_map) for name in names]


def _offline_map(maps: Path, key: str) -> np.ndarray:
    """The whole-sequence map ``key`` of a ``supportnet maps`` folder (any unreadable file is one
    line naming it)."""
    return load_sequence_maps(maps, (key,))[key]


def offline_maps_folders(supports: list[SupportSource]) -> list[Path]:
    """The maps folders of the ``offline:MAPS`` sources among ``supports``."""
    return [
        Path(s.name.partition(":")[2])
        for s in supports
        if isinstance(s, MapSupport) and s.name.startswith("offline:")
    ]
