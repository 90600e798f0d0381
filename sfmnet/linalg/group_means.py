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


def harmonic_mean_rows(counts: torch.Tensor) -> float:
    """The rows behind a typical tied direction: the harmonic mean of ``counts`` (``K``, rows per pose), so that one
    pose of thousands among many of three leaves most directions resting on three rows (the plain mean would call
    them sharp). A pose mean's SNR is ``sqrt`` of it times a row's (method §5)."""
    return float(len(counts) / (1 / counts.to(torch.float64)).sum())
