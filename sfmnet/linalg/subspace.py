"""Subspaces of sensorimotor vectors: choosing the rank, gappy projection, principal angles (method §8, §10)."""

from __future__ import annotations

import torch

from sfmnet.linalg.factorisation import RANK_TOLERANCE


def largest_ratio_rank(singular_values: torch.Tensor) -> int:
    """The paper's rule: ``argmax_k s_k / s_(k+1)``, numerically null values ignored (method §8).

    Args:
        singular_values: ``m``, descending.
    """
    s = singular_values[singular_values > RANK_TOLERANCE * singular_values[0]]
    if len(s) < 2:
        return len(s)
    return int(torch.argmax(s[:-1] / s[1:])) + 1


def parallel_analysis_rank(
    standardised: torch.Tensor, generator: torch.Generator, draws: int = 20, quantile: float = 0.95
) -> int:
    """Horn's parallel analysis: keep the leading components stronger than chance.

    Each column is permuted independently (keeping its distribution, destroying every
    correlation) ``draws`` times; component ``k`` is kept while ``s_k`` exceeds the
    ``quantile`` of the permuted data's ``s_k``. Unlike the largest-ratio rule it needs no
    gap in the spectrum, which sensorimotor data seldom has.

    Args:
        standardised: ``f x m``, centred and scaled columns.
    """
    s = torch.linalg.svdvals(standardised)
    f = standardised.shape[0]
    chance = torch.stack(
        [
            torch.linalg.svdvals(
                torch.stack([column[torch.randperm(f, generator=generator)] for column in standardised.T], dim=1)
            )
            for _ in range(draws)
        ]
    )
    threshold = torch.quantile(chance, quantile, dim=0)
    above = (s > threshold).to(torch.int64)
    return max(1, int(torch.cumprod(above, dim=0).sum()))


def masked_projection(basis: torch.Tensor, values: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
    """Coefficients from the observed columns alone: ``c = argmin |c B_o - x_o|`` (gappy PCA, method §8).

    An explicit mask, never zeros for missing: an "off" command or an idle bumper is a real zero.

    Args:
        basis: ``B``, ``k x m`` (rows spanning the subspace).
        values: ``b x m`` (unobserved columns ignored).
        observed: boolean ``m``.

    Returns:
        ``b x k``; the reconstruction is ``c B``.
    """
    return torch.linalg.lstsq(basis[:, observed].T, values[:, observed].T).solution.T


def principal_angles_deg(first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
    """Principal angles between the row spaces of ``first`` (``k x m``) and ``second`` (``l x m``), degrees, ascending."""
    q1 = torch.linalg.qr(first.T).Q
    q2 = torch.linalg.qr(second.T).Q
    cosines = torch.linalg.svdvals(q1.T @ q2).clamp(-1.0, 1.0)
    return torch.rad2deg(torch.arccos(cosines))
