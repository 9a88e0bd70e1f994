"""Stage 4: the weighted, robust SE(3) refinement of the extrinsic (the paper's Eq. 4).

``min_ΔT Σ_i s_i ρ(‖ũ_i − π(K, ΔT · T⁰ · p_i)‖²)`` over ``ΔT = exp(δ)``, ``δ = (ρ, ω) ∈ se(3)``
applied on the left (in the camera frame), by Levenberg–Marquardt on iteratively reweighted
normal equations with analytic Jacobians. Points may come from many frames at once: the
extrinsic is shared, only the camera intrinsics ``K`` must be common. The loop runs in torch
(float64) from end to end; numpy arrays are converted once at the entry and the exit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from calib.errors import NumericalError
from calib.geometry import se3_exp

__all__ = ["RefineConfig", "Refinement", "refine_extrinsic", "reprojection_jacobian", "robust_weight"]


class RefineConfig(BaseModel):
    """Robust loss and stopping rules of :func:`refine_extrinsic`."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

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
        residuals: ``(N, 2)`` pixels ``π(K, T p_i) − ũ_i`` at the estimate.
    """

    T_cam_lidar: np.ndarray
    covariance: np.ndarray
    iterations: int
    cost: float
    initial_cost: float
    converged: bool
    residuals: np.ndarray


def robust_weight(r2: torch.Tensor, loss: str, scale: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``ρ(r²)`` and its derivative ``ρ'(r²)`` (the IRLS weight) for squared residuals ``r2``.

    Cauchy ``ρ(s) = c² log(1 + s / c²)``; Huber ``ρ(s) = s`` for ``s ≤ c²``, else ``2c√s − c²``.

    Args:
        r2: ``(*)`` squared residuals (any shape; numpy arrays are accepted too).
        loss: ``cauchy``, ``huber`` or ``squared``. scale: ``c``, where the loss bends.

    Returns:
        ``ρ (*)`` and ``ρ' (*)``, tensors of ``r2``'s shape.
    """
    r2 = torch.as_tensor(r2, dtype=torch.float64)
    c2 = scale * scale
    if loss == "cauchy":
        return c2 * torch.log1p(r2 / c2), 1.0 / (1.0 + r2 / c2)
    if loss == "huber":
        root = torch.sqrt(r2)
        inlier = r2 <= c2
        return torch.where(inlier, r2, 2 * scale * root - c2), torch.where(
            inlier, torch.ones_like(r2), scale / root.clamp_min(1e-12)
        )
    if loss == "squared":
        return r2, torch.ones_like(r2)
    raise ValueError(f"unknown loss {loss!r} (cauchy, huber or squared)")


def reprojection_jacobian(points_cam: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """``∂π(K, exp(δ) · q) / ∂δ`` at ``δ = 0``: ``(*, N, 2, 6)`` for ``points_cam q (*, N, 3)``.

    ``∂(exp(δ) q)/∂δ = [I | −[q]×]`` (translation first, as kornia's ``Se3``), chained with the
    pinhole derivative ``[[fx/z, s/z, −(fx x + s y)/z²], [0, fy/z, −fy y/z²]]``.

    Args:
        points_cam: ``(*, N, 3)`` points in the camera frame (``z > 0``). K: ``(3, 3)``.
    """
    q = torch.as_tensor(points_cam, dtype=torch.float64)
    K = torch.as_tensor(K, dtype=torch.float64)
    x, y, z = q.unbind(-1)
    fx, s, fy = K[0, 0], K[0, 1], K[1, 1]
    zero = torch.zeros_like(z)
    d_pi = torch.stack(
        [
            torch.stack([fx / z, s / z, -(fx * x + s * y) / z**2], -1),
            torch.stack([zero, fy / z, -fy * y / z**2], -1),
        ],
        -2,
    )  # (*, N, 2, 3)
    one = torch.ones_like(z)
    d_q = torch.stack(  # [I | −[q]×], −[q]× = [[0, z, −y], [−z, 0, x], [y, −x, 0]]
        [
            torch.stack([one, zero, zero, zero, z, -y], -1),
            torch.stack([zero, one, zero, -z, zero, x], -1),
            torch.stack([zero, zero, one, y, -x, zero], -1),
        ],
        -2,
    )  # (*, N, 3, 6)
    return d_pi @ d_q


def _residuals(
    T: torch.Tensor, points_lidar: torch.Tensor, uv_target: torch.Tensor, K: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """``π(K, T p) − ũ (N, 2)`` and the camera-frame points ``T p (N, 3)``."""
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
        NumericalError: fewer than 6 usable correspondences, points behind the camera at the
            start, or a non-finite cost (reported, never returned as a silently wrong estimate).
    """
    f64 = torch.float64
    p = torch.as_tensor(np.asarray(points_lidar), dtype=f64)
    target = torch.as_tensor(np.asarray(uv_target), dtype=f64)
    s = torch.as_tensor(np.asarray(weights), dtype=f64)
    if p.ndim != 2 or p.shape[1] != 3 or target.shape != (len(p), 2) or s.shape != (len(p),):
        raise ValueError(
            f"expected points (N, 3), uv (N, 2), weights (N,); got {tuple(p.shape)}, "
            f"{tuple(target.shape)}, {tuple(s.shape)}"
        )
    used = int(torch.count_nonzero(s > 0))
    if used < 6:
        raise NumericalError(f"refinement needs at least 6 weighted correspondences, got {used}")
    K = torch.as_tensor(np.asarray(K), dtype=f64)
    T = torch.as_tensor(np.asarray(T_init), dtype=f64)

    def evaluate(T: torch.Tensor) -> tuple[float, torch.Tensor, torch.Tensor, torch.Tensor]:
        r, q = _residuals(T, p, target, K)
        rho, w = robust_weight((r * r).sum(1), config.loss, config.loss_scale_px)
        return float((s * rho).sum()), r, q, s * w

    cost, r, q, w = evaluate(T)
    if bool((q[:, 2] <= 0).any()) or not np.isfinite(cost):
        raise NumericalError(
            "refinement: points lie behind the camera or the cost is not finite at the start"
        )
    initial_cost, lam, converged, iterations = cost, config.initial_damping, False, 0
    while iterations < config.max_iterations:
        iterations += 1
        J = reprojection_jacobian(q, K)
        H = torch.einsum("n,nai,naj->ij", w, J, J)
        g = torch.einsum("n,nai,na->i", w, J, r)
        delta = -torch.linalg.solve(H + lam * torch.diag(torch.diag(H)), g)
        T_new = se3_exp(delta) @ T
        new_cost, r_new, q_new, w_new = evaluate(T_new)
        if np.isfinite(new_cost) and new_cost < cost and bool((q_new[:, 2] > 0).all()):
            T, cost, r, q, w, lam = T_new, new_cost, r_new, q_new, w_new, max(lam / 10, 1e-12)
        else:
            lam *= 10
        if float(torch.linalg.norm(delta)) < config.step_tolerance:
            converged = True
            break
    J = reprojection_jacobian(q, K)
    H = torch.einsum("n,nai,naj->ij", w, J, J)
    dof = max(2 * used - 6, 1)
    covariance = torch.linalg.pinv(H) * float((w * (r * r).sum(1)).sum() / dof)
    return Refinement(T.numpy(), covariance.numpy(), iterations, cost, initial_cost, converged, r.numpy())
