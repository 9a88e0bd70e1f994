"""SE(3) helpers on kornia: compose, inverse, exp/log, calibration error and random perturbations.

Conventions (DESIGN.md): ``T_a_b`` is a ``(..., 4, 4)`` homogeneous transform mapping points from
frame ``b`` into frame ``a``. A twist ``xi = (rho, omega)`` is ``(..., 6)``, translation part first,
as in :class:`kornia.geometry.liegroup.Se3`. Every function broadcasts over leading dimensions.

kornia's ``Se3.log`` handles small angles (float64 gradcheck at the identity passes,
``tests/calib/test_geometry.py`` keeps asserting it), so it is used directly. The exponential is
written out in closed form instead (and tested against kornia's ``Se3.exp``): kornia builds a
quaternion and two group objects per call, about 5.7 ms whatever the batch, and Stage 4 calls it
about 1900 times per calibration (every solver step, every candidate batch of the global
search); the closed form took 1.1–1.4 ms for 1–12 twists, measured on the same loaded machine.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import torch
from kornia.geometry.liegroup import Se3, So3

__all__ = [
    "CalibrationError",
    "calibration_error",
    "kabsch",
    "perturb",
    "pose_error",
    "random_perturbation",
    "se3_adjoint",
    "se3_compose",
    "se3_exp",
    "se3_inverse",
    "se3_log",
    "so3_log",
    "twist_steps",
]


def _as_tensor(x: np.ndarray | torch.Tensor, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    return x.to(dtype) if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x), dtype=dtype)


def _grad_like(x: torch.Tensor) -> torch.set_grad_enabled:
    """kornia's ``So3`` keeps its quaternion as an ``nn.Parameter``, so its outputs require grad
    even for plain inputs; track gradients only when the input asks for them."""
    return torch.set_grad_enabled(torch.is_grad_enabled() and x.requires_grad)


def _check_transform(T: torch.Tensor, name: str) -> None:
    if T.shape[-2:] != (4, 4):
        raise ValueError(f"{name} must have shape (..., 4, 4), got {tuple(T.shape)}")


def se3_exp(xi: torch.Tensor) -> torch.Tensor:
    """Exponential map se(3) -> SE(3).

    Args:
        xi: twist ``(..., 6)``: translation part ``rho`` then rotation vector ``omega``.

    Returns:
        ``(..., 4, 4)`` homogeneous transforms.
    """
    if xi.shape[-1] != 6:
        raise ValueError(f"xi must have shape (..., 6), got {tuple(xi.shape)}")
    rho, omega = xi[..., :3], xi[..., 3:]
    theta2 = (omega * omega).sum(-1, keepdim=True)[..., None]  # (..., 1, 1)
    small = theta2 < 1e-8
    t2 = torch.where(small, torch.ones_like(theta2), theta2)  # safe: no 0/0 in either branch's grad
    t = torch.sqrt(t2)
    # R = I + a [ω]x + b [ω]x²,  V = I + b [ω]x + c [ω]x²  (Taylor series below θ = 1e-4)
    a = torch.where(small, 1 - theta2 / 6 + theta2**2 / 120, torch.sin(t) / t)
    b = torch.where(small, 0.5 - theta2 / 24 + theta2**2 / 720, (1 - torch.cos(t)) / t2)
    c = torch.where(small, 1 / 6 - theta2 / 120 + theta2**2 / 5040, (t - torch.sin(t)) / (t2 * t))
    wx, wy, wz = omega.unbind(-1)
    zero = torch.zeros_like(wx)
    W = torch.stack([zero, -wz, wy, wz, zero, -wx, -wy, wx, zero], -1).reshape(*omega.shape[:-1], 3, 3)
    W2 = W @ W
    eye = torch.eye(3, dtype=xi.dtype, device=xi.device)
    R = eye + a * W + b * W2
    V = eye + b * W + c * W2
    top = torch.cat([R, (V @ rho[..., None])], -1)  # (..., 3, 4)
    bottom = torch.zeros(*omega.shape[:-1], 1, 4, dtype=xi.dtype, device=xi.device)
    bottom[..., 0, 3] = 1.0
    return torch.cat([top, bottom], -2)


def se3_log(T: torch.Tensor) -> torch.Tensor:
    """Logarithm SE(3) -> se(3), the inverse of :func:`se3_exp`.

    Args:
        T: ``(..., 4, 4)`` homogeneous transforms with orthonormal rotation blocks.

    Returns:
        ``(..., 6)`` twists ``(rho, omega)``.
    """
    _check_transform(T, "T")
    with _grad_like(T):
        return Se3.from_matrix(T).log()


def so3_log(R: torch.Tensor) -> torch.Tensor:
    """Rotation vector of ``(..., 3, 3)`` rotation matrices, ``(..., 3)``, angle in radians."""
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"R must have shape (..., 3, 3), got {tuple(R.shape)}")
    with _grad_like(R):
        return So3.from_matrix(R).log()


def se3_inverse(T_a_b: torch.Tensor) -> torch.Tensor:
    """Closed-form inverse ``T_b_a`` of ``(..., 4, 4)`` rigid transforms."""
    _check_transform(T_a_b, "T_a_b")
    R_t = T_a_b[..., :3, :3].transpose(-1, -2)
    T_b_a = torch.zeros_like(T_a_b)
    T_b_a[..., :3, :3] = R_t
    T_b_a[..., :3, 3] = -(R_t @ T_a_b[..., :3, 3:4])[..., 0]
    T_b_a[..., 3, 3] = 1.0
    return T_b_a


def se3_adjoint(T_a_b: torch.Tensor) -> torch.Tensor:
    """``(..., 6, 6)`` adjoint of ``(..., 4, 4)`` rigid transforms for twists ``(ρ, ω)``:
    ``T · exp(ξ) = exp(Ad(T) ξ) · T``, so ``Ad(T_a_b)`` takes a twist in frame ``b`` to frame ``a``."""
    _check_transform(T_a_b, "T_a_b")
    with _grad_like(T_a_b):
        return Se3.from_matrix(T_a_b).adjoint()


def se3_compose(T_a_b: torch.Tensor, T_b_c: torch.Tensor) -> torch.Tensor:
    """``T_a_c = T_a_b · T_b_c``, broadcasting over leading dimensions."""
    _check_transform(T_a_b, "T_a_b")
    _check_transform(T_b_c, "T_b_c")
    return T_a_b @ T_b_c


def pose_error(
    T_est: torch.Tensor, T_ref: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Error of an estimate against a reference, as DESIGN.md (and MDPCalib) define it.

    ``E = T_ref⁻¹ · T_est``; translation error ``‖t(E)‖``; rotation error ``angle(R(E))``.

    Args:
        T_est: ``(..., 4, 4)`` estimated transforms.
        T_ref: ``(..., 4, 4)`` reference transforms.

    Returns:
        ``translation_cm (...)``, ``rotation_deg (...)``, and their per-axis components
        ``translation_xyz_cm (..., 3)`` (``t(E)``) and ``rotation_xyz_deg (..., 3)`` (the
        rotation vector of ``R(E)``), both in the reference frame's axes.
    """
    _check_transform(T_est, "T_est")
    _check_transform(T_ref, "T_ref")
    E = se3_compose(se3_inverse(T_ref), T_est)
    t_xyz_cm = E[..., :3, 3] * 100.0
    r_xyz_deg = torch.rad2deg(so3_log(E[..., :3, :3]))
    return t_xyz_cm.norm(dim=-1), r_xyz_deg.norm(dim=-1), t_xyz_cm, r_xyz_deg


