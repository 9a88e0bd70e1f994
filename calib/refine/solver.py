"""Stage 4: the weighted, robust SE(3) refinement of the extrinsic (the paper's Eq. 4).

``min_ΔT Σ_i s_i ρ(‖ũ_i − π(K, ΔT · T⁰ · p_i)‖²)`` over ``ΔT = exp(δ)``, ``δ = (ρ, ω) ∈ se(3)``
applied on the left (in the camera frame), by Levenberg–Marquardt on iteratively reweighted
normal equations with analytic Jacobians. Points may come from many frames at once: the
extrinsic is shared, only the camera intrinsics ``K`` must be common. The loop runs in torch
(float64) from end to end; numpy arrays are converted once at the entry and the exit.

With a :class:`TimeModel` the camera–LiDAR time offset ``δt`` is a seventh parameter: each
point ``q_i``, deskewed to its scan's stamp, is seen at the camera's time as
``p_i(δt) = exp(−δt ξ_f) q_i`` (:mod:`calib.motion`, ``ξ_f`` its scan's twist), and
``∂p_i/∂δt = −(ω_f × p_i + v_f)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from calib.errors import NumericalError
from calib.geometry import se3_exp

__all__ = [
    "RefineConfig",
    "Refinement",
    "TimeModel",
    "cluster_covariance",
    "refine_extrinsic",
    "reprojection_jacobian",
    "robust_weight",
]


class RefineConfig(BaseModel):
    """Robust loss and stopping rules of :func:`refine_extrinsic`."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    loss: Literal["cauchy", "huber", "squared"] = "cauchy"
    loss_scale_px: float = Field(2.0, gt=0, description="residual where the robust loss bends")
    max_iterations: int = Field(50, ge=1)
    step_tolerance: float = Field(
        1e-6,
        gt=0,
        description="stop when ‖δ‖ (m, rad; δt in ms) falls below this: a micrometre, a microradian",
    )
    initial_damping: float = Field(1e-3, gt=0, description="Levenberg–Marquardt λ at the start")
    covariance_cell_deg: float = Field(
        10.0,
        ge=0,
        description="result.json's covariance treats correspondences within one image cell of "
        "this size (view angle) of one frame as one cluster of correlated errors (a cluster-robust "
        "sandwich; the edge matcher smooths its flow over about 10° at full resolution, so "
        "neighbouring residuals share their errors); 0: independent residuals, the normal "
        "equations' inverse. The online filter always takes the independent one (its measurement "
        "floor is set for it)",
    )
    noise_floor_px: float = Field(
        0.5,
        gt=0,
        description="the residual scale the time offset's std assumes at least (exact residuals "
        "would make any δt look certain, however weakly the motion excites it)",
    )


@dataclass(frozen=True)
class Refinement:
    """Result of :func:`refine_extrinsic`.

    Attributes:
        T_cam_lidar: ``(4, 4)`` the estimate ``exp(δ*) · T⁰``.
        covariance: ``(6, 6)`` of ``δ = (ρ, ω)`` about the estimate (metres, radians), from the
            final normal equations scaled by the residual variance (independent residuals).
        iterations: accepted and rejected LM steps taken. cost, initial_cost: the objective.
        converged: the step fell below the tolerance before ``max_iterations``.
        residuals: ``(N, 2)`` pixels ``π(K, T p_i) − ũ_i`` at the estimate.
        time_offset_s: ``δt`` at the estimate, with a :class:`TimeModel` (else ``None``).
        time_offset_std_s: its standard deviation with the extrinsic marginalised out (residual
            scale at least ``config.noise_floor_px``; ``inf`` where the motion cannot tell ``δt``
            from a translation); ``None`` when ``δt`` was held fixed.
        cell_covariance: ``(6, 6)`` as ``covariance``, the cluster-robust sandwich over the
            ``clusters`` given (:func:`cluster_covariance`); ``None`` without them.
    """

    T_cam_lidar: np.ndarray
    covariance: np.ndarray
    iterations: int
    cost: float
    initial_cost: float
    converged: bool
    residuals: np.ndarray
    time_offset_s: float | None = None
    time_offset_std_s: float | None = None
    cell_covariance: np.ndarray | None = None


