"""The data loaders both training systems use: worker processes that stay alive between epochs,
and page-locked batches where a CUDA device will take them (copies overlap the GPU's work)."""

from __future__ import annotations

import os

import torch
from torch.utils.data import DataLoader, Dataset

__all__ = ["loader"]


def loader(dataset: Dataset, batch_size: int, workers: int) -> DataLoader:
    """A :class:`DataLoader` over ``dataset`` with ``workers`` processes (0: in the main one; -1:
    one per CPU core but one)."""
    if workers < 0:
        workers = max((os.cpu_count() or 1) - 1, 0)
    return DataLoader(
        dataset,
        batch_size=batch_size,
        num_workers=workers,
        persistent_workers=workers > 0,
        pin_memory=torch.cuda.is_available(),
    )
