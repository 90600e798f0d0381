"""A second quadric through the rows of unknown load: where the constant magnitude fixes a family of calibrations (method §5).

The magnitude constraint says that each unknown row's load ``x_j = C (z_j - o) / F`` lies on the unit sphere, a
quadric. If the rows also lie on a second quadric ``q(x) = 0`` (two circles of orientations: ``(a^T x)(b^T x) = 0``
for a mass turned about two axes only), every quadric of the pencil ``|x|^2 - 1 + t q(x)`` that is an ellipsoid passes
through them as well, and each is another calibration that puts every row at magnitude ``F`` (its loads
``F (A_t x_j + b_t) = C_t (z_j - o_t)``):

    |A_t x_j + b_t|^2 - 1 = c (|x_j|^2 - 1 + t q(x_j)) = 0  =>  C_t = A_t C,  C_t o_t = A_t C o - F b_t   (Q1)

The likelihood along that family is curved only by the rows' noise off the second quadric, so the fit stops wherever
that noise puts it, and error bars from the information at the fit, which counts that noise as information, do not
describe it (at the truth the information along the family is zero). :func:`second_quadric_ratio` measures how far the
rows sit off the best second quadric, as a multiple of where their noise alone would put them:

    mu = min_q  sum_j q(x_j)^2 / sum_j grad q(x_j)^T Sigma_j grad q(x_j),   q orthogonal to the sphere      (Q2)

(the second smallest generalised eigenvalue of ``sum phi phi^T`` against ``sum J_phi Sigma J_phi^T``, ``phi`` the
monomials of degree two or less, the smallest being the sphere the fit itself put the rows on). About 1 where the rows
lie on a second quadric to within their noise; the real spread off it adds ``mu - 1`` noise's worth.
"""

from __future__ import annotations

import itertools

import torch


def quadric_exponents(dims: int, offsets: bool) -> list[tuple[int, ...]]:
    """The exponents of the monomials a calibration's quadric is a combination of, in ``dims`` load axes.

    With ``offsets`` every monomial of degree two or less (``1, x_a, x_a x_b``: 10 for ``n = 3``, 6 for ``n = 2``);
    without, the constant and those of degree two (tared readings put the sphere's centre at the origin, so a
    calibration's quadric ``x^T A x - 1`` has no linear part).
    """
    return [e for e in itertools.product(range(3), repeat=dims) if sum(e) <= 2 and (offsets or sum(e) != 1)]


def quadric_monomials(points: torch.Tensor, offsets: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """The monomials of :func:`quadric_exponents` at each point, and their gradients.

    Args:
        points: ``f x n``.

    Returns:
        ``values`` (``f x q``) and ``gradients`` (``f x q x n``, ``d phi_i / d x_a``).
    """
    n = points.shape[1]
    powers = torch.tensor(quadric_exponents(n, offsets), dtype=points.dtype)
    values = points[:, None, :].pow(powers[None]).prod(dim=2)
    gradients = torch.zeros(len(points), len(powers), n, dtype=points.dtype)
    for axis in range(n):
        reduced = powers.clone()
        reduced[:, axis] = (powers[:, axis] - 1).clamp_min(0)
        gradients[:, :, axis] = powers[:, axis] * points[:, None, :].pow(reduced[None]).prod(dim=2)
    return values, gradients


def second_quadric_ratio(points: torch.Tensor, covariance: torch.Tensor, offsets: bool) -> float:
    """How far the points sit off the best second quadric, in their noise (eq. Q2): about 1 on one, large off every one.

    Args:
        points: ``f x n``, the unknown rows' loads over the magnitude, ``x_j = C (z_j - o) / F``: on the unit sphere up
            to noise; more of them than :func:`quadric_exponents` has monomials.
        covariance: ``n x n``, each point's noise (``C diag(v) C^T / F^2``, ``v`` the channels' noise variances).
        offsets: the calibration estimates offsets (the quadric's linear part free; :func:`quadric_exponents`).

    Returns:
        ``mu``, the second smallest ratio of the points' spread off a quadric to their noise's.
    """
    values, gradients = quadric_monomials(points, offsets)
    spread = values.T @ values
    noise = torch.einsum("jia,ab,jkb->ik", gradients, covariance, gradients)
    # mu = 1 / nu, nu the eigenvalues of the noise against the spread: the constant has no gradient, so the noise is
    # singular and the spread (points in general position) is not.
    scale, vectors = torch.linalg.eigh(spread)
    whiten = vectors / scale.clamp_min(torch.finfo(points.dtype).eps * float(scale.max())).sqrt()
    ratios = torch.linalg.eigvalsh(whiten.T @ noise @ whiten)
    return float(1 / ratios[-2].clamp_min(torch.finfo(points.dtype).tiny))