@dataclass(frozen=True)
class CalibrationError:
    """Error of one extrinsic estimate against a reference (see :func:`pose_error`)."""

    translation_cm: float
    rotation_deg: float
    translation_xyz_cm: tuple[float, float, float]
    rotation_xyz_deg: tuple[float, float, float]

    def to_dict(self) -> dict:
        return asdict(self)

    def __str__(self) -> str:
        return f"{self.translation_cm:.3f} cm / {self.rotation_deg:.4f}°"


def calibration_error(T_est: np.ndarray | torch.Tensor, T_ref: np.ndarray | torch.Tensor) -> CalibrationError:
    """:func:`pose_error` of one ``(4, 4)`` estimate, in float64, as plain floats."""
    t, r, t_xyz, r_xyz = pose_error(_as_tensor(T_est), _as_tensor(T_ref))
    if t.ndim != 0:
        raise ValueError(f"calibration_error takes single (4, 4) transforms, got {tuple(t.shape)}")
    return CalibrationError(
        float(t),
        float(r),
        tuple(t_xyz.tolist()),
        tuple(r_xyz.tolist()),  # type: ignore[arg-type]
    )


def random_perturbation(
    translation_cm: float,
    rotation_deg: float,
    batch_shape: tuple[int, ...] = (),
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float64,
) -> torch.Tensor:
    """Random rigid transforms of exactly the given size, in uniformly random directions.

    The translation has norm ``translation_cm`` and the rotation angle ``rotation_deg``, about an
    axis drawn uniformly on the sphere (independent of the translation direction).

    Returns:
        ``(*batch_shape, 4, 4)`` transforms.
    """
    if translation_cm < 0 or rotation_deg < 0:
        raise ValueError(
            f"perturbation sizes must be non-negative, got {translation_cm} cm, {rotation_deg} deg"
        )
    directions = torch.randn(*batch_shape, 2, 3, generator=generator, dtype=dtype)
    directions = directions / directions.norm(dim=-1, keepdim=True)
    rotation = directions[..., 1, :] * math.radians(rotation_deg)
    translation = directions[..., 0, :] * (translation_cm / 100.0)
    T = torch.zeros(*batch_shape, 4, 4, dtype=dtype)
    with torch.no_grad():
        T[..., :3, :3] = So3.exp(rotation).matrix()
    T[..., :3, 3] = translation
    T[..., 3, 3] = 1.0
    return T


