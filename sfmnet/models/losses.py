"""Loss terms of the factorisation (method §5), in the models' dimensionless units.

Readings are divided by their RMS norm and loads by the load magnitude ``F``, so a relative
load error ``d`` costs about ``d^2`` in each term and one weight means the same for any sensor.
Every term is a sum over the rows it applies to divided by the batch's row count: each row
counts once, whichever terms apply to it.
"""

from __future__ import annotations

import torch


def reconstruction_loss(
    readings: torch.Tensor,
    motion: torch.Tensor,
    shape: torch.Tensor,
    offset: torch.Tensor,
    rows: torch.Tensor | None = None,
) -> torch.Tensor:
    """``sum_j |z_j - m_j S - o|^2 / b`` over the selected rows (paper eq. 5 with offsets).

    Args:
        readings: ``b x p``; motion: ``b x n``; shape: ``n x p``; offset: ``p``.
        rows: boolean ``b``, the rows to sum (default all).
    """
    residual = readings - motion @ shape - offset
    if rows is not None:
        residual = residual[rows]
    return residual.pow(2).sum() / len(readings)


def metric_constraint_loss(motion: torch.Tensor, constrained: torch.Tensor) -> torch.Tensor:
    """The metric constraint ``|m_j| = 1`` (loads in units of ``F``) as a loss: ``sum_j ((|m_j|^2 - 1) / 2)^2 / b``.

    Paper eq. 11 generalised (method §5); near the constraint each term is ``(|m_j| - 1)^2``.

    Args:
        motion: ``b x n``.
        constrained: boolean ``b``, the rows whose magnitude is ``F``.
    """
    violation = ((motion[constrained].pow(2).sum(dim=1) - 1) / 2).pow(2)
    return violation.sum() / len(motion)

