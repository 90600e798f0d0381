"""Wrenches of a mass hanging from a six-axis force/torque sensor (method §6)."""

from __future__ import annotations

import torch

STANDARD_GRAVITY = 9.80665


def cross_matrix(vector: torch.Tensor) -> torch.Tensor:
    """``[r]x``, ``3 x 3``, with ``[r]x v = r x v``."""
    x, y, z = vector.unbind()
    zero = torch.zeros((), dtype=vector.dtype)
    return torch.stack([torch.stack([zero, -z, y]), torch.stack([z, zero, -x]), torch.stack([-y, x, zero])])


def wrench_map(mass: float, centre_of_mass: torch.Tensor, gravity: float = STANDARD_GRAVITY) -> torch.Tensor:
    """``D = m g [I, [r]x^T]``, ``3 x 6``: the wrench ``[F, M] = u D`` of the mass for gravity direction ``u``.

    ``F = m g u`` (N) and ``M = r x F`` (N m), rows as everywhere in sfmnet. One mass
    configuration's wrenches span only 3 of the 6 dimensions; three with different
    ``(m, r)`` span all six.

    Args:
        mass: ``m``, kg.
        centre_of_mass: ``r``, ``3``, m, in the sensor frame.
        gravity: ``g``, m/s^2.
    """
    eye = torch.eye(3, dtype=centre_of_mass.dtype)
    return mass * gravity * torch.cat([eye, cross_matrix(centre_of_mass).T], dim=1)
