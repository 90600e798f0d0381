"""Unit directions: spread evenly (the marginal likelihood's quadrature grid, the simulators' sweeps), clustered into the poses a recording holds, and ordered so that neighbours in direction come together."""

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


def distinct_directions(directions: torch.Tensor, tolerance: float, enough: int) -> torch.Tensor:
    """The distinct directions (poses) the unit rows hold, up to ``enough`` of them: ``k x d``, ``k <= enough``.

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
    return leaders


def median_angle_from_poses(directions: torch.Tensor, leaders: torch.Tensor) -> float:
    """Median angle (radians) of the unit rows (``f x d``) from the mean direction of the pose they are nearest
    (``leaders``, ``k x d``, from :func:`distinct_directions`): below one direction's RMS noise where the rows were
    held at those poses, nearer the poses' spacing where they sweep between them. The median, so that two poses
    closer than the clustering's tolerance, taken for one, leave the rest of the poses to say it."""
    pose = (directions @ leaders.T).argmax(dim=1)
    means = torch.zeros_like(leaders).index_add_(0, pose, directions)
    means = means / means.norm(dim=1, keepdim=True)
    cosine = (directions * means[pose]).sum(dim=1)
    # atan2 of the off-pose part: acos loses the small angles held poses have.
    sine = (directions - cosine[:, None] * means[pose]).norm(dim=1)
    return float(torch.atan2(sine, cosine).median())


def neighbour_order(directions: torch.Tensor, batch_rows: int) -> torch.Tensor:
    """An order of the unit rows (``f x d``, ``d`` = 2 or 3) in which consecutive rows are near in direction, so that
    ``batch_rows`` of them at a time hold about a square patch: round the circle by angle; on the sphere in bands of
    equal row counts by the last coordinate, each band by azimuth, every other one reversed (a snake), with about
    ``sqrt(f / (pi batch_rows))`` bands, whatever law the directions follow.

    Returns:
        ``f`` (long), a permutation of the rows.
    """
    azimuth = torch.atan2(directions[:, 1], directions[:, 0])
    if directions.shape[1] == 2:
        return azimuth.argsort()
    f = len(directions)
    bands = max(1, round(math.sqrt(f / (math.pi * batch_rows))))
    band = torch.empty(f, dtype=torch.long)
    band[directions[:, 2].argsort()] = torch.arange(f) * bands // f
    azimuth = torch.where(band % 2 == 1, -azimuth, azimuth)
    # Band first, then azimuth within it (azimuth / (2 pi) + 0.5 lies in [0, 1]).
    return (band + azimuth / (2 * math.pi + 1e-9) + 0.5).argsort()
