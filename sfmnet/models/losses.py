"""Loss terms of the factorisation (NOTES 5), in the models' dimensionless units.

Readings are divided by their RMS norm and loads by the load magnitude ``F``, so a relative
load error ``d`` costs about ``d^2`` in each term and one weight means the same for any sensor.
Every term is a sum over the rows it applies to divided by the batch's row count: each row
counts once, whichever terms apply to it.
"""

from __future__ import annotations

import torch


def reconstruction_loss(
    readings: torch.Tensor, motion: torch.Tensor, shape: torch.Tensor, offset: torch.Tensor
) -> torch.Tensor:
    """``mean_j |z_j - m_j S - o|^2`` (paper eq. 5 with offsets).

    Args:
        readings: ``b x p``; motion: ``b x n``; shape: ``n x p``; offset: ``p``.
    """
    return (readings - motion @ shape - offset).pow(2).sum(dim=1).mean()


def metric_constraint_loss(motion: torch.Tensor, constrained: torch.Tensor) -> torch.Tensor:
    """The metric constraint ``|m_j| = 1`` (loads in units of ``F``) as a loss: ``sum_j ((|m_j|^2 - 1) / 2)^2 / b``.

    Paper eq. 11 generalised (NOTES 5); near the constraint each term is ``(|m_j| - 1)^2``.

    Args:
        motion: ``b x n``.
        constrained: boolean ``b``, the rows whose magnitude is ``F``.
    """
    violation = ((motion[constrained].pow(2).sum(dim=1) - 1) / 2).pow(2)
    return violation.sum() / len(motion)


def known_load_loss(motion: torch.Tensor, loads: torch.Tensor) -> torch.Tensor:
    """``sum_k |m_k - f_k|^2 / b`` over the rows whose load ``f_k`` is known, NaN elsewhere (NOTES 3).

    Args:
        motion: ``b x n``; loads: ``b x n``.
    """
    known = ~torch.isnan(loads).any(dim=1)
    return (motion[known] - loads[known]).pow(2).sum() / len(motion)
