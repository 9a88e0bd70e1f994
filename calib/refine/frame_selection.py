"""Which frames Stage 4 uses: those that together constrain every direction of the extrinsic.

A frame's evidence lies on its occluding contours (the edges both sensors see). A contour sample
constrains the image coordinate across its edge: a depth jump along a scan line (a vertical image
edge) fixes ``u``, one between rings (a horizontal edge, a silhouette against the sky) fixes
``v``. So a frame's information about ``δ = (ρ, ω)`` is ``Σ_i J_iᵀ J_i`` with ``J_i`` that row of
the reprojection Jacobian, computed from the scan alone under the initial extrinsic (no image, no
matching). Frames are then chosen greedily to maximise ``log det`` of the summed information
(D-optimal design: the choice does not depend on the units of ``ρ`` and ``ω``, and a frame that
pins a direction the others leave loose gains the most).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from calib.match.contours import horizontal_edges, in_view, vertical_edges
from calib.refine.solver import reprojection_jacobian

__all__ = ["FrameSelectionConfig", "contour_information", "select_informative"]


class FrameSelectionConfig(BaseModel):
    """``selection:`` in ``calibrate.yaml``."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    method: Literal["spread", "information"] = Field(
        "information",
        description="spread: evenly over the sequence; information: the most informative of the candidates",
    )
    candidates: int = Field(
        3, ge=1, description="candidates looked at per frame used (spread evenly over the sequence)"
    )


def contour_information(
    points_lidar: np.ndarray,
    T_cam_lidar: np.ndarray,
    K: np.ndarray,
    image_size: tuple[int, int],
    T_cam_rig: np.ndarray | None = None,
) -> np.ndarray:
    """``(6, 6)`` information about ``δ = (ρ, ω)`` (metres, radians; camera frame, as the solver's
    ``exp(δ) · T``) from one scan's occluding contours in view, one pixel of noise each.

    Args:
        points_lidar: ``(N, 3+)`` the scan. T_cam_lidar: ``(4, 4)`` (a rig's ``T_rig_lidar``
            with ``T_cam_rig``: ``δ`` is then the rig's, in its frame, so that the information of
            its cameras adds up). K: ``(3, 3)``. image_size: ``(H, W)``.
        T_cam_rig: ``(4, 4)`` the camera's pose in its rig, or ``None``.
    """
    across_u = horizontal_edges(points_lidar)
    contours, silhouettes, _ = vertical_edges(points_lidar)
    across_v = np.concatenate([contours, silhouettes])
    T_cam = T_cam_lidar if T_cam_rig is None else T_cam_rig @ T_cam_lidar
    rig = None if T_cam_rig is None else torch.as_tensor(T_cam_rig)
    information = np.zeros((6, 6))
    for samples, row in ((across_u, 0), (across_v, 1)):
        seen = samples[in_view(samples, T_cam, K, image_size, 0.0)]
        q = seen @ T_cam_lidar[:3, :3].T + T_cam_lidar[:3, 3]  # the camera's frame, or the rig's
        J = reprojection_jacobian(torch.as_tensor(q), torch.as_tensor(K), rig)[:, row, :].numpy()
        information += J.T @ J
    return information


def select_informative(informations: Sequence[np.ndarray], count: int) -> list[int]:
    """Positions of ``count`` of the ``(6, 6)`` ``informations``, chosen one after another, each
    maximising ``log det`` of the chosen ones' sum (a tiny ridge, relative to the candidates' mean
    trace, keeps the first choices comparable while the sum is still singular)."""
    if count >= len(informations):
        return list(range(len(informations)))
    stack = np.asarray(informations, np.float64)
    ridge = 1e-9 * max(float(np.trace(stack.mean(0))), 1e-300) * np.eye(6)
    chosen: list[int] = []
    total = ridge
    for _ in range(count):
        scores = [
            -np.inf if i in chosen else np.linalg.slogdet(total + stack[i])[1] for i in range(len(stack))
        ]
        best = int(np.argmax(scores))
        chosen.append(best)
        total = total + stack[best]
    return sorted(chosen)