@dataclass(frozen=True)
class TimeModel:
    """The camera–LiDAR time offset as a parameter (see the module docstring).

    Attributes:
        scan: ``(N,)`` int, which scan each point belongs to (an index into ``twists``).
        twists: ``(F, 2, 6)`` each scan's twist before and after its stamp
            (:class:`~calib.motion.ScanMotion`).
        offset_s: ``δt`` at the start (camera time minus LiDAR stamp).
        estimate: fit ``δt``; ``False`` holds it at ``offset_s``.
    """

    scan: np.ndarray
    twists: np.ndarray
    offset_s: float = 0.0
    estimate: bool = True


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


def pinhole_jacobian(points_cam: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """``∂π(K, q) / ∂q = [[fx/z, s/z, −(fx x + s y)/z²], [0, fy/z, −fy y/z²]]``: ``(*, N, 2, 3)``
    for ``points_cam q (*, N, 3)`` (``z > 0``) and ``K (3, 3)``, or ``(N, 3, 3)`` one per point."""
    q = torch.as_tensor(points_cam, dtype=torch.float64)
    K = torch.as_tensor(K, dtype=torch.float64)
    x, y, z = q.unbind(-1)
    fx, s, fy = K[..., 0, 0], K[..., 0, 1], K[..., 1, 1]
    zero = torch.zeros_like(z)
    return torch.stack(
        [
            torch.stack([fx / z, s / z, -(fx * x + s * y) / z**2], -1),
            torch.stack([zero, fy / z, -fy * y / z**2], -1),
        ],
        -2,
    )


def reprojection_jacobian(
    points: torch.Tensor, K: torch.Tensor, T_cam_rig: torch.Tensor | None = None
) -> torch.Tensor:
    """``∂π(K, exp(δ) · q) / ∂δ`` at ``δ = 0``: ``(*, N, 2, 6)`` for ``points q (*, N, 3)`` in the
    camera frame (``z > 0``); with ``T_cam_rig`` (``(N, 4, 4)`` one per point, or one ``(4, 4)``),
    ``∂π(K, T_cam_rig · exp(δ) · q) / ∂δ`` for points in a rig's frame (``δ`` a move of the rig).

    ``∂(exp(δ) q)/∂δ = [I | −[q]×]`` (translation first, as kornia's ``Se3``), chained with
    :func:`pinhole_jacobian` (by the rig's rotation first): a row ``a`` of ``∂π/∂q`` becomes
    ``(a, q × a)``.

    Args:
        points: ``(*, N, 3)``. K: ``(3, 3)``, or ``(N, 3, 3)`` each point's camera's.
    """
    q = torch.as_tensor(points, dtype=torch.float64)
    if T_cam_rig is None:
        d_q = pinhole_jacobian(q, K)  # (*, N, 2, 3)
    else:
        R = torch.as_tensor(T_cam_rig, dtype=torch.float64)[..., :3, :3]
        q_cam = (R @ q[..., None])[..., 0] + torch.as_tensor(T_cam_rig, dtype=torch.float64)[..., :3, 3]
        d_q = pinhole_jacobian(q_cam, K) @ R
    # each row a of ∂π/∂q times [I | −[q]×]: (a, aᵀ(−[q]×)) = (a, q × a)
    return torch.cat([d_q, torch.linalg.cross(q[..., None, :].expand_as(d_q), d_q)], -1)


def _at_camera_time(
    points: torch.Tensor, time: TimeModel | None, scan: torch.Tensor | None, offset: float
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Points in the LiDAR frame at the camera's time ``(N, 3)`` and ``∂p/∂δt (N, 3)``
    (``points`` unchanged and ``None`` without a time model); ``scan (N,)`` is ``time.scan`` as a
    tensor."""
    if time is None or scan is None:
        return points, None
    twists = torch.as_tensor(time.twists[:, 1 if offset >= 0 else 0], dtype=torch.float64)  # (F, 6)
    A = se3_exp(-offset * twists)[scan]  # exp(−δt ξ_f) per point, (N, 4, 4)
    p = torch.einsum("nij,nj->ni", A[:, :3, :3], points) + A[:, :3, 3]
    xi = twists[scan]
    return p, -(torch.linalg.cross(xi[:, 3:], p) + xi[:, :3])


def _normal_equations(w: torch.Tensor, J: torch.Tensor, r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``H = Σ w Jᵀ J (P, P)`` and ``g = Σ w Jᵀ r (P,)`` for ``w (N,)``, ``J (N, 2, P)``, ``r (N, 2)``
    (as one matrix product over the ``2N`` rows: a three-operand einsum is about 1.5x slower)."""
    rows = J.reshape(-1, J.shape[-1])
    weighted = rows * w.repeat_interleave(2)[:, None]
    return weighted.T @ rows, weighted.T @ r.reshape(-1)


def cluster_covariance(
    H: torch.Tensor, w: torch.Tensor, J: torch.Tensor, r: torch.Tensor, clusters: torch.Tensor
) -> torch.Tensor:
    """The cluster-robust (sandwich) covariance ``H⁻¹ (Σ_c g_c g_cᵀ) H⁻¹ · C / (C − 1)`` of a
    weighted least-squares estimate, with ``g_c = Σ_{i∈c} w_i J_iᵀ r_i`` each cluster's share of
    the gradient (Liang and Zeger 1986): residuals within a cluster may be correlated in any way,
    clusters are independent. With one residual per cluster and a constant weight it is White's
    heteroscedasticity-consistent estimate.

    Args:
        H: ``(P, P)`` the normal matrix ``Σ w Jᵀ J``. w: ``(N,)``. J: ``(N, 2, P)``. r: ``(N, 2)``.
        clusters: ``(N,)`` int ids.
    """
    ids, inverse = torch.unique(clusters, return_inverse=True)
    per_point = torch.einsum("n,nkp,nk->np", w, J, r)
    g = torch.zeros(len(ids), J.shape[-1], dtype=J.dtype).index_add_(0, inverse, per_point)
    bread = torch.linalg.pinv(H)
    return bread @ (g.T @ g) @ bread * (len(ids) / max(len(ids) - 1, 1))


def refine_extrinsic(
    points_lidar: np.ndarray,
    uv_target: np.ndarray,
    weights: np.ndarray,
    K: np.ndarray,
    T_init: np.ndarray,
    config: RefineConfig = RefineConfig(),
    time: TimeModel | None = None,
    clusters: np.ndarray | None = None,
    T_cam_rig: np.ndarray | None = None,
) -> Refinement:
    """Minimise Eq. 4 over ``ΔT`` (and ``δt`` with ``time``) starting at ``T_init``.

    Args:
        points_lidar: ``(N, 3)`` points (with ``time``: deskewed to their scan's stamp).
        uv_target: ``(N, 2)`` matched pixels ``ũ_i``. weights: ``(N,)`` non-negative ``s_i``.
        K: ``(3, 3)``, or ``(N, 3, 3)`` each point's camera's. T_init: ``(4, 4)`` ``T⁰_cam_lidar``
            (a rig's ``T⁰_rig_lidar`` with ``T_cam_rig``). time: the time offset's model.
        clusters: ``(N,)`` int, correspondences whose errors are correlated share an id: the
            result's ``cell_covariance`` is then the cluster-robust sandwich
            (:func:`cluster_covariance`).
        T_cam_rig: ``(N, 4, 4)`` each point's camera in a rig: the point projects through
            ``T_cam_rig · T``, and ``T`` (with its covariance) is the rig's ``T_rig_lidar``.

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
    if time is not None and (time.scan.shape != (len(p),) or time.twists.shape[1:] != (2, 6)):
        raise ValueError(
            f"time model needs scan (N,) = ({len(p)},) and twists (F, 2, 6); got "
            f"{time.scan.shape} and {time.twists.shape}"
        )
    used = int(torch.count_nonzero(s > 0))
    if used < 6:
        raise NumericalError(f"refinement needs at least 6 weighted correspondences, got {used}")
    K = torch.as_tensor(np.asarray(K), dtype=f64)
    if K.shape not in ((3, 3), (len(p), 3, 3)):
        raise ValueError(f"expected K (3, 3) or ({len(p)}, 3, 3), got {tuple(K.shape)}")
    rig = None if T_cam_rig is None else torch.as_tensor(np.asarray(T_cam_rig), dtype=f64)
    if rig is not None and rig.shape != (len(p), 4, 4):
        raise ValueError(f"expected T_cam_rig ({len(p)}, 4, 4), got {tuple(rig.shape)}")
    T = torch.as_tensor(np.asarray(T_init), dtype=f64)
    offset = time.offset_s if time is not None else 0.0
    scan = torch.as_tensor(time.scan) if time is not None else None
    n_params = 7 if time is not None and time.estimate else 6

    # a held δt moves every point once, not at every evaluation
    held = _at_camera_time(p, time, scan, offset) if n_params == 6 else None

    def evaluate(
        T: torch.Tensor, offset: float
    ) -> tuple[float, torch.Tensor, torch.Tensor, Callable[[], torch.Tensor]]:
        """Cost, residuals ``(N, 2)``, IRLS weights ``(N,)`` and a function giving the Jacobian
        ``(N, 2, n_params)`` there (made only for a step that is taken)."""
        points, d_offset = held if held is not None else _at_camera_time(p, time, scan, offset)
        q_rig = points @ T[:3, :3].T + T[:3, 3]  # the camera's frame, or the rig's
        q = q_rig if rig is None else torch.einsum("nij,nj->ni", rig[:, :3, :3], q_rig) + rig[:, :3, 3]
        uvw = q @ K.T if K.ndim == 2 else torch.einsum("nij,nj->ni", K, q)
        r = uvw[:, :2] / uvw[:, 2:3] - target
        rho, w = robust_weight((r * r).sum(1), config.loss, config.loss_scale_px)

        def jacobian() -> torch.Tensor:
            J = reprojection_jacobian(q_rig, K, rig)
            if n_params == 7:  # ∂π/∂δt = ∂π/∂q_rig · R · ∂p/∂δt (∂π/∂q_rig: the first 3 columns)
                J = torch.cat([J, J[..., :3] @ (d_offset @ T[:3, :3].T)[:, :, None]], -1)
            return J

        if bool((q[:, 2] <= 0).any()):
            return math.inf, r, w, jacobian
        return float((s * rho).sum()), r, s * w, jacobian

    cost, r, w, jacobian = evaluate(T, offset)
    if not math.isfinite(cost):
        raise NumericalError(
            "refinement: points lie behind the camera or the cost is not finite at the start"
        )
    J = jacobian()
    initial_cost, lam, converged, iterations = cost, config.initial_damping, False, 0
    while iterations < config.max_iterations:
        iterations += 1
        H, g = _normal_equations(w, J, r)
        delta = -torch.linalg.solve(H + lam * torch.diag(torch.diag(H)), g)
        T_new = se3_exp(delta[:6]) @ T
        offset_new = offset + float(delta[6]) if n_params == 7 else offset
        new_cost, r_new, w_new, jacobian = evaluate(T_new, offset_new)
        if math.isfinite(new_cost) and new_cost < cost:
            T, offset, cost, r, w, J = T_new, offset_new, new_cost, r_new, w_new, jacobian()
            lam = max(lam / 10, 1e-12)
        else:
            lam *= 10
        # δt in seconds is small beside metres and radians: its step counts in milliseconds
        step = delta * torch.tensor([1.0] * 6 + [1e3] * (n_params - 6), dtype=f64)
        if float(torch.linalg.norm(step)) < config.step_tolerance:
            converged = True
            break
    H, _ = _normal_equations(w, J, r)
    dof = max(2 * used - n_params, 1)
    variance = float((w * (r * r).sum(1)).sum() / dof)
    covariance = torch.linalg.pinv(H) * variance
    cells = (
        None
        if clusters is None
        else cluster_covariance(H, w, J, r, torch.as_tensor(np.asarray(clusters)))[:6, :6].numpy()
    )
    offset_std = None
    if n_params == 7:  # δt's information once the extrinsic is marginalised out (Schur complement)
        information = float(H[6, 6] - H[6, :6] @ torch.linalg.lstsq(H[:6, :6], H[:6, 6:]).solution[:, 0])
        # the floor in pixels, in the units of the weighted variance (which carries the weights'
        # mean: support weights are not normalised)
        scale = max(variance, config.noise_floor_px**2 * float(2 * w.sum()) / dof)
        offset_std = math.sqrt(scale / information) if information > 1e-12 * float(H[6, 6]) else math.inf
    return Refinement(
        T.numpy(),
        covariance[:6, :6].numpy(),
        iterations,
        cost,
        initial_cost,
        converged,
        r.numpy(),
        offset if time is not None else None,
        offset_std,
        cells,
    )
