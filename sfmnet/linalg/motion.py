"""The motion of each sample given the shape: the inner problem of variable projection (NOTES 5)."""

from __future__ import annotations

import torch


@torch.no_grad()
def constrained_motion(
    readings: torch.Tensor,
    shape: torch.Tensor,
    metric_weight: float,
    iterations: int = 50,
    tolerance: float = 1e-13,
) -> torch.Tensor:
    """Per row, ``argmin_m |z - m S|^2 + w ((|m|^2 - 1) / 2)^2`` (loads in units of ``F``).

    With ``w = 0`` this is the least-squares projection ``z pinv(S)``; as ``w`` grows the rows
    are pulled onto the unit sphere, the metric constraint. Solved by Newton steps from the
    projection, dropping the constraint's negative curvature so each step is a descent step.

    Eliminating ``M`` this way leaves a small, well-conditioned problem in ``S`` (and ``o``)
    for the trainer's optimiser; by the envelope theorem the loss gradient with respect to
    ``S`` at this ``M`` is the gradient of the reduced problem, so no gradient flows through
    the solve.

    Args:
        readings: ``b x p`` (offsets removed).
        shape: ``n x p``.
        metric_weight: ``w``.
        iterations: at most this many Newton steps.
        tolerance: stop once no entry moves by more than this (units of ``F``).

    Returns:
        ``b x n``.
    """
    gram = shape @ shape.T
    target = readings @ shape.T
    motion = torch.linalg.solve(gram, target.T).T
    if metric_weight == 0:
        return motion
    eye = torch.eye(shape.shape[0], dtype=shape.dtype, device=shape.device)
    for _ in range(iterations):
        excess = motion.pow(2).sum(dim=1, keepdim=True) - 1
        gradient = 2 * (motion @ gram - target) + metric_weight * excess * motion
        hessian = 2 * gram + metric_weight * (
            excess.clamp_min(0)[:, :, None] * eye + 2 * motion[:, :, None] * motion[:, None, :]
        )
        step = torch.linalg.solve(hessian, gradient[:, :, None])[:, :, 0]
        motion = motion - step
        if float(step.abs().max()) < tolerance:
            break
    return motion
