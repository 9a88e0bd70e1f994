"""Online calibration: Stage 4 over a sliding window of a stream, fused into a running estimate.

The state is the extrinsic's departure from the one on file, ``x = log(T_file⁻¹ · T)`` (a twist
``(ρ, ω)``, metres and radians), the camera–LiDAR time offset ``δt`` and the rate it drifts at
(two free-running clocks drift apart linearly), with their joint covariance ``C``. The extrinsic
is a random walk (a loosening bracket moves a little between windows), ``δt`` moves on by its
rate and diffuses; each window predicts and updates (Kalman) with that window's refined
extrinsic ``z`` and its covariance ``R``, and its own ``δt`` where its motion told it.
A window's extrinsic was fitted with its points moved by the ``δt`` it used; were that off by
``ε``, the fit moves the extrinsic by ``−ε ξ̄`` (``ξ̄`` the LiDAR's mean body twist over the
window), so ``z = x − ξ̄ (δt − δt_used)``: a straight window tells the extrinsic and ``δt``
together, and once a turn tells ``δt`` that corrects what the straight ones said (the
translation's bias along the drive).

Drift is flagged when the running estimate has left the calibration on file by more than
``drift_sigmas`` of its uncertainty and a minimum size, or ``δt`` has left where it stood when
a window first fitted it (the start, ``time_offset.initial_s``, is a guess within
``time_offset_initial_std_ms``: the first fit correcting it is not the clock drifting).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, NonNegativeFloat, PositiveFloat

from calib.geometry import se3_adjoint, se3_exp, se3_inverse, se3_log
from calib.results import block_std

__all__ = ["OnlineConfig", "OnlineState", "departure", "departure_covariance", "extrinsic_of"]


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
    time_offset_rate_initial_std_ppm: NonNegativeFloat = Field(
        0.0,
        description="how fast the clock may drift at the start (ppm: µs of δt per second; 0: δt is a "
        "random walk alone, the default); where set, the rate is tracked, so between the turns "
        "that tell δt it moves on at the rate they showed. Off by default: on a drive with one "
        "turn its uncertainty widened δt's gate and a wrong turn window got in (README, online)",
    )
    time_offset_rate_process_std_ppm: NonNegativeFloat = Field(
        0.0, description="how far that rate may change between windows"
    )
    time_offset_floor_ms: NonNegativeFloat = Field(
        1.0,
        description="added to each window's δt std (the fit's own is optimistic: 0.02 ms claimed "
        "where the error was 1 ms on the synthetic street)",
    )
    time_offset_drift_min_ms: NonNegativeFloat = Field(5.0, description="δt drift: beyond this size too")
    time_offset_gate_sigmas: PositiveFloat = Field(
        3.0,
        description="a window's δt this many standard deviations (its own and the prediction's) "
        "from the running one is not taken (a fit in another minimum: one window of a turn can "
        "settle 5-25 ms off, README), unless the window before said the same (the clock jumped); "
        "its extrinsic still is, at the δt it used",
    )


def _diag(sizes: tuple[float, float]) -> np.ndarray:
    """``(6, 6)`` diagonal variance from (cm, °) standard deviations."""
    return np.diag(np.repeat([sizes[0] / 100, np.radians(sizes[1])], 3) ** 2)


def departure(T: np.ndarray, T_file: np.ndarray) -> np.ndarray:
    """``(6,)`` twist ``log(T_file⁻¹ · T)``: how far ``T`` is from the calibration on file."""
    return se3_log(torch.from_numpy(np.linalg.inv(T_file) @ T)).numpy()


def departure_covariance(covariance: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``(6, 6)`` covariance of :func:`departure` ``(T, ·)`` from ``covariance (6, 6)`` of the
    left perturbation ``T = exp(δ) · T*`` in the camera frame (a calibration's, Stage 4): the
    departure moves by ``Ad(T⁻¹) δ``, in the LiDAR frame, to first order near the file's."""
    Ad = se3_adjoint(se3_inverse(torch.from_numpy(np.asarray(T, np.float64)))).numpy()
    return Ad @ np.asarray(covariance, np.float64) @ Ad.T


def extrinsic_of(x: np.ndarray, T_file: np.ndarray) -> np.ndarray:
    """``(4, 4)`` ``T_file · exp(x)``, the inverse of :func:`departure`."""
    return T_file @ se3_exp(torch.from_numpy(np.asarray(x, np.float64))).numpy()


