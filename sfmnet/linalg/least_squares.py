"""Least-squares calibration, the traditional baseline: every load known (NOTES 7, paper eq. 5 with M known)."""

from __future__ import annotations

import torch

from sfmnet.errors import SfmnetError


def least_squares_shape(
    loads: torch.Tensor, readings: torch.Tensor, estimate_offset: bool
) -> tuple[torch.Tensor, torch.Tensor]:
    """Solve ``Z = M S + 1 o^T`` for ``S`` (and ``o``) given known loads ``M``.

    Args:
        loads: ``M``, ``k x n``, load units.
        readings: ``Z``, ``k x p``, raw units.
        estimate_offset: fit ``o`` too (a column of ones); else ``o = 0`` (tared readings).

    Returns:
        ``(S, o)``: ``n x p`` and ``p``.

    Raises:
        SfmnetError: if the loads do not span all ``n`` axes or are fewer than the unknowns.
    """
    k, n = loads.shape
    design = torch.cat([loads, torch.ones(k, 1, dtype=loads.dtype)], dim=1) if estimate_offset else loads
    if k < design.shape[1]:
        raise SfmnetError(
            f"least squares needs at least {design.shape[1]} known loads for {n} axes"
            f"{' and offsets' if estimate_offset else ''}, got {k}"
        )
    singular = torch.linalg.svdvals(design)
    if singular[-1] <= 1e-9 * singular[0]:
        raise SfmnetError(
            "the known loads do not span every load axis (collinear or coplanar): "
            "apply loads in directions that cover all axes"
        )
    solution = torch.linalg.lstsq(design, readings).solution
    offset = solution[n] if estimate_offset else torch.zeros(readings.shape[1], dtype=readings.dtype)
    return solution[:n], offset

