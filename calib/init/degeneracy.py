"""Whether the motion determined Stage 1's rotation: three numerical tests, and a refusal.

Every motion pair obeys ``A_k X = X B_k`` (``X = T_cam_lidar``). Rotation: ``ω_A,k = R_X ω_B,k``
for the rotation vectors, so two pairs turning about non-parallel axes fix ``R_X`` (Tsai–Lenz,
Park–Martin). A ground vehicle turns about one axis, its vertical ``n``: the axes then fix two of
the three angles, and the rotation about ``n`` rests on the camera's translation directions,
``s_k â_k = R_X t_B,k − (R_A,k − I) t_X``. Those cannot fix it on a circular arc (a headland
U-turn): every LiDAR motion is then a rotation about the same vertical line through the turn's
centre, so a rotation ``C`` about that line commutes with every ``B_k`` and
``A_k (X C) = X B_k C = (X C) B_k``: ``X C`` explains the motion as well as ``X`` does, for any
angle (the rotation about the vertical is traded against ``t_X``; only straight stretches, weave
or uneven ground break the tie). Three numbers:

1. **Axis spread** ``σ₂ / σ₁`` of the stacked, angle-weighted LiDAR rotation axes ``ω_B,k``
   (``(K, 3)``): 0 when every axis is parallel (planar motion), of order 1 when they span 3D.
   At least ``min_axis_spread``, the axes alone fix the rotation; below it, the rotation about the
   common axis leans on the translation directions (as it does for every ground vehicle). It
   explains a refusal, it does not make one: planar driving with straights and turns is fine.
2. **Conditioning**: the rotation block of the hand–eye system's information with the
   translation and the scales marginalised (Schur complement) and the prior on ``t_X`` left out,
   ``Λ_R = I_RR − I_Rt I_tt⁺ I_tR`` (``(3, 3)``, σ-normalised residuals, so at the noise the
   ``hand_eye`` config expects): its weakest direction's standard deviation ``1 / √λ_min(Λ_R)``
   in degrees (refused above ``max_rotation_std_deg``) and its condition number
   ``√(λ_max / λ_min)``. The circular arc above gives ``λ_min = 0``.
3. **Agreement of robust subsets**: the robust solve repeated on ``subsets`` random halves of the
   pairs (each half gets half of the rotating pairs); the RMS angle between a half's rotation and
   the full one. With independent noise a half has twice the full solve's variance, so
   ``E‖R_half ⊖ R_full‖² = 2σ² − σ² = σ²``: the RMS estimates the full rotation's own error from
   the data's scatter, whatever the noise model says (refused above ``max_subset_spread_deg``).

Test 2 catches what the motion cannot give at the expected noise; test 3 what the data's own
scatter leaves loose. Neither sees a bias every pair shares (halves of an arc agree on the same
wrong answer), which is why test 2 reads the geometry, not the residuals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial.transform import Rotation

from calib.init.hand_eye import HandEyeConfig, HandEyeResult, UnobservableError, refine_hand_eye

__all__ = [
    "DegenerateMotionError",
    "DegeneracyConfig",
    "MotionDiagnostics",
    "axis_spread",
    "check_motion",
    "diagnose",
    "rotation_conditioning",
    "subset_spread",
]

AXES = ("x", "y", "z")
SUBSET_EVALUATIONS = 50
"""Residual evaluations each half's refinement may take (see :func:`subset_spread`)."""


class DegenerateMotionError(UnobservableError):
    """The motion pairs do not determine the rotation: the message names the failed test, its value
    and its threshold; ``diagnostics`` holds every number."""

    def __init__(self, message: str, diagnostics: MotionDiagnostics | None = None):
        super().__init__(message)
        self.diagnostics = diagnostics


