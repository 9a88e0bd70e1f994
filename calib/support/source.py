"""Stage 3 at run time: where a support map comes from. Stage 4 asks a :class:`SupportSource` for
each frame's map; ``calib`` ships the two that need no learned part (uniform, and a fixed offline
map of the whole sequence), and ``supportnet.runtime`` adds the learned predictor."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from calib.data.types import Frame
from calib.errors import DataError

__all__ = ["MapSupport", "SupportSource", "UniformSupport"]


@runtime_checkable
class SupportSource(Protocol):
    """The support map of a frame.

    Attributes:
        name: how results and reports name it (``uniform``, ``offline:MAPS``, ``onnx``).
    """

    name: str

    def __call__(self, frame: Frame) -> np.ndarray | None:
        """``(H, W)`` support in [0, 1] for ``frame`` (its image size), or ``None``: sample
        uniformly."""
        ...


@dataclass(frozen=True)
class UniformSupport:
    """No support map: Stage 4 samples correspondences uniformly (the MDPCalib baseline)."""

    name: str = "uniform"

    def __call__(self, frame: Frame) -> None:
        return None


@dataclass(frozen=True)
class MapSupport:
    """One fixed ``(H, W)`` map for every frame (an offline map of the whole sequence, Eq. 2)."""

    name: str
    map: np.ndarray

    def __call__(self, frame: Frame) -> np.ndarray:
        if self.map.shape != frame.image_size:
            raise DataError(self.name, f"map is {self.map.shape}, images are {frame.image_size}")
        return self.map
