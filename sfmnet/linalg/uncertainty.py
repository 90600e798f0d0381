"""Error bars of a calibration: the Cramer-Rao bound from the model's Fisher information (method §5).

Model, with white reading noise of variance ``sigma^2``::

    z_j = m_j S + o + e_j,    m_j known (known-load rows) or m_j = u_j D_j, |u_j| = 1 (unknown rows)

with ``D_j = F I`` for one constant-magnitude mass and the configuration's direction map
for six axes (method §6). Parameters: the shape ``S`` (``n x p``), the offsets ``o`` (``p``,
when estimated) and, for each unknown row, its direction ``u_j`` on the circle or sphere
(``d - 1`` tangent coordinates).
The per-row directions are eliminated by a Schur complement, leaving the information of
``(S, o)``. Without known loads the frame's rotation is not identifiable: the
pseudo-inverse then removes that gauge, as in the planning measurements of method §5.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch.func import jacrev

from sfmnet.calibration import calibration_matrix


# Eigenvalues of the information below this fraction of the largest are the gauge, not data.
GAUGE_RTOL = 1e-10


@dataclass(frozen=True)
class CalibrationUncertainty:
    """Standard errors (square roots of the Cramer-Rao bound's diagonal).

    Attributes:
        matrix_std: ``n x p``, of the calibration matrix entries (load units per raw unit).
        offset_std: ``p``, of the offsets (raw units); zeros when offsets are not estimated.
        noise_std: the reading noise estimated from the residuals (raw units).
    """

    matrix_std: torch.Tensor
    offset_std: torch.Tensor
    noise_std: float


def tangent_bases(directions: torch.Tensor) -> torch.Tensor:
    """Orthonormal bases of the planes orthogonal to each row: ``f x n`` in, ``f x n x (n-1)`` out."""
    u, _, _ = torch.linalg.svd(directions[:, :, None])
    return u[:, :, 1:]


def global_jacobian(motion: torch.Tensor, channels: int, estimate_offset: bool) -> torch.Tensor:
    """``d z_j / d (vec S, o)`` for each row: ``f x p x (n p [+ p])``, ``vec`` row-major."""
    f, n = motion.shape
    eye = torch.eye(channels, dtype=motion.dtype)
    shape_part = (motion[:, None, :, None] * eye[None, :, None, :]).reshape(f, channels, n * channels)
    if not estimate_offset:
        return shape_part
    return torch.cat([shape_part, eye.expand(f, channels, channels)], dim=2)


def shape_information(
    shape: torch.Tensor,
    known_motion: torch.Tensor,
    unknown_directions: torch.Tensor,
    unknown_maps: torch.Tensor,
    estimate_offset: bool,
    unknown_weight: float = 1.0,
) -> torch.Tensor:
    """Fisher information of ``(vec S, o)`` per unit noise variance, the unknown directions marginalised.

    Args:
        shape: ``S``, ``n x p``.
        known_motion: ``k x n`` loads of the known-load rows.
        unknown_directions: ``f x d`` fitted unit directions ``u_j`` of the unknown-load rows.
        unknown_maps: ``f x d x n``, their maps ``D_j`` (load units per unit direction).
        estimate_offset: include the offsets.
        unknown_weight: how many rows each unknown row stands for (a sample of a longer recording).

    Returns:
        ``(n p [+ p]) x (n p [+ p])``.
    """
    p = shape.shape[1]
    known = global_jacobian(known_motion, p, estimate_offset)
    unknown = global_jacobian(torch.einsum("jd,jdn->jn", unknown_directions, unknown_maps), p, estimate_offset)
    information = torch.einsum("jpa,jpb->ab", unknown, unknown)
    if len(unknown_directions) and unknown_directions.shape[1] > 1:
        # d z_j / d delta_j = T_j^T D_j S, the direction's tangent coordinates.
        tangent_maps = torch.einsum("jde,jdn->jen", tangent_bases(unknown_directions), unknown_maps)
        direction = torch.einsum("jen,np->jpe", tangent_maps, shape)
        cross = torch.einsum("jpa,jpd->jad", unknown, direction)
        local = torch.einsum("jpd,jpe->jde", direction, direction)
        information = information - torch.einsum("jad,jde,jbe->ab", cross, torch.linalg.inv(local), cross)
    return torch.einsum("jpa,jpb->ab", known, known) + unknown_weight * information


def calibration_uncertainty(
    shape: torch.Tensor,
    known_motion: torch.Tensor,
    unknown_directions: torch.Tensor,
    unknown_maps: torch.Tensor,
    estimate_offset: bool,
    residual_sum_of_squares: float,
    observations: int,
    unknown_weight: float = 1.0,
) -> CalibrationUncertainty:
    """Cramer-Rao standard errors of the calibration matrix ``C = pinv(S)^T`` and the offsets.

    The noise variance is ``RSS / (observations - parameters)``; the matrix covariance is
    the bound on ``S`` carried through the Jacobian of ``pinv(S)^T``. ``unknown_weight``: see
    :func:`shape_information` (``RSS`` and ``observations`` then of the whole recording).
    """
    n, p = shape.shape
    information = shape_information(shape, known_motion, unknown_directions, unknown_maps, estimate_offset, unknown_weight)
    parameters = information.shape[0] + unknown_weight * len(unknown_directions) * (unknown_directions.shape[1] - 1)
    noise_var = residual_sum_of_squares / max(observations - parameters, 1)
    # The frame's rotation gauge (no known loads) is null only up to rounding, which grows with the
    # row count: a default relative cut (~1e-15) can invert that rounding into a huge variance.
    covariance = noise_var * torch.linalg.pinv(information, hermitian=True, rtol=GAUGE_RTOL)
    shape_cov = covariance[: n * p, : n * p]
    jacobian = jacrev(calibration_matrix)(shape).reshape(n * p, n * p)
    matrix_var = torch.einsum("ab,bc,ac->a", jacobian, shape_cov, jacobian)
    offset_var = covariance.diagonal()[n * p :] if estimate_offset else torch.zeros(p, dtype=shape.dtype)
    return CalibrationUncertainty(
        matrix_std=matrix_var.clamp_min(0).sqrt().reshape(n, p),
        offset_std=offset_var.clamp_min(0).sqrt(),
        noise_std=noise_var**0.5,
    )
