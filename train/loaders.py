"""The data loaders both training systems use: worker processes that stay alive between epochs,
and page-locked batches where a CUDA device will take them (copies overlap the GPU's work)."""

from __future__ import annotations

import torch
from torch.utils.data import DataLoader, Dataset

__all__ = ["loader"]


def loader(dataset: Dataset, batch_size: int, workers: int) -> DataLoader:
    """A :class:`DataLoader` over ``dataset`` with ``workers`` processes (0: in the main one)."""
    return DataLoader(
        dataset,
        batch_size=batch_size,
        num_workers=workers,
        persistent_workers=workers > 0,
        pin_memory=torch.cuda.is_available(),
    )