class DegeneracyConfig(BaseModel):
    """``degeneracy:`` in ``configs/init_calib.yaml``: when Stage 1 refuses instead of returning."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    refuse: bool = Field(True, description="refuse a rotation the tests find undetermined (false: report)")
    min_axis_spread: float = Field(
        0.05,
        ge=0,
        le=1,
        description="σ2/σ1 of the rotation axes below which they are parallel and the rotation about "
        "them rests on the camera's translation directions (explains a refusal, makes none)",
    )
    max_rotation_std_deg: float = Field(
        1.3,
        gt=0,
        description="refuse when the weakest rotation direction's std (translation and scales free, "
        "no prior, at the hand_eye sigmas) exceeds this",
    )
    subsets: int = Field(8, ge=0, description="random halves of the pairs solved again (0: no subset test)")
    max_subset_spread_deg: float = Field(
        1.75,
        gt=0,
        description="refuse when the halves' rotations differ from the full one by more (RMS, an "
        "estimate of the full rotation's own std)",
    )
    seed: int = Field(0, ge=0, description="seed of the random halves")


@dataclass(frozen=True)
class MotionDiagnostics:
    """The three tests' numbers (see the module docstring).

    Attributes:
        pairs, rotating: motion pairs, and those rotating enough for the closed-form rotation.
        axis_spread: ``σ₂ / σ₁`` of the rotating pairs' LiDAR rotation vectors.
        common_axis_lidar: ``(3,)`` their dominant axis (unit, LiDAR frame).
        rotation_std_deg: std of the weakest rotation direction (∞: unobservable).
        rotation_condition: ``√(λ_max / λ_min)`` of the marginal rotation information.
        weakest_axis_lidar: ``(3,)`` that direction, a rotation axis in the LiDAR frame.
        subset_spread_deg: RMS angle of the halves' rotations from the full one (NaN: not run).
        subset_max_deg: the largest of those angles (NaN: not run).
        subsets_solved: halves that could be solved.
        failed: the failed tests' one-line reasons (empty: the rotation is determined).
    """

    pairs: int
    rotating: int
    axis_spread: float
    common_axis_lidar: np.ndarray
    rotation_std_deg: float
    rotation_condition: float
    weakest_axis_lidar: np.ndarray
    subset_spread_deg: float
    subset_max_deg: float
    subsets_solved: int
    failed: list[str]

    def to_dict(self) -> dict:
        """JSON-ready values (``None`` for a test not run, ``"inf"`` for an unbounded std)."""

        def number(v: float) -> float | str | None:
            return None if np.isnan(v) else ("inf" if np.isinf(v) else float(v))

        return {
            "pairs": self.pairs,
            "rotating_pairs": self.rotating,
            "axis_spread": number(self.axis_spread),
            "common_axis_lidar": self.common_axis_lidar.tolist(),
            "rotation_std_deg": number(self.rotation_std_deg),
            "rotation_condition": number(self.rotation_condition),
            "weakest_axis_lidar": self.weakest_axis_lidar.tolist(),
            "subset_spread_deg": number(self.subset_spread_deg),
            "subset_max_deg": number(self.subset_max_deg),
            "subsets_solved": self.subsets_solved,
            "determined": not self.failed,
            "failed": list(self.failed),
        }


def _signed(axis: np.ndarray) -> np.ndarray:
    """``axis`` with its largest component positive (an axis has no sign)."""
    return axis * np.sign(axis[np.argmax(np.abs(axis))])


def _axis_name(axis_lidar: np.ndarray) -> str:
    """``LiDAR +z`` for an axis within 25° of one, else the rounded direction."""
    best = int(np.argmax(np.abs(axis_lidar)))
    if abs(axis_lidar[best]) > np.cos(np.radians(25)):
        return f"LiDAR +{AXES[best]}"
    return f"LiDAR direction {np.round(axis_lidar, 2).tolist()}"


def axis_spread(omega: np.ndarray) -> tuple[float, np.ndarray]:
    """How far the rotation axes spread, from the angle-weighted axes (rotation vectors).

    Args:
        omega: ``(K, 3)`` rotation vectors, radians.

    Returns:
        ``σ₂ / σ₁`` of ``omega`` (0: all parallel or fewer than two; 1: spread evenly in a plane or
        in space) and the dominant axis ``(3,)`` (unit; zeros when nothing rotates).
    """
    omega = np.asarray(omega, np.float64).reshape(-1, 3)
    if len(omega) == 0 or not np.any(omega):
        return 0.0, np.zeros(3)
    _, singular, Vt = np.linalg.svd(omega, full_matrices=False)
    spread = float(singular[1] / singular[0]) if len(singular) > 1 else 0.0
    return spread, _signed(Vt[0])


def rotation_conditioning(information: np.ndarray) -> tuple[float, float, np.ndarray]:
    """The rotation's weakest direction from the ``(6, 6)`` information of (rotation, translation).

    ``Λ_R = I_RR − I_Rt I_tt⁺ I_tR`` marginalises the translation (pseudo-inverse: a translation
    direction nothing constrains, the vertical under planar motion, drops out).

    Returns:
        std of the weakest direction (degrees; ∞ when unconstrained), ``√(λ_max / λ_min)`` (∞
        likewise) and that direction ``(3,)`` in the information's frame.
    """
    info = 0.5 * (information + information.T)
    marginal = info[:3, :3] - info[:3, 3:] @ np.linalg.pinv(info[3:, 3:], hermitian=True) @ info[3:, :3]
    values, vectors = np.linalg.eigh(0.5 * (marginal + marginal.T))
    if values[-1] <= 0 or values[0] <= 1e-12 * values[-1]:
        return np.inf, np.inf, vectors[:, 0]
    return float(np.degrees(1 / np.sqrt(values[0]))), float(np.sqrt(values[-1] / values[0])), vectors[:, 0]


def _halves(rotating: np.ndarray, count: int, rng: np.random.Generator) -> list[np.ndarray]:
    """``count`` boolean masks, each half of the rotating and half of the other pairs."""
    masks = []
    for _ in range(count):
        mask = np.zeros(len(rotating), bool)
        for group in (np.flatnonzero(rotating), np.flatnonzero(~rotating)):
            mask[rng.permutation(group)[: len(group) // 2]] = True
        masks.append(mask)
    return masks


def subset_spread(
    A: np.ndarray,
    B: np.ndarray,
    full: HandEyeResult,
    config: HandEyeConfig,
    count: int,
    seed: int = 0,
) -> tuple[float, float, int]:
    """How much the robust solve's rotation moves when half the pairs are left out.

    Each half is refined from the full solution (its rotation, translation and the half's scales)
    for at most :data:`SUBSET_EVALUATIONS` residual evaluations: the rotation settles within a few
    hundredths of a degree of the half's own optimum long before ``t_X`` stops creeping along the
    flat valley a monocular, mostly planar motion leaves it (measured on synthetic drives), and a
    cold start would only add the closed form's own scatter.

    Args:
        A, B: ``(K, 4, 4)`` the motion pairs (as :func:`hand_eye` takes them).
        full: the solve from every pair (``used`` marks the rotating pairs; each half gets half).
        count: how many random halves.

    Returns:
        RMS and largest angle (degrees) between a half's rotation and the full one (NaN when not
        run: ``count`` 0 or fewer than ``2 · min_pairs`` rotating pairs), and how many halves.
    """
    if count == 0 or full.used.sum() < 2 * config.min_pairs:
        return np.nan, np.nan, 0
    R_full = full.T_cam_lidar[:3, :3]
    angles = []
    for mask in _halves(full.used, count, np.random.default_rng(seed)):
        half = refine_hand_eye(
            A[mask], B[mask], full.T_cam_lidar, full.scales[mask], config, SUBSET_EVALUATIONS
        )
        R_half = half.T_cam_lidar[:3, :3]
        angles.append(np.degrees(np.linalg.norm(Rotation.from_matrix(R_half @ R_full.T).as_rotvec())))
    angles_deg = np.asarray(angles)
    return float(np.sqrt(np.mean(angles_deg**2))), float(angles_deg.max()), len(angles)


def diagnose(
    A: np.ndarray,
    B: np.ndarray,
    result: HandEyeResult,
    hand_eye_config: HandEyeConfig,
    config: DegeneracyConfig | None = None,
) -> MotionDiagnostics:
    """The three tests on the pairs ``A, B`` (``(K, 4, 4)``) that gave ``result``.

    ``config`` (default: :class:`DegeneracyConfig`'s defaults) sets the thresholds; the failed tests'
    reasons go into ``failed``, nothing is raised (:func:`check_motion` does that).
    """
    config = config or DegeneracyConfig()
    R_X = result.T_cam_lidar[:3, :3]
    omega_B = Rotation.from_matrix(B[result.used, :3, :3]).as_rotvec()
    spread, common = axis_spread(omega_B)
    std, condition, weakest_cam = rotation_conditioning(result.information)
    weakest = _signed(R_X.T @ weakest_cam)  # the camera-frame axis in the LiDAR frame
    rms, largest, solved = subset_spread(A, B, result, hand_eye_config, config.subsets, config.seed)
    failed = []
    if std > config.max_rotation_std_deg:
        why = (
            f"every motion turns about {_axis_name(common)} (axis spread {spread:.3f} < "
            f"{config.min_axis_spread:g}), so only the camera's translation directions fix the "
            "rotation about it"
            if spread < config.min_axis_spread
            else "the motion pairs hardly constrain it"
        )
        size = "unbounded" if np.isinf(std) else f"{std:.2f}°"
        failed.append(
            f"rotation about {_axis_name(weakest)} undetermined: std {size} > "
            f"{config.max_rotation_std_deg:g}° (max_rotation_std_deg; {why})"
        )
    if rms > config.max_subset_spread_deg:  # NaN (not run) compares False
        failed.append(
            f"halves of the motion disagree: their rotations differ from the full solve's by "
            f"{rms:.2f}° RMS (up to {largest:.1f}°) > {config.max_subset_spread_deg:g}° "
            "(max_subset_spread_deg)"
        )
    return MotionDiagnostics(
        pairs=len(A),
        rotating=int(result.used.sum()),
        axis_spread=spread,
        common_axis_lidar=common,
        rotation_std_deg=std,
        rotation_condition=condition,
        weakest_axis_lidar=weakest,
        subset_spread_deg=rms,
        subset_max_deg=largest,
        subsets_solved=solved,
        failed=failed,
    )


def check_motion(diagnostics: MotionDiagnostics, config: DegeneracyConfig, where: str = "") -> None:
    """Raise :class:`DegenerateMotionError` when a test failed and ``config.refuse`` is on.

    Raises:
        DegenerateMotionError: one line: what failed, its number against its threshold, and what
            to do.
    """
    if diagnostics.failed and config.refuse:
        prefix = f"{where}: " if where else ""
        raise DegenerateMotionError(
            f"{prefix}Stage 1 refuses the rotation from this motion: {'; '.join(diagnostics.failed)}. "
            "Drive longer, with straight stretches between turns (or over uneven ground), "
            "or use --init file:PATH.",
            diagnostics,
        )
