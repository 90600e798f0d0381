"""Quadrature over unknown directions, for the marginal likelihood of shape from motion."""

from __future__ import annotations

import math

import torch


def direction_grid(dims: int, count: int) -> torch.Tensor:
    """``count x dims`` unit vectors spread evenly: equal angles on the circle, a Fibonacci spiral on the sphere.

    Equal weights then approximate the uniform prior's integral over directions.
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
