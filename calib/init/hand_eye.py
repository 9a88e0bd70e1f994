"""Scaled hand–eye calibration of ``T_cam_lidar`` from camera and LiDAR motions (MDPCalib-style).

Both sensors sit on one rigid body, so every motion pair obeys ``A_k · X = X · B_k`` with
``X = T_cam_lidar``, ``A_k = T_cam_j_cam_i`` (visual odometry) and ``B_k = T_lidar_j_lidar_i``
(LiDAR odometry). Rotation: ``R_A R_X = R_X R_B``, so the rotation vectors obey ``ω_A = R_X ω_B``.
Translation: ``(R_A − I) t_X + s_k â_k = R_X t_B`` where monocular odometry gives only the
direction ``â_k`` of each camera translation and ``s_k`` is its unknown metric length.

1. Closed form: ``R_X`` by Kabsch on the rotation axes (and, when every axis is parallel, as in
   planar driving, on the translation directions too); then ``t_X`` and every ``s_k`` by linear
   least squares.
2. Robust joint refinement of ``R_X, t_X, s_k`` with ``scipy.optimize.least_squares`` (Cauchy).
3. Observability from the refined problem's information matrix: directions of ``R_X`` or ``t_X``
   whose standard deviation exceeds a threshold are reported as weak (planar motion leaves the
   translation along the common rotation axis, the vertical offset, unobservable).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from calib.errors import NumericalError
from calib.geometry import kabsch
from calib.observability import WeakDirection, weak_directions

__all__ = [
    "HandEyeConfig",
    "HandEyeResult",
    "UnobservableError",
    "WeakDirection",
    "hand_eye",
    "refine_hand_eye",
]


class UnobservableError(NumericalError):
    """The motion cannot determine the extrinsic; the message says what is unobservable."""


class HandEyeConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    min_rotation_deg: float = Field(
        1.0, ge=0, description="pairs rotating less are left out of the closed-form rotation"
    )
    min_pairs: int = Field(3, ge=2, description="fewer usable pairs than this is an error")
    metric_camera: bool = Field(False, description="camera translations are metric (scales known, = 1)")
    rotation_sigma_deg: float = Field(0.1, gt=0, description="expected rotation noise of one motion")
    translation_sigma_m: float = Field(0.02, gt=0, description="expected translation noise of one motion")
    loss_scale: float = Field(2.0, gt=0, description="Cauchy scale, in sigmas")
    translation_prior_m: float | None = Field(
        1.0,
        gt=0,
        description="σ of a weak prior t_X ≈ 0 that keeps unobservable directions bounded (None: off)",
    )
    weak_std_cm: float = Field(2.0, gt=0, description="a translation direction with a larger std is weak")
    weak_std_deg: float = Field(0.2, gt=0, description="a rotation direction with a larger std is weak")


@dataclass(frozen=True)
class HandEyeResult:
    """The refined extrinsic and what the motion could tell about it.

    Attributes:
        T_cam_lidar: ``(4, 4)``. closed_form: ``(4, 4)`` before refinement.
        scales: ``(K,)`` metric length of each camera translation.
        covariance: ``(6, 6)`` of (rotation vector rad, translation m), scales marginalised.
        std_deg, std_cm: ``(3,)`` per camera-frame axis.
        weak: directions whose std exceeds the thresholds (empty: everything observable).
        used: ``(K,)`` bool, the pairs rotating enough for the closed-form rotation (every pair
            enters the linear translation step and the refinement).
        inlier_ratio: share of pairs whose residuals stay within the Cauchy scale.
        information: ``(6, 6)`` what the motion pairs alone say about (rotation vector, translation)
            at the solution: ``Jᵀ J`` of the robustly weighted, σ-normalised pair residuals with the
            scales marginalised and the prior on ``t_X`` left out (the degeneracy tests read it).
    """

    T_cam_lidar: np.ndarray
    closed_form: np.ndarray
    scales: np.ndarray
    covariance: np.ndarray
    std_deg: np.ndarray
    std_cm: np.ndarray
    weak: list[WeakDirection]
    used: np.ndarray
    inlier_ratio: float
    cost: float
    notes: list[str] = field(default_factory=list)
    information: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))

    def report(self) -> dict:
        """The standard deviations and weak directions, as JSON-ready values."""
        return {
            "std_deg": self.std_deg.tolist(),
            "std_cm": self.std_cm.tolist(),
            "weak": [w.to_dict() for w in self.weak],
        }


def _closed_form(
    A: np.ndarray, B: np.ndarray, rotating: np.ndarray, metric: bool, notes: list[str]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``R_X`` from the ``rotating`` pairs' axes, then ``t_X`` and scales of every pair by linear
    least squares."""
    omega_A = Rotation.from_matrix(A[rotating, :3, :3]).as_rotvec()
    omega_B = Rotation.from_matrix(B[rotating, :3, :3]).as_rotvec()
    singular = np.linalg.svd(omega_B, compute_uv=False)
    source, target = omega_B, omega_A
    if singular[1] < 0.05 * singular[0]:  # every axis parallel: add the translation directions
        notes.append(
            "every motion turns about one axis (planar motion): rotation started from axes and headings"
        )
        unit = lambda t: t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)  # noqa: E731
        scale = np.linalg.norm(omega_B, axis=1).mean()
        moving = np.linalg.norm(B[:, :3, 3], axis=1) > 1e-6
        source = np.vstack([omega_B, scale * unit(B[moving, :3, 3])])
        target = np.vstack([omega_A, scale * unit(A[moving, :3, 3])])
    R_X = kabsch(source, target)
    K = len(A)
    # (R_A − I) t_X + s_k â_k = R_X t_B, stacked: unknowns t_X (3) and s_k (K) unless metric
    M = np.zeros((3 * K, 3 + (0 if metric else K)))
    rhs = (B[:, :3, 3] @ R_X.T).reshape(-1)
    for k in range(K):
        M[3 * k : 3 * k + 3, :3] = A[k, :3, :3] - np.eye(3)
        if metric:
            rhs[3 * k : 3 * k + 3] -= A[k, :3, 3]
        else:
            M[3 * k : 3 * k + 3, 3 + k] = A[k, :3, 3]
    x = np.linalg.lstsq(M, rhs, rcond=None)[0]
    return R_X, x[:3], (np.ones(K) if metric else x[3:])


