"""Stage 4: the weighted, robust SE(3) refinement of the extrinsic (the paper's Eq. 4).

``min_ΔT Σ_i s_i ρ(‖ũ_i − π(K, ΔT · T⁰ · p_i)‖²)`` over ``ΔT = exp(δ)``, ``δ = (ρ, ω) ∈ se(3)``
applied on the left (in the camera frame), by Levenberg–Marquardt on iteratively reweighted
normal equations with analytic Jacobians. Points may come from many frames at once: the
extrinsic is shared, only the camera intrinsics ``K`` must be common.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from calib.errors import SupportnetError
from calib.geometry import se3_exp

__all__ = ["RefineConfig", "Refinement", "refine_extrinsic", "reprojection_jacobian", "robust_weight"]


class RefineConfig(BaseModel):
    """Robust loss and stopping rules of :func:`refine_extrinsic`."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    loss: Literal["cauchy", "huber", "squared"] = "cauchy"
    loss_scale_px: float = Field(2.0, gt=0, description="residual where the robust loss bends")
    max_iterations: int = Field(50, ge=1)
    step_tolerance: float = Field(1e-10, gt=0, description="stop when ‖δ‖ (m, rad) falls below this")
    initial_damping: float = Field(1e-3, gt=0, description="Levenberg–Marquardt λ at the start")


@dataclass(frozen=True)
class Refinement:
    """Result of :func:`refine_extrinsic`.

    Attributes:
        T_cam_lidar: ``(4, 4)`` the estimate ``exp(δ*) · T⁰``.
        covariance: ``(6, 6)`` of ``δ = (ρ, ω)`` about the estimate (metres, radians), from the
            final normal equations scaled by the residual variance.
        iterations: accepted and rejected LM steps taken. cost, initial_cost: the objective.
        converged: the step fell below the tolerance before ``max_iterations``.
    """

    T_cam_lidar: np.ndarray
    covariance: np.ndarray
    iterations: int
    cost: float
    initial_cost: float
    converged: bool


