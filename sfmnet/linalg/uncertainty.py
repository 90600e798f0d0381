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

import math
from dataclasses import dataclass

import torch
from torch.func import jacrev

from sfmnet.calibration import calibration_matrix


# Eigenvalues of the information below this fraction of the largest are the gauge, not data.
GAUGE_RTOL = 1e-10
# Rows whose information is summed at once (memory ~ rows x p x (n + 1) p doubles).
INFORMATION_CHUNK_ROWS = 20_000
# Above this many unknown-load rows an evenly spaced sample of them stands for all: the information is a
# mean over the rows, which a sample this size gives to about 0.3 % (the error bars to half that), as the
# streamed fit's sample does.
INFORMATION_SAMPLE_ROWS = 100_000


@dataclass(frozen=True)
class CalibrationUncertainty:
    """Standard errors (square roots of the Cramer-Rao bound's diagonal).

    Attributes:
        matrix_std: ``n x p``, of the calibration matrix entries (load units per raw unit).
        offset_std: ``p``, of the offsets (raw units); zeros when offsets are not estimated.
        noise_std: the reading noise estimated from the residuals (raw units).
        frame_share: the fraction of the matrix's variance (``|matrix_std|_F^2``) that lies along turns of the load
            frame (``dC = W C``, ``W`` antisymmetric), which only the known loads fix; None without known loads, or
            where the unknown rows' directions are not loads (six axes).
    """

    matrix_std: torch.Tensor
    offset_std: torch.Tensor
    noise_std: float
    frame_share: float | None = None


