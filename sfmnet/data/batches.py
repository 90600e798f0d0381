"""Loaders that serve in-memory tensors in batches without copying them row by row."""

from __future__ import annotations

from torch.utils.data import BatchSampler, DataLoader, RandomSampler, TensorDataset


def batch_loader(dataset: TensorDataset, batch_size: int | None) -> DataLoader:
    """Batches of ``dataset`` taken by whole-tensor indexing, not gathered row by row and stacked.

    ``batch_size`` None: one batch, the tensors themselves (a slice: no copy); else shuffled minibatches.
    """
    if batch_size is None:
        return DataLoader(dataset, sampler=[slice(0, len(dataset))], batch_size=None)
    return DataLoader(dataset, sampler=BatchSampler(RandomSampler(dataset), batch_size, drop_last=False), batch_size=None)
