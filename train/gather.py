"""Validation samples from every process of a distributed (DDP) run.

Under DDP each process validates its own share of the frames. A median or a correlation of the
shares is not the median or correlation of the whole, so the validation metrics are computed
from every process's samples gathered together (the same numbers on every process, so their
checkpoints agree); outside DDP the samples are returned as they are.
"""

from __future__ import annotations

import numpy as np
import torch.distributed as dist

__all__ = ["gathered"]


def gathered(part: np.ndarray) -> np.ndarray:
    """``part (C, N)`` of this process joined along ``N`` with every other process's, in rank order.

    Args:
        part: ``(C, N)`` samples (``N`` may differ between processes).

    Returns:
        ``(C, ΣN)`` under DDP, else ``part``.
    """
    if not (dist.is_available() and dist.is_initialized()) or dist.get_world_size() == 1:
        return part
    parts: list[np.ndarray | None] = [None] * dist.get_world_size()
    dist.all_gather_object(parts, part)
    return np.concatenate(parts, axis=1)
