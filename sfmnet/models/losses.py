"""Loss terms of the factorisation (NOTES 5). Each is dimensionless, so one weight means the same for any sensor."""

from __future__ import annotations

import torch


def reconstruction_loss(
    readings: torch.Tensor, motion: torch.Tensor, shape: torch.Tensor, offset: torch.Tensor, scale2: torch.Tensor
) -> torch.Tensor:
    """``mean_j |z_j - m_j S - o|^2 / scale2``.

    Args:
        readings: ``b x p``; motion: ``b x n``; shape: ``n x p``; offset: ``p``.
        scale2: mean squared norm of the centred readings, so that a relative load error
            ``d`` costs about ``d^2`` here as in :func:`metric_constraint_loss`.
    """
    residual = readings - motion @ shape - offset
    return residual.pow(2).sum(dim=1).mean() / scale2


def metric_constraint_loss(motion: torch.Tensor, magnitude: float) -> torch.Tensor:
    """The metric constraint ``|m_j| = F`` as a loss: ``mean_j ((|m_j|^2 - F^2) / (2 F^2))^2`` (eq. 11, NOTES 5).

    Near the constraint this is ``((|m_j| - F) / F)^2``: the squared relative magnitude error.

    Args:
        motion: ``b x n`` loads of the rows whose magnitude is ``F``.
        magnitude: ``F`` (load units).
    """
    if len(motion) == 0:
        return motion.new_zeros(())
    return ((motion.pow(2).sum(dim=1) - magnitude**2) / (2 * magnitude**2)).pow(2).mean()


def known_load_loss(motion: torch.Tensor, loads: torch.Tensor, scale: float) -> torch.Tensor:
    """``mean_k |m_k - f_k|^2 / scale^2`` over the rows whose load ``f_k`` is known (NOTES 3).

    Args:
        motion: ``k x n``; loads: ``k x n``; scale: a typical load magnitude.
    """
    if len(motion) == 0:
        return motion.new_zeros(())
    return (motion - loads).pow(2).sum(dim=1).mean() / scale**2