def tangent_bases(directions: torch.Tensor) -> torch.Tensor:
    """Orthonormal bases of the planes orthogonal to each unit row: ``f x n`` in, ``f x n x (n-1)`` out.

    The last ``n - 1`` columns of the Householder reflection ``H = I - 2 v v^T / |v|^2``,
    ``v = u + sign(u_1) e_1``, which maps ``u`` to ``-sign(u_1) e_1`` (``v`` never near zero).
    """
    n = directions.shape[1]
    v = directions.clone()
    v[:, 0] += torch.where(directions[:, 0] >= 0, 1.0, -1.0)
    reflection = torch.eye(n, dtype=directions.dtype) - 2 * v[:, :, None] * v[:, None, :] / v.pow(2).sum(dim=1)[:, None, None]
    return reflection[:, :, 1:]


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
            Beyond ``INFORMATION_SAMPLE_ROWS`` rows an every-``k``-th sample is summed, each
            standing for ``k`` times as many.

    Returns:
        ``(n p [+ p]) x (n p [+ p])``.
    """
    p = shape.shape[1]
    if len(unknown_directions) > INFORMATION_SAMPLE_ROWS:
        stride = math.ceil(len(unknown_directions) / INFORMATION_SAMPLE_ROWS)
        sampled = unknown_directions[::stride]
        unknown_weight = unknown_weight * len(unknown_directions) / len(sampled)
        unknown_directions, unknown_maps = sampled, unknown_maps[::stride]
    known = global_jacobian(known_motion, p, estimate_offset)
    information = torch.einsum("jpa,jpb->ab", known, known)
    # In chunks of rows: the per-row Jacobians of a million rows would take gigabytes at once.
    for start in range(0, len(unknown_directions), INFORMATION_CHUNK_ROWS):
        rows = slice(start, start + INFORMATION_CHUNK_ROWS)
        information = information + unknown_weight * unknown_rows_information(
            shape, unknown_directions[rows], unknown_maps[rows], estimate_offset
        )
    return information


def unknown_rows_information(
    shape: torch.Tensor, directions: torch.Tensor, maps: torch.Tensor, estimate_offset: bool
) -> torch.Tensor:
    """The unknown-load rows' share of :func:`shape_information`, each row's direction eliminated (Schur complement).

    Row ``j``'s Jacobian is ``J_j = [m_j kron I_p, I_p]`` (``m_j = u_j D_j``); eliminating its direction
    leaves ``J_j^T Q_j J_j``, ``Q_j = I - P_j`` the projector off the span of ``d z_j / d delta_j``
    (``p x (d-1)``). Its Kronecker structure makes the sum one matrix product:
    ``sum_j (w_j w_j^T) kron Q_j``, ``w_j = [m_j, 1]``.
    """
    p = shape.shape[1]
    motion = torch.einsum("jd,jdn->jn", directions, maps)
    weights = torch.cat([motion, torch.ones_like(motion[:, :1])], dim=1) if estimate_offset else motion
    projector = torch.eye(p, dtype=shape.dtype).expand(len(directions), p, p)
    if directions.shape[1] > 1:
        # d z_j / d delta_j = (T_j^T D_j S)^T, the direction's tangent coordinates.
        tangent = torch.einsum("jde,jdn,np->jpe", tangent_bases(directions), maps, shape)
        local = tangent.transpose(1, 2) @ tangent
        projector = projector - tangent @ torch.linalg.solve(local, tangent.transpose(1, 2))
    k = weights.shape[1]
    outer = (weights[:, :, None] * weights[:, None, :]).reshape(len(weights), k * k)
    blocks = (outer.T @ projector.reshape(len(weights), p * p)).reshape(k, k, p, p)
    return blocks.permute(0, 2, 1, 3).reshape(k * p, k * p)


def residual_noise_variance(
    squares: float, observations: float, free_directions: float, direction_dims: int, parameters: int
) -> float:
    """The noise variance of one reading entry from a fit's residual sum of squares over ``observations`` entries.

    ``sigma^2 = squares / dof``, ``dof = observations - g (d - 1) - parameters``: each of the ``g`` free directions
    takes up ``d - 1`` of its row's components (``d`` the direction's dimension), the shape and offsets their
    ``parameters`` entries (the frame's rotation, unidentified without known loads, is not counted: a few of
    hundreds). The plain mean square understates it by about ``(p - d + 1) / p`` and so overstates the SNR, most
    where ``p = n`` (simulated, SNR 20: 1.25x at p = 6, n = 3, and 1.57x at p = n = 3; counted, 1.01x and 0.88x).
    """
    return squares / max(observations - free_directions * (direction_dims - 1) - parameters, 1)


def calibration_uncertainty(
    shape: torch.Tensor,
    known_motion: torch.Tensor,
    unknown_directions: torch.Tensor,
    unknown_maps: torch.Tensor,
    estimate_offset: bool,
    residual_sum_of_squares: float,
    observations: int,
    unknown_weight: float = 1.0,
    free_directions: int | None = None,
) -> CalibrationUncertainty:
    """Cramer-Rao standard errors of the calibration matrix ``C = pinv(S)^T`` and the offsets.

    The noise variance is ``RSS / (observations - parameters)``; the matrix covariance is
    the bound on ``S`` carried through the Jacobian of ``pinv(S)^T``. ``unknown_weight``: see
    :func:`shape_information` (``RSS`` and ``observations`` then of the whole recording).
    ``free_directions``: how many directions the fit solved for (each ``d - 1`` parameters), when rows
    share them (tied poses); None: one per unknown row. Rows sharing a true direction carry the same
    information whether their directions are tied or not (the nuisance direction removes the same
    subspace from each row's), so only the parameter count changes.

    The frame's share (:attr:`CalibrationUncertainty.frame_share`): the unknown rows say nothing of how the load
    frame is turned, so with one known load set on a stage most of a matrix's variance is often that one reading's
    noise turning the frame (the default fingertip session: 92 %), which more readings of the known loads shrink and
    more orientations do not.
    """
    n, p = shape.shape
    information = shape_information(shape, known_motion, unknown_directions, unknown_maps, estimate_offset, unknown_weight)
    if free_directions is None:
        free_directions = unknown_weight * len(unknown_directions)
    noise_var = residual_noise_variance(
        residual_sum_of_squares, observations, free_directions, unknown_directions.shape[1], information.shape[0]
    )
    # The frame's rotation gauge (no known loads) is null only up to rounding, which grows with the
    # row count: a default relative cut (~1e-15) can invert that rounding into a huge variance.
    covariance = noise_var * torch.linalg.pinv(information, hermitian=True, rtol=GAUGE_RTOL)
    jacobian = jacrev(calibration_matrix)(shape).reshape(n * p, n * p)
    matrix_cov = jacobian @ covariance[: n * p, : n * p] @ jacobian.T
    matrix_var = matrix_cov.diagonal()
    offset_var = covariance.diagonal()[n * p :] if estimate_offset else torch.zeros(p, dtype=shape.dtype)
    frame_share = None
    if len(known_motion) and len(unknown_directions) and unknown_directions.shape[1] == n and n > 1:
        turns = frame_turns(calibration_matrix(shape))
        total = float(matrix_var.clamp_min(0).sum())
        frame_share = float(torch.trace(turns @ matrix_cov @ turns.T)) / total if total > 0 else 0.0
    return CalibrationUncertainty(
        matrix_std=matrix_var.clamp_min(0).sqrt().reshape(n, p),
        offset_std=offset_var.clamp_min(0).sqrt(),
        noise_std=noise_var**0.5,
        frame_share=frame_share,
    )


def frame_turns(matrix: torch.Tensor) -> torch.Tensor:
    """An orthonormal basis (``n (n - 1) / 2 x n p``, rows ``vec`` row-major) of the matrix's changes ``dC = W C`` under
    small turns ``W`` (antisymmetric) of the load frame: what the known loads, and nothing else, determine."""
    n = matrix.shape[0]
    generators = []
    for a in range(n):
        for b in range(a + 1, n):
            turn = torch.zeros(n, n, dtype=matrix.dtype)
            turn[a, b], turn[b, a] = 1.0, -1.0
            generators.append((turn @ matrix).reshape(-1))
    basis, _ = torch.linalg.qr(torch.stack(generators).T)
    return basis.T


def alternation_bias(shape: torch.Tensor, snr: float) -> float:
    """The alternation's bias (untied directions fitted row by row), to first order, as a fraction of the matrix.

    A row's noise reaches its load as ``C e`` (covariance ``sigma^2 C C^T``); the part across the row's direction is
    taken up by the fitted direction and adds to ``|m|^2`` on average, so the fit biases the calibration by about half
    the transverse variance over ``F^2``, most along the shape's weakest axis (the matrix too large there) (method §5, eq. B1): averaged over the sphere,
    ``(d - 1) / (2 d) sum_i 1 / SNR_i^2`` with ``SNR_i = F sigma_i(S) / noise`` along each of the shape's singular
    directions. On a well-conditioned sensor that is the familiar ``(d - 1) / (2 SNR^2)``; on an ill-conditioned one
    the weak axis sets it, whatever the mean SNR (``F |s| / noise``). First order and averaged over the sphere, it is a
    guide within about 3x: on 3-channel sensors with random shapes (20,000 rows) the matrix error was up to 2x it, on
    one with a single weak axis (tests/test_goodness_and_triads.py) half of it.

    Args:
        shape: ``S``, ``n x p`` (raw units per load unit); snr: ``F |s| / noise`` with ``|s|`` the mean of the
            channels' ``|s_k|`` (:attr:`~sfmnet.models.shape_from_motion.ShapeFromMotion.direction_snr`).
    """
    singular = torch.linalg.svdvals(shape)
    per_axis = snr * singular / shape.norm(dim=0).mean()
    d = shape.shape[0]
    return float((d - 1) / (2 * d) * per_axis.pow(-2).sum())


def relative_matrix_std(matrix_std: torch.Tensor, matrix: torch.Tensor) -> float:
    """The calibration matrix's standard error relative to the matrix: ``|matrix_std|_F / |C|_F`` (both ``n x p``)."""
    return float(matrix_std.norm() / matrix.norm())


def load_error_rms(
    shape: torch.Tensor, matrix: torch.Tensor, uncertainty: CalibrationUncertainty, magnitude: float
) -> float:
    """The RMS load error, a fraction of ``F``, the error bars predict over unit loads spread evenly on the sphere.

    A load ``m = F u`` reads ``z = m S + o``; the calibration puts it at ``C (z - o)``, off by
    ``dC m S - C do``. With independent entries, ``E|dC m S|^2 = (F^2 / n) sum_ij var(C_ij) |S_:j|^2``
    (``E[u u^T] = I / n``) and ``E|C do|^2 = sum_ij C_ij^2 var(o_j)``.

    Args:
        shape: ``S``, ``n x p``; matrix: ``C``, ``n x p``; magnitude: ``F``.
    """
    n = shape.shape[0]
    through_matrix = magnitude**2 / n * float((uncertainty.matrix_std.pow(2) @ shape.pow(2).sum(dim=0)).sum())
    through_offset = float((matrix.pow(2) @ uncertainty.offset_std.pow(2)).sum())
    return math.sqrt(through_matrix + through_offset) / magnitude
