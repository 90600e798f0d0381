"""The motion of each sample given the shape: the inner problem of variable projection (method §5)."""

from __future__ import annotations

import torch


@torch.no_grad()
def constrained_motion(
    readings: torch.Tensor, shape: torch.Tensor, metric_weight: float, iterations: int = 80
) -> torch.Tensor:
    """Per row, the global ``argmin_m |z - m S|^2 + w ((|m|^2 - 1) / 2)^2`` (loads in units of ``F``).

    With ``w = 0`` this is the least-squares projection ``z pinv(S)``; as ``w`` grows the rows
    are pulled onto the unit sphere, the metric constraint. Stationarity reads
    ``(G + s I) m = S z^T`` with ``G = S S^T`` and ``s = w (|m|^2 - 1) / 2``; in the eigenbasis
    of ``G`` (eigenvalues ``g_i``, ``c = V^T S z^T``) that is one equation in ``s``,

        phi(s) = s - w/2 (sum_i c_i^2 / (g_i + s)^2 - 1) = 0,

    increasing on ``s > -g_min``, so it has one root there and it gives the global minimum
    (as for the trust-region subproblem). It is found by bisection, for every row at once.

    Eliminating ``M`` this way leaves a small, well-conditioned problem in ``S`` (and ``o``)
    for the trainer's optimiser; by the envelope theorem the loss gradient with respect to
    ``S`` at this ``M`` is the gradient of the reduced problem, so no gradient flows through
    the solve.

    Args:
        readings: ``b x p`` (offsets removed).
        shape: ``n x p``.
        metric_weight: ``w``.
        iterations: bisection steps (each halves the bracket).

    Returns:
        ``b x n``.
    """
    eigenvalues, basis = torch.linalg.eigh(shape @ shape.T)
    coefficients = readings @ shape.T @ basis
    if metric_weight == 0:
        return (coefficients / eigenvalues) @ basis.T

    def phi(s: torch.Tensor) -> torch.Tensor:
        norm2 = (coefficients / (eigenvalues + s[:, None])).pow(2).sum(dim=1)
        return s - metric_weight / 2 * (norm2 - 1)

    low = torch.full((len(readings),), -float(eigenvalues[0]), dtype=readings.dtype, device=readings.device)
    high = torch.ones_like(low)
    while bool((phi(high) < 0).any()):
        high = torch.where(phi(high) < 0, 2 * high, high)
    for _ in range(iterations):
        middle = (low + high) / 2
        below = phi(middle) < 0
        low = torch.where(below, middle, low)
        high = torch.where(below, high, middle)
    s = (low + high) / 2
    return (coefficients / (eigenvalues + s[:, None])) @ basis.T