def _residuals(
    x: np.ndarray, A: np.ndarray, B: np.ndarray, R0: np.ndarray, metric: bool, config: HandEyeConfig
) -> np.ndarray:
    """Normalised rotation and translation residuals of every pair, then the weak prior on
    ``t_X``: ``(6K + 3,)``."""
    R_X = Rotation.from_rotvec(x[:3]).as_matrix() @ R0
    t_X, scales = x[3:6], (np.ones(len(A)) if metric else x[6:])
    R_A, R_B = A[:, :3, :3], B[:, :3, :3]
    # rotation: log(R_Aᵀ · R_X R_B R_Xᵀ), zero when R_A = R_X R_B R_Xᵀ
    predicted = R_X @ R_B @ R_X.T
    rot = Rotation.from_matrix(np.transpose(R_A, (0, 2, 1)) @ predicted).as_rotvec()
    trans = (R_A - np.eye(3)) @ t_X + scales[:, None] * A[:, :3, 3] - B[:, :3, 3] @ R_X.T
    pairs = np.hstack([rot / np.radians(config.rotation_sigma_deg), trans / config.translation_sigma_m])
    prior = t_X / config.translation_prior_m if config.translation_prior_m else np.zeros(3)
    return np.concatenate([pairs.reshape(-1), prior])


def _cauchy_except_prior(z: np.ndarray) -> np.ndarray:
    """Cauchy ``ρ(z) = log(1 + z)`` on the pairs' squared residuals, plain squares on the last
    three (the prior on ``t_X`` must not be down-weighted as an outlier), with ρ′ and ρ″."""
    out = np.empty((3, len(z)))
    out[0], out[1], out[2] = np.log1p(z), 1 / (1 + z), -1 / (1 + z) ** 2
    out[:, -3:] = np.stack([z[-3:], np.ones(3), np.zeros(3)])
    return out


def _weak_directions(
    covariance: np.ndarray, R_X: np.ndarray, config: HandEyeConfig
) -> tuple[list[WeakDirection], np.ndarray, np.ndarray]:
    """The weak directions (rotation block first in this solver's covariance), and the
    per-camera-axis stds (degrees, cm)."""
    weak = weak_directions(
        covariance[3:, 3:], covariance[:3, :3], R_X, config.weak_std_cm, config.weak_std_deg
    )
    std_deg = np.degrees(np.sqrt(np.clip(np.diag(covariance)[:3], 0, None)))
    std_cm = 100 * np.sqrt(np.clip(np.diag(covariance)[3:], 0, None))
    return weak, std_deg, std_cm


def _rotating(A: np.ndarray, B: np.ndarray, config: HandEyeConfig) -> np.ndarray:
    """``(K,)`` bool: the pairs whose camera and LiDAR motions both rotate ``min_rotation_deg``."""
    angle_A = np.degrees(np.linalg.norm(Rotation.from_matrix(A[:, :3, :3]).as_rotvec(), axis=1))
    angle_B = np.degrees(np.linalg.norm(Rotation.from_matrix(B[:, :3, :3]).as_rotvec(), axis=1))
    return (angle_A >= config.min_rotation_deg) & (angle_B >= config.min_rotation_deg)