def kabsch(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``R (3, 3)`` minimising ``Σ ‖target_k − R source_k‖²`` over rotations (Kabsch): ``source,
    target (K, 3)``, already centred where a translation is fitted too."""
    U, _, Vt = np.linalg.svd(source.T @ target)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


def perturb(
    T_cam_lidar: np.ndarray,
    translation_cm: float,
    rotation_deg: float,
    generator: torch.Generator | None = None,
) -> np.ndarray:
    """Perturb an extrinsic so that its :func:`calibration_error` is exactly the given size.

    Returns ``T_cam_lidar · Δ`` with ``Δ`` from :func:`random_perturbation`, so that
    ``E = T_ref⁻¹ · T_est = Δ``.

    Args:
        T_cam_lidar: ``(4, 4)`` reference extrinsic.

    Returns:
        ``(4, 4)`` float64 perturbed extrinsic.
    """
    delta = random_perturbation(translation_cm, rotation_deg, generator=generator)
    return (se3_compose(_as_tensor(T_cam_lidar), delta)).numpy()


def twist_steps(rotation: float, translation: float) -> torch.Tensor:
    """± one step along each twist axis, the moves of a pattern search over SE(3).

    Args:
        rotation: step of each rotation axis (radians).
        translation: step of each translation axis (metres).

    Returns:
        ``(12, 6)`` float64 twists ``(rho, omega)`` (translation first, as :func:`se3_exp`): rows
        ``2k`` and ``2k + 1`` step axis ``k`` forwards and backwards, so ``[:6]`` are the
        translation moves and ``[6:]`` the rotation moves.
    """
    steps = torch.zeros(12, 6, dtype=torch.float64)
    for axis in range(6):
        size = translation if axis < 3 else rotation
        steps[2 * axis, axis], steps[2 * axis + 1, axis] = size, -size
    return steps