@dataclass
class OnlineState:
    """The running estimate: the extrinsic's departure ``x (6,)`` from the file's, ``δt``
    (seconds) and the rate it drifts at (seconds per second), with their joint covariance
    ``C (8, 8)`` (``δt`` and its rate last)."""

    x: np.ndarray
    time_offset_s: float
    C: np.ndarray
    config: OnlineConfig
    time_offset_rate: float = 0.0
    time_offset_told_s: float | None = None
    outside_s: float | None = None  # the last window's δt, where it fell outside the gate

    @classmethod
    def start(
        cls, T_init: np.ndarray, T_file: np.ndarray, config: OnlineConfig, time_offset_s: float = 0.0
    ) -> OnlineState:
        C = np.zeros((8, 8))
        C[:6, :6] = _diag(config.initial_std)
        C[6, 6] = (config.time_offset_initial_std_ms / 1e3) ** 2
        C[7, 7] = (config.time_offset_rate_initial_std_ppm * 1e-6) ** 2
        return cls(departure(T_init, T_file), time_offset_s, C, config)

    @property
    def P(self) -> np.ndarray:
        """``(6, 6)`` the extrinsic's covariance (``δt`` marginalised out)."""
        return self.C[:6, :6]

    def predicted_time_offset_s(self, elapsed_s: float | None) -> float:
        """``δt`` carried ``elapsed_s`` seconds on at its rate (``None``: as it stands)."""
        return self.time_offset_s + self.time_offset_rate * (elapsed_s or 0.0)

    @property
    def time_offset_std_s(self) -> float:
        return float(np.sqrt(self.C[6, 6]))

    def update(
        self,
        z: np.ndarray,
        R: np.ndarray,
        twist: np.ndarray | None = None,
        used_s: float = 0.0,
        z_s: float | None = None,
        std_s: float | None = None,
        elapsed_s: float | None = None,
    ) -> bool:
        """Predict one window on and fuse that window: its extrinsic's departure ``z (6,)`` with
        covariance ``R (6, 6)`` (of ``z``, in the LiDAR frame: :func:`departure_covariance`),
        fitted with its points moved by ``δt = used_s`` along the LiDAR's mean body twist
        ``twist (6,)`` (``None``: not moved), and its own ``δt`` fit ``z_s`` with ``std_s`` where it
        made one.

        The clock is an offset and a rate (a skew, as two free-running clocks drift: linearly
        between corrections): over the ``elapsed_s`` seconds since the last window ``δt`` moves on
        by its rate times them (``None``: no times known, ``δt`` only diffuses). Between the turns
        that tell ``δt``, the straight windows' translations then follow the clock as it drifts.

        A window fitted at a ``δt`` off by ``ε`` finds the extrinsic moved by ``−ε · twist``
        (its points sit where the LiDAR was ``ε`` earlier): ``z = x − twist (δt − used_s)``. So a
        window that holds ``δt`` (a straight drive) tells ``x`` and ``δt`` together, and one that
        turns tells ``δt`` too, which then corrects what the straight ones said of ``x``.

        Returns:
            Whether the window's own ``δt`` was taken (not where it fell outside the gate,
            ``time_offset_gate_sigmas``).
        """
        cfg = self.config
        F = np.eye(8)
        F[6, 7] = elapsed_s or 0.0
        Q = np.zeros((8, 8))
        Q[:6, :6] = _diag(cfg.process_std)
        Q[6, 6] = (cfg.time_offset_process_std_ms / 1e3) ** 2
        Q[7, 7] = (cfg.time_offset_rate_process_std_ppm * 1e-6) ** 2
        s = F @ np.append(self.x, [self.time_offset_s, self.time_offset_rate])
        C = F @ self.C @ F.T + Q
        twist = np.zeros(6) if twist is None else np.asarray(twist, np.float64)
        fitted = z_s is not None and std_s is not None
        if fitted:
            r = std_s**2 + (cfg.time_offset_floor_ms / 1e3) ** 2
            gate = cfg.time_offset_gate_sigmas * np.sqrt(r)
            if self.outside_s is not None and abs(z_s - self.outside_s) <= gate * np.sqrt(2):
                C[6, 6] += (z_s - s[6]) ** 2  # two windows agree: the clock jumped
            fitted = abs(z_s - s[6]) <= cfg.time_offset_gate_sigmas * np.sqrt(C[6, 6] + r)
            self.outside_s = None if fitted else z_s
        H = np.hstack([np.eye(6), -twist[:, None], np.zeros((6, 1))])
        m = np.asarray(z, np.float64) - twist * used_s
        if fitted:
            H, m = np.vstack([H, np.eye(8)[6]]), np.append(m, z_s)
        noise = np.zeros((len(m), len(m)))
        noise[:6, :6] = R + _diag(cfg.measurement_floor)
        if fitted:
            noise[6, 6] = r
        gain = C @ H.T @ np.linalg.inv(H @ C @ H.T + noise)
        s = s + gain @ (m - H @ s)
        I_KH = np.eye(8) - gain @ H
        self.C = I_KH @ C @ I_KH.T + gain @ noise @ gain.T  # Joseph form: stays symmetric
        self.x, self.time_offset_s, self.time_offset_rate = s[:6], float(s[6]), float(s[7])
        if self.time_offset_told_s is None and fitted:
            self.time_offset_told_s = self.time_offset_s  # where the clock stood when first told
        return fitted

    @property
    def std(self) -> tuple[float, float]:
        """Standard deviations of the translation (cm) and rotation (°), the largest per block."""
        return block_std(self.P)

    @property
    def drift(self) -> bool:
        """Whether the estimate has left the calibration on file beyond its uncertainty."""
        told = self.time_offset_told_s
        size = (
            100 * np.linalg.norm(self.x[:3]),
            np.degrees(np.linalg.norm(self.x[3:])),
            0.0 if told is None else 1e3 * abs(self.time_offset_s - told),
        )
        std = (*self.std, 1e3 * self.time_offset_std_s)
        minimums = (*self.config.drift_min, self.config.time_offset_drift_min_ms)
        return any(
            s > max(self.config.drift_sigmas * sd, minimum)
            for s, sd, minimum in zip(size, std, minimums, strict=True)
        )
