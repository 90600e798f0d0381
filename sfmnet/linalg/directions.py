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
