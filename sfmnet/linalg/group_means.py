"""Means of rows by group (poses, static intervals)."""

from __future__ import annotations

import torch


def group_means(values: torch.Tensor, groups: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each group's mean row.

    Args:
        values: ``f x c``; groups: ``f`` (long), any labels.

    Returns:
        ``means`` (``K x c``, groups in sorted label order), ``index`` (``f``, each row's group
        position) and ``counts`` (``K``, rows per group).
    """
    _, index, counts = torch.unique(groups, return_inverse=True, return_counts=True)
    sums = torch.zeros(len(counts), values.shape[1], dtype=values.dtype).index_add_(0, index, values)
    return sums / counts[:, None].to(values.dtype), index, counts