def hand_eye(A: np.ndarray, B: np.ndarray, config: HandEyeConfig = HandEyeConfig()) -> HandEyeResult:
    """``T_cam_lidar`` from motion pairs.

    Args:
        A: ``(K, 4, 4)`` camera motions ``T_cam_j_cam_i``; translations are directions (any
            length) unless ``config.metric_camera``.
        B: ``(K, 4, 4)`` LiDAR motions ``T_lidar_j_lidar_i`` over the same intervals, metric.

    Raises:
        UnobservableError: too few pairs rotate: the message names what the motion cannot tell.
    """
    if A.shape != B.shape or A.shape[1:] != (4, 4):
        raise ValueError(f"expected A and B (K, 4, 4), got {A.shape}, {B.shape}")
    used = _rotating(A, B, config)
    if used.sum() < config.min_pairs:
        raise UnobservableError(_no_rotation_report(B, int(used.sum()), config))
    notes: list[str] = []
    R0, t0, s0 = _closed_form(A, B, used, config.metric_camera, notes)
    closed = np.eye(4)
    closed[:3, :3], closed[:3, 3] = R0, t0
    result = refine_hand_eye(A, B, closed, s0, config)
    return replace(result, notes=notes)


def refine_hand_eye(
    A: np.ndarray,
    B: np.ndarray,
    start: np.ndarray,
    scales: np.ndarray,
    config: HandEyeConfig = HandEyeConfig(),
    max_evaluations: int | None = None,
) -> HandEyeResult:
    """The robust joint refinement of ``R_X, t_X, s_k`` from a start (step 2 of the module docstring).

    Args:
        A, B: ``(K, 4, 4)`` motion pairs, as :func:`hand_eye` takes them.
        start: ``(4, 4)`` the extrinsic to start from (the closed form, or another solve's answer).
        scales: ``(K,)`` metric lengths to start from (ignored with ``metric_camera``).
        max_evaluations: stop after this many residual evaluations (``None``: scipy's default).

    Returns:
        The refined result, with ``start`` as its ``closed_form``.
    """
    R0, t0 = start[:3, :3], start[:3, 3]
    x0 = np.concatenate([np.zeros(3), t0, [] if config.metric_camera else scales])
    K = len(A)
    sparsity = np.zeros((6 * K + 3, len(x0)), bool)  # pair k: the extrinsic and its own scale
    sparsity[:, :6] = True
    if not config.metric_camera:
        sparsity[np.arange(6 * K), 6 + np.repeat(np.arange(K), 6)] = True
    fit = least_squares(
        _residuals,
        x0,
        args=(A, B, R0, config.metric_camera, config),
        loss=_cauchy_except_prior,
        f_scale=config.loss_scale,
        x_scale="jac",
        jac_sparsity=sparsity,
        max_nfev=max_evaluations,
    )
    R_X = Rotation.from_rotvec(fit.x[:3]).as_matrix() @ R0
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R_X, fit.x[3:6]
    J = fit.jac.toarray() if hasattr(fit.jac, "toarray") else fit.jac  # sparse with jac_sparsity
    info, data_info = J.T @ J, J[:-3].T @ J[:-3]  # with and without the prior's three rows
    # marginalise the scales (Schur complement); rotation is a left perturbation in the camera frame
    if not config.metric_camera:
        info, data_info = (
            M[:6, :6] - M[:6, 6:] @ np.linalg.pinv(M[6:, 6:]) @ M[6:, :6] for M in (info, data_info)
        )
    covariance = np.linalg.pinv(info[:6, :6], rcond=1e-12, hermitian=True)
    values, vectors = np.linalg.eigh(info[:6, :6])
    if values[0] <= 1e-9 * values[-1]:  # an exactly blind direction: its std is unbounded
        covariance = covariance + 1e6 * np.outer(vectors[:, 0], vectors[:, 0])
    weak, std_deg, std_cm = _weak_directions(covariance, R_X, config)
    residual = _residuals(fit.x, A, B, R0, config.metric_camera, config)[:-3].reshape(-1, 6)
    inliers = float(np.mean(np.abs(residual).max(axis=1) <= config.loss_scale))
    return HandEyeResult(
        T_cam_lidar=T,
        closed_form=start.copy(),
        scales=(np.ones(len(A)) if config.metric_camera else fit.x[6:]),
        covariance=covariance,
        std_deg=std_deg,
        std_cm=std_cm,
        weak=weak,
        used=_rotating(A, B, config),
        inlier_ratio=inliers,
        cost=float(fit.cost),
        information=data_info[:6, :6],
    )


def _no_rotation_report(B: np.ndarray, usable: int, config: HandEyeConfig) -> str:
    """What a motion without enough rotation cannot determine (a straight line, pure translation)."""
    parts = [
        f"only {usable} of {len(B)} motion pairs rotate {config.min_rotation_deg}° or more "
        f"(at least {config.min_pairs} needed): the translation of T_cam_lidar is unobservable "
        "without rotation"
    ]
    t = B[:, :3, 3][np.linalg.norm(B[:, :3, 3], axis=1) > 1e-6]
    if len(t):
        singular, vectors = np.linalg.svd(t / np.linalg.norm(t, axis=1, keepdims=True))[1:]
        if len(singular) < 2 or singular[1] < 0.1 * singular[0]:
            d = vectors[0] * np.sign(vectors[0][np.argmax(np.abs(vectors[0]))])
            parts.append(
                f"and the motion is a straight line (LiDAR direction {np.round(d, 2).tolist()}): "
                "the rotation about it is unobservable too"
            )
    return "; ".join(parts) + ". Drive curves (turns both ways, over uneven ground) or use --init file:PATH."
