"""Unit directions spread evenly: the marginal likelihood's quadrature grid and the simulators' sweeps."""

from __future__ import annotations

import math

import torch


def direction_grid(dims: int, count: int) -> torch.Tensor:
    """``count x dims`` unit vectors spread evenly, in the order of one continuous turn.

    Equal angles round the circle; a Fibonacci spiral from pole to pole on the sphere. With
    equal weights they approximate an integral over uniform directions.
    """
    step = torch.arange(count, dtype=torch.float64)
    if dims == 2:
        angle = 2 * math.pi * step / count
        return torch.stack([angle.cos(), angle.sin()], dim=1)
    if dims != 3:
        raise ValueError(f"direction grids exist for 2 or 3 dimensions, not {dims}")
    z = 1 - 2 * (step + 0.5) / count
    radius = (1 - z**2).sqrt()
    azimuth = math.pi * (3 - math.sqrt(5)) * step
    return torch.stack([radius * azimuth.cos(), radius * azimuth.sin(), z], dim=1)


def count_distinct_directions(directions: torch.Tensor, tolerance: float, enough: int) -> int:
    """How many distinct directions (poses) the unit rows hold, counted up to ``enough``.

    Greedy leader clustering: the first row no pose found so far holds (within ``tolerance``
    radians) starts a new one. Stops at ``enough`` poses: ``f x enough^2`` work at most.

    Args:
        directions: ``f x d`` unit rows; tolerance: radians; enough: the count that suffices.
    """
    cosine = math.cos(tolerance)
    leaders, remaining = directions[:0], directions
    while len(remaining) and len(leaders) < enough:
        leaders = torch.cat([leaders, remaining[:1]])
        remaining = remaining[remaining @ remaining[0] < cosine]
    return len(leaders)
