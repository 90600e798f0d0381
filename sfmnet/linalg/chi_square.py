"""Tails of the chi-square and F statistics in standard deviations, for checks that compare sums of squares with noise."""

from __future__ import annotations

import math

import torch


def f_ratio_z(ratio: float, dof: float, noise_dof: float = math.inf) -> float:
    """How many standard deviations ``ratio ~ F(dof, noise_dof)`` lies above its expectation: ``z ~ N(0, 1)``.

    Paulson's normal approximation: ``(1 - 2 / (9 nu2)) F^(1/3)`` less ``(1 - 2 / (9 nu1))``, over
    ``sqrt(2 / (9 nu2) F^(2/3) + 2 / (9 nu1))``, good to a few per cent in the tail from ``nu1 = 1`` and ``nu2 = 3``.
    With ``noise_dof`` infinite (the noise known) it is the Wilson-Hilferty transform of ``chi2(dof) / dof``.
    NaN where ``dof < 1``.
    """
    if not dof >= 1:
        return math.nan
    a, b = 2 / (9 * dof), 2 / (9 * noise_dof)
    cube_root = ratio ** (1 / 3)
    return ((1 - b) * cube_root - (1 - a)) / math.sqrt(b * cube_root**2 + a)


def chi_square_z(statistic: float, dof: float) -> float:
    """How many standard deviations ``statistic ~ chi2(dof)`` lies above its expectation (:func:`f_ratio_z` of
    ``statistic / dof`` with the noise known). NaN where ``dof < 1``."""
    return f_ratio_z(statistic / dof, dof) if dof >= 1 else math.nan


def chi_square_quantile(dof: torch.Tensor, z: float) -> torch.Tensor:
    """Wilson-Hilferty approximation of the chi-square quantile at standard-normal quantile ``z``, per entry of ``dof``."""
    a = 2 / (9 * dof)
    return dof * (1 - a + z * a.sqrt()) ** 3


def robust_noise_variance(squares: torch.Tensor, dof: torch.Tensor) -> float:
    """The noise variance of one entry from rows' squared residuals, which a minority of bad rows barely moves.

    ``|r_j|^2 / sigma^2 ~ chi2(k_j)`` for a row that fits (``k_j`` its residual's degrees of freedom), so
    ``sigma^2`` is the median of ``|r_j|^2 / median(chi2(k_j))``.

    Args:
        squares: ``f``, each row's ``|r_j|^2``; dof: ``f``, each row's ``k_j`` (all positive).
    """
    return float((squares / chi_square_quantile(dof.to(squares.dtype), 0.0)).median())
