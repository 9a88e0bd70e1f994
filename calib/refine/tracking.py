"""Online calibration: Stage 4 over a sliding window of a stream, fused into a running estimate.

The state is the extrinsic's departure from the one on file, ``x = log(T_file⁻¹ · T)`` (a twist
``(ρ, ω)``, metres and radians). The mount is a random walk (a loosening bracket moves a little
between windows), so each window predicts ``P ← P + Q`` and updates with that window's refined
extrinsic ``z`` and its covariance ``R`` (Kalman): ``K = P (P + R)⁻¹, x ← x + K (z − x),
P ← (I − K) P``. Drift is flagged when the running estimate has left the calibration on file by
more than ``drift_sigmas`` of its uncertainty and a minimum size.

The camera–LiDAR time offset ``δt`` (a clock that drifts slowly) is tracked beside it by a
scalar filter of the same kind, from the windows whose motion tells ``δt`` (the others leave it
to the prediction), and its departure from where it started counts as drift too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, NonNegativeFloat, PositiveFloat

from calib.geometry import se3_exp, se3_log
from calib.results import block_std

__all__ = ["OnlineConfig", "OnlineState", "departure", "extrinsic_of"]


class OnlineConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    window: int = Field(10, ge=1, description="frames refined together")
    step: int = Field(5, ge=1, description="frames between the starts of two windows")
    initial_std: tuple[PositiveFloat, PositiveFloat] = Field(
        (10.0, 2.0), description="cm, °: how far the start may be from the truth"
    )
    process_std: tuple[NonNegativeFloat, NonNegativeFloat] = Field(
        (1.0, 0.2), description="cm, °: how far the mount may move between two windows"
    )
    measurement_floor: tuple[NonNegativeFloat, NonNegativeFloat] = Field(
        (3.0, 0.05),
        description="cm, °: added to each window's covariance (the matcher's errors are correlated "
        "across points, so the refinement's own covariance is optimistic; one window's translation "
        "scatters by a few cm)",
    )
    drift_sigmas: float = Field(3.0, gt=0, description="drift: beyond this many standard deviations ...")
    drift_min: tuple[NonNegativeFloat, NonNegativeFloat] = Field(
        (2.0, 0.3), description="... and beyond this size (cm, °)"
    )
    time_offset_initial_std_ms: PositiveFloat = Field(50.0, description="how far δt may start from the truth")
    time_offset_process_std_ms: NonNegativeFloat = Field(
        1.0, description="how far δt may move between windows"
    )
    time_offset_floor_ms: NonNegativeFloat = Field(
        1.0,
        description="added to each window's δt std (the fit's own is optimistic: 0.02 ms claimed "
        "where the error was 1 ms on the synthetic street)",
    )
    time_offset_drift_min_ms: NonNegativeFloat = Field(5.0, description="δt drift: beyond this size too")


def _diag(sizes: tuple[float, float]) -> np.ndarray:
    """``(6, 6)`` diagonal variance from (cm, °) standard deviations."""
    return np.diag(np.repeat([sizes[0] / 100, np.radians(sizes[1])], 3) ** 2)


def departure(T: np.ndarray, T_file: np.ndarray) -> np.ndarray:
    """``(6,)`` twist ``log(T_file⁻¹ · T)``: how far ``T`` is from the calibration on file."""
    return se3_log(torch.from_numpy(np.linalg.inv(T_file) @ T)).numpy()


def extrinsic_of(x: np.ndarray, T_file: np.ndarray) -> np.ndarray:
    """``(4, 4)`` ``T_file · exp(x)``, the inverse of :func:`departure`."""
    return T_file @ se3_exp(torch.from_numpy(np.asarray(x, np.float64))).numpy()


@dataclass
class OnlineState:
    """The running estimate ``x (6,)`` and its covariance ``P (6, 6)`` about the file's extrinsic."""

    x: np.ndarray
    P: np.ndarray
    config: OnlineConfig
    time_offset_s: float = 0.0
    time_offset_var: float = 0.0
    time_offset_file_s: float = 0.0

    @classmethod
    def start(
        cls, T_init: np.ndarray, T_file: np.ndarray, config: OnlineConfig, time_offset_s: float = 0.0
    ) -> OnlineState:
        return cls(
            departure(T_init, T_file),
            _diag(config.initial_std),
            config,
            time_offset_s,
            (config.time_offset_initial_std_ms / 1e3) ** 2,
            time_offset_s,
        )

    def update_time_offset(self, z_s: float | None, std_s: float | None) -> None:
        """Predict ``δt`` one window on; fuse one window's ``z_s`` with ``std_s`` where it has one."""
        self.time_offset_var += (self.config.time_offset_process_std_ms / 1e3) ** 2
        if z_s is None or std_s is None:
            return
        r = std_s**2 + (self.config.time_offset_floor_ms / 1e3) ** 2
        gain = self.time_offset_var / (self.time_offset_var + r)
        self.time_offset_s += gain * (z_s - self.time_offset_s)
        self.time_offset_var *= 1 - gain

    @property
    def time_offset_std_s(self) -> float:
        return float(np.sqrt(self.time_offset_var))

    def update(self, z: np.ndarray, R: np.ndarray) -> None:
        """Fuse one window's estimate ``z (6,)`` with covariance ``R (6, 6)``."""
        self.P = self.P + _diag(self.config.process_std)
        R = R + _diag(self.config.measurement_floor)
        gain = self.P @ np.linalg.inv(self.P + R)
        self.x = self.x + gain @ (z - self.x)
        self.P = (np.eye(6) - gain) @ self.P

    @property
    def std(self) -> tuple[float, float]:
        """Standard deviations of the translation (cm) and rotation (°), the largest per block."""
        return block_std(self.P)

    @property
    def drift(self) -> bool:
        """Whether the estimate has left the calibration on file beyond its uncertainty."""
        size = (
            100 * np.linalg.norm(self.x[:3]),
            np.degrees(np.linalg.norm(self.x[3:])),
            1e3 * abs(self.time_offset_s - self.time_offset_file_s),
        )
        std = (*self.std, 1e3 * self.time_offset_std_s)
        minimums = (*self.config.drift_min, self.config.time_offset_drift_min_ms)
        return any(
            s > max(self.config.drift_sigmas * sd, minimum)
            for s, sd, minimum in zip(size, std, minimums, strict=True)
        )