def robust_weight(r2: np.ndarray, loss: str, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """``ρ(r²)`` and its derivative ``ρ'(r²)`` (the IRLS weight) for squared residuals ``r2``.

    Cauchy ``ρ(s) = c² log(1 + s / c²)``; Huber ``ρ(s) = s`` for ``s ≤ c²``, else ``2c√s − c²``.
    """
    c2 = scale * scale
    if loss == "cauchy":
        return c2 * np.log1p(r2 / c2), 1.0 / (1.0 + r2 / c2)
    if loss == "huber":
        root = np.sqrt(r2)
        inlier = r2 <= c2
        return np.where(inlier, r2, 2 * scale * root - c2), np.where(
            inlier, 1.0, scale / np.maximum(root, 1e-12)
        )
    if loss == "squared":
        return r2, np.ones_like(r2)
    raise ValueError(f"unknown loss {loss!r} (cauchy, huber or squared)")


def reprojection_jacobian(points_cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    """``∂π(K, exp(δ) · q) / ∂δ`` at ``δ = 0``: ``(N, 2, 6)`` for ``points_cam q (N, 3)``.

    ``∂(exp(δ) q)/∂δ = [I | −[q]×]`` (translation first, as kornia's ``Se3``), chained with the
    pinhole derivative ``[[fx/z, s/z, −(fx x + s y)/z²], [0, fy/z, −fy y/z²]]``.
    """
    x, y, z = points_cam.T
    fx, s, fy = K[0, 0], K[0, 1], K[1, 1]
    d_pi = np.zeros((len(points_cam), 2, 3))
    d_pi[:, 0, 0], d_pi[:, 0, 1], d_pi[:, 0, 2] = fx / z, s / z, -(fx * x + s * y) / z**2
    d_pi[:, 1, 1], d_pi[:, 1, 2] = fy / z, -fy * y / z**2
    d_q = np.zeros((len(points_cam), 3, 6))
    d_q[:, :, :3] = np.eye(3)
    d_q[:, 0, 4], d_q[:, 0, 5] = z, -y  # −[q]× = [[0, z, −y], [−z, 0, x], [y, −x, 0]]
    d_q[:, 1, 3], d_q[:, 1, 5] = -z, x
    d_q[:, 2, 3], d_q[:, 2, 4] = y, -x
    return d_pi @ d_q


def _residuals(T: np.ndarray, points_lidar: np.ndarray, uv_target: np.ndarray, K: np.ndarray):
    q = points_lidar @ T[:3, :3].T + T[:3, 3]
    uvw = q @ K.T
    return uvw[:, :2] / uvw[:, 2:3] - uv_target, q


def refine_extrinsic(
    points_lidar: np.ndarray,
    uv_target: np.ndarray,
    weights: np.ndarray,
    K: np.ndarray,
    T_init: np.ndarray,
    config: RefineConfig = RefineConfig(),
) -> Refinement:
    """Minimise Eq. 4 over ``ΔT`` starting at ``T_init``.

    Args:
        points_lidar: ``(N, 3)`` points. uv_target: ``(N, 2)`` matched pixels ``ũ_i``.
        weights: ``(N,)`` non-negative ``s_i``. K: ``(3, 3)``. T_init: ``(4, 4)`` ``T⁰_cam_lidar``.

    Raises:
        SupportnetError: fewer than 6 usable correspondences, points behind the camera at the
            start, or a non-finite cost (reported, never returned as a silently wrong estimate).
    """
    p = np.asarray(points_lidar, np.float64)
    target = np.asarray(uv_target, np.float64)
    s = np.asarray(weights, np.float64)
    if p.shape[1:] != (3,) or target.shape != (len(p), 2) or s.shape != (len(p),):
        raise ValueError(
            f"expected points (N, 3), uv (N, 2), weights (N,); got {p.shape}, {target.shape}, {s.shape}"
        )
    if np.count_nonzero(s > 0) < 6:
        raise SupportnetError(
            f"refinement needs at least 6 weighted correspondences, got {np.count_nonzero(s > 0)}"
        )
    T = np.asarray(T_init, np.float64)

    def evaluate(T: np.ndarray):
        r, q = _residuals(T, p, target, K)
        rho, w = robust_weight((r * r).sum(1), config.loss, config.loss_scale_px)
        return float((s * rho).sum()), r, q, s * w

    cost, r, q, w = evaluate(T)
    if (q[:, 2] <= 0).any() or not np.isfinite(cost):
        raise SupportnetError(
            "refinement: points lie behind the camera or the cost is not finite at the start"
        )
    initial_cost, lam, converged, iterations = cost, config.initial_damping, False, 0
    while iterations < config.max_iterations:
        iterations += 1
        J = reprojection_jacobian(q, K)
        H = np.einsum("n,nai,naj->ij", w, J, J)
        g = np.einsum("n,nai,na->i", w, J, r)
        delta = -np.linalg.solve(H + lam * np.diag(np.diag(H)), g)
        T_new = se3_exp(torch.from_numpy(delta)).numpy() @ T
        new_cost, r_new, q_new, w_new = evaluate(T_new)
        if np.isfinite(new_cost) and new_cost < cost and (q_new[:, 2] > 0).all():
            T, cost, r, q, w, lam = T_new, new_cost, r_new, q_new, w_new, max(lam / 10, 1e-12)
        else:
            lam *= 10
        if np.linalg.norm(delta) < config.step_tolerance:
            converged = True
            break
    J = reprojection_jacobian(q, K)
    H = np.einsum("n,nai,naj->ij", w, J, J)
    dof = max(2 * np.count_nonzero(s > 0) - 6, 1)
    covariance = np.linalg.pinv(H) * float((w * (r * r).sum(1)).sum() / dof)
    return Refinement(T, covariance, iterations, cost, initial_cost, converged)
