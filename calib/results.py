"""Typed results of the library: what :class:`calib.pipeline.Calibrator` and
:class:`calib.pipeline.OnlineCalibrator` return. Every ``result.json`` is written from their
``to_dict()``, which is strict JSON (no NaN) and carries :data:`SCHEMA_VERSION`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib.geometry import CalibrationError, calibration_error
from calib.observability import WeakDirection

__all__ = ["SCHEMA_VERSION", "CalibrationResult", "OnlineEstimate", "block_std"]

SCHEMA_VERSION = 2
"""Version of the ``result.json`` layout: 2 adds ``schema_version``, ``covariance_order``,
``std_cm``/``std_deg``, ``weak_directions`` and the time offset fields."""


def block_std(covariance: np.ndarray) -> tuple[float, float]:
    """Largest standard deviation of the translation (cm) and rotation (°) blocks of a ``(6, 6)``
    covariance of ``(ρ m, ω rad)``."""
    c = np.asarray(covariance, np.float64)
    t, r = (float(np.sqrt(max(np.linalg.eigvalsh(c[s, s]).max(), 0.0))) for s in (slice(0, 3), slice(3, 6)))
    return 100 * t, float(np.degrees(r))


def _matrix(T: np.ndarray | None) -> list | None:
    return None if T is None else np.asarray(T, np.float64).tolist()


def _error(T: np.ndarray, T_ref: np.ndarray | None) -> CalibrationError | None:
    return None if T_ref is None else calibration_error(T, T_ref)


@dataclass(frozen=True)
class CalibrationResult:
    """One calibration of a sequence (Stages 2–4 from an initial extrinsic).

    Attributes:
        T_cam_lidar: ``(4, 4)`` the estimate.
        initial_T_cam_lidar: ``(4, 4)`` where it started.
        reference_T_cam_lidar: ``(4, 4)`` the data's own calibration, or ``None``.
        covariance: ``(6, 6)`` of the left perturbation ``δ = (ρ, ω)`` (metres, radians, camera
            frame) about the estimate: ``T = exp(δ) · T*``; cluster-robust over image cells
            where ``refine.covariance_cell_deg`` is set (the matcher's errors are shared by
            neighbouring points), else from independent residuals.
        support: name of the support source (``uniform``, ``offline:MAPS``, ``onnx``).
        frame_indices: the frames used, as positions in the sequence.
        correspondences: how many the last pass used.
        runtime_s: seconds.
        passes: one dict per pass (iterations, cost, correspondences, update).
        coarse: one dict per scale of the global coarse stage (σ, score before and after), or
            empty when it did not run.
        weak_directions: directions whose std passes the config's thresholds.
        time_offset_s, time_offset_std_s: camera minus LiDAR time ``δt`` the points were moved by
            (``None``: not moved), and its std (``None``: held, not estimated).
        time_offset_note: how ``δt`` was found, or why it was held.
        time_offset_reference_s: the frames' camera stamp minus LiDAR stamp, where known.
        moving_points: per used frame, the points left out as moving (:mod:`calib.moving`).
        stage_seconds: seconds per stage, in the order they ran (``frames``, ``global``, or
            ``global and flow, side by side`` where the learned matcher's passes run beside the
            global search, ``probe``, ``pyramid 90 px``, ..., ``finest``).
    """

    T_cam_lidar: np.ndarray
    initial_T_cam_lidar: np.ndarray
    reference_T_cam_lidar: np.ndarray | None
    covariance: np.ndarray
    support: str
    frame_indices: list[int]
    correspondences: int
    runtime_s: float
    passes: list[dict] = field(default_factory=list)
    coarse: list[dict] = field(default_factory=list)
    weak_directions: list[WeakDirection] = field(default_factory=list)
    time_offset_s: float | None = None
    time_offset_std_s: float | None = None
    time_offset_note: str = ""
    time_offset_reference_s: float | None = None
    moving_points: list[int] = field(default_factory=list)
    stage_seconds: dict[str, float] = field(default_factory=dict)

    @property
    def error(self) -> CalibrationError | None:
        """Error against the reference, ``None`` without one."""
        return _error(self.T_cam_lidar, self.reference_T_cam_lidar)

    @property
    def initial_error(self) -> CalibrationError | None:
        return _error(self.initial_T_cam_lidar, self.reference_T_cam_lidar)

    @property
    def std(self) -> tuple[float, float]:
        """Largest standard deviation of translation (cm) and rotation (°)."""
        return block_std(self.covariance)

    def to_dict(self) -> dict:
        error, initial = self.error, self.initial_error
        std_cm, std_deg = self.std
        return {
            "schema_version": SCHEMA_VERSION,
            "T_cam_lidar": _matrix(self.T_cam_lidar),
            "initial_T_cam_lidar": _matrix(self.initial_T_cam_lidar),
            "reference_T_cam_lidar": _matrix(self.reference_T_cam_lidar),
            "error": None if error is None else error.to_dict(),
            "initial_error": None if initial is None else initial.to_dict(),
            "covariance": _matrix(self.covariance),
            "covariance_order": "rho_x rho_y rho_z (m), omega_x omega_y omega_z (rad), camera frame, left",
            "std_cm": std_cm,
            "std_deg": std_deg,
            "weak_directions": [w.to_dict() for w in self.weak_directions],
            "time_offset_s": self.time_offset_s,
            "time_offset_std_s": self.time_offset_std_s,
            "time_offset_note": self.time_offset_note,
            "time_offset_reference_s": self.time_offset_reference_s,
            "moving_points": list(self.moving_points),
            "stage_seconds": dict(self.stage_seconds),
            "support": self.support,
            "frames": len(self.frame_indices),
            "frame_indices": list(self.frame_indices),
            "correspondences": self.correspondences,
            "runtime_s": self.runtime_s,
            "coarse": self.coarse,
            "passes": self.passes,
        }


@dataclass(frozen=True)
class OnlineEstimate:
    """The running estimate after one window of a stream.

    Attributes:
        window: its number (0, 1, ...). first_frame, last_frame: the frames it spans.
        time_s: camera time of the window's middle frame.
        T_cam_lidar: ``(4, 4)`` the running (fused) estimate.
        window_T_cam_lidar: ``(4, 4)`` this window's own refinement.
        covariance: ``(6, 6)`` of the running estimate's twist about the calibration on file.
        drift: whether it has left the calibration on file beyond its uncertainty.
        correspondences: how many this window's last pass used.
        reference_T_cam_lidar: the calibration on file.
        time_offset_s, time_offset_std_s: the running ``δt`` and its std.
        time_offset_rate: the rate the running ``δt`` drifts at (seconds per second).
        window_time_offset_s: this window's own ``δt`` (``None``: held or not modelled).
        window_time_offset_taken: whether the running ``δt`` took it (not where it lay outside
            the gate, :class:`~calib.refine.tracking.OnlineConfig`'s ``time_offset_gate_sigmas``).
    """

    window: int
    first_frame: int
    last_frame: int
    time_s: float
    T_cam_lidar: np.ndarray
    window_T_cam_lidar: np.ndarray
    covariance: np.ndarray
    drift: bool
    correspondences: int
    reference_T_cam_lidar: np.ndarray
    time_offset_s: float = 0.0
    time_offset_std_s: float = 0.0
    window_time_offset_s: float | None = None
    window_time_offset_taken: bool = False
    time_offset_rate: float = 0.0

    @property
    def std(self) -> tuple[float, float]:
        """Largest standard deviation of translation (cm) and rotation (°)."""
        return block_std(self.covariance)

    def to_dict(self) -> dict:
        std_cm, std_deg = self.std
        return {
            "schema_version": SCHEMA_VERSION,
            "window": self.window,
            "first_frame": self.first_frame,
            "last_frame": self.last_frame,
            "time_s": self.time_s,
            "T_cam_lidar": _matrix(self.T_cam_lidar),
            "window_T_cam_lidar": _matrix(self.window_T_cam_lidar),
            "std_cm": std_cm,
            "std_deg": std_deg,
            "drift": self.drift,
            "correspondences": self.correspondences,
            "time_offset_s": self.time_offset_s,
            "time_offset_std_s": self.time_offset_std_s,
            "window_time_offset_s": self.window_time_offset_s,
            "window_time_offset_taken": self.window_time_offset_taken,
            "time_offset_rate": self.time_offset_rate,
        }
