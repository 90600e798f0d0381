"""The motion of each sample given the shape: the inner problem of variable projection (method §5)."""

from __future__ import annotations

import torch

UNIT_MOTION_CHUNK_ROWS = 131_072


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


@torch.no_grad()
def unit_motion(
    readings: torch.Tensor, shape: torch.Tensor, iterations: int = 100, multipliers: torch.Tensor | None = None
) -> torch.Tensor:
    """Per row, the global ``argmin_{|u| = 1} |z - u S|^2``: the direction that explains the readings best.

    The hard metric constraint (method §5), the limit of :func:`constrained_motion` as ``w``
    grows. Normalising the least-squares projection ``z pinv(S)`` gives the same direction only
    when ``S S^T`` is a multiple of ``I``; for a sensor whose axes differ in gain it leans
    towards the weak axes, which inflates residuals and biases ``S``. Stationarity reads
    ``(G + s I) u = c`` with ``G = S S^T``, ``c = S z^T`` and ``s > -g_min`` chosen so that
    ``|u| = 1``; in the eigenbasis of ``G``

        sum_i c_i^2 / (g_i + s)^2 = 1,

    the trust-region boundary equation, solved by Newton's method on ``1 - 1/|u(s)|`` (concave
    and nearly linear in ``s``, so from the root's left it climbs without overshooting), each row
    stepped until it has converged.

    Args:
        readings: ``b x p`` (offsets removed).
        shape: ``n x p``.
        iterations: at most this many Newton steps per row.
        multipliers: ``b``, optional, read and overwritten: each row's ``s`` to start from (NaN: no
            start) and, on return, the root found. An alternation passes the previous round's roots:
            its shape moves little between rounds, so rows need fewer steps (a million rows'
            solve about 1.4x faster on 2 threads).

    Returns:
        ``b x n``, unit rows.
    """
    eigenvalues, basis = torch.linalg.eigh(shape @ shape.T)
    # In chunks, so the solve's temporaries stay some tens of MB however long the recording (and large enough
    # for the thread pool to pay off: 65,536-row chunks were 1.3x slower on 2 threads).
    chunks = readings.split(UNIT_MOTION_CHUNK_ROWS)
    starts = [None] * len(chunks) if multipliers is None else multipliers.split(UNIT_MOTION_CHUNK_ROWS)
    to_eigenbasis = shape.T @ basis
    return torch.cat(
        [boundary_directions(chunk @ to_eigenbasis, eigenvalues, basis, iterations, start) for chunk, start in zip(chunks, starts)]
    )


def boundary_directions(
    coefficients: torch.Tensor,
    eigenvalues: torch.Tensor,
    basis: torch.Tensor,
    iterations: int,
    multipliers: torch.Tensor | None = None,
) -> torch.Tensor:
    """:func:`unit_motion`'s Newton solve for rows ``c = z S^T V`` (``b x n``) in the eigenbasis ``V`` of ``S S^T``;
    ``multipliers`` (``b``) as there: starts (NaN: none), overwritten with the roots."""
    # |u(s)| >= |c| / (g_max + s) and >= |c_min| / (g_min + s): left of the root, so a floor for every step.
    low = torch.maximum(coefficients.norm(dim=1) - eigenvalues[-1], coefficients[:, 0].abs() - eigenvalues[0])
    # Noise-free readings have their root at s = 0; a step from its right lands left of the root (concavity), as
    # does one from a warm start right of it, and every step is floored: from there Newton climbs to the root.
    s = low.clamp(min=0.0)
    if multipliers is not None:
        s = torch.where(torch.isnan(multipliers), s, multipliers)
    # The rows still stepping, compacted as they converge (most take two to four steps); the
    # squares are stored n x b, where sums over the n axes are whole-vector adds.
    rows, squares, s_rows, low_rows = torch.arange(len(s), device=s.device), coefficients.T.pow(2), s.clone(), low
    for _ in range(iterations):
        inverse = (eigenvalues[:, None] + s_rows).reciprocal_()
        terms = squares * inverse * inverse
        norm2 = terms.sum(dim=0)
        step = (norm2.sqrt() - 1) * norm2 / terms.mul_(inverse).sum(dim=0)
        s_rows = torch.maximum(s_rows + step, low_rows)
        # A step moves u by about step / (g_min + s), and Newton is quadratic: after a relative step below
        # 1e-7 the error left is of order 1e-14 (measured: at most 1.2e-13 in u on a 100:1:0.01-gain sensor).
        going = step.abs() > 1e-7 * (s_rows + eigenvalues[0])
        s[rows[~going]] = s_rows[~going]
        rows, squares, s_rows, low_rows = rows[going], squares[:, going], s_rows[going], low_rows[going]
        if len(rows) == 0:
            break
    s[rows] = s_rows
    if multipliers is not None:
        multipliers.copy_(s)
    directions = (coefficients / (eigenvalues + s[:, None])) @ basis.T
    return directions / directions.norm(dim=1, keepdim=True)
