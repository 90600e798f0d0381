"""Tails of the chi-square and F statistics in standard deviations, for checks that compare sums of squares with noise."""

from __future__ import annotations

import math


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
