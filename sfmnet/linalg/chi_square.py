"""The chi-square statistic's tail in standard deviations, for checks that compare a sum of squares with the noise."""

from __future__ import annotations

import math


def chi_square_z(statistic: float, dof: float) -> float:
    """How many standard deviations ``statistic ~ chi2(dof)`` lies above its expectation: ``z ~ N(0, 1)``.

    The Wilson-Hilferty transform: ``(T / nu)^(1/3)`` is nearly normal with mean ``1 - 2 / (9 nu)`` and variance
    ``2 / (9 nu)``, good to a few per cent in the tail from ``nu = 1``. NaN where ``dof < 1``.
    """
    if not dof >= 1:
        return math.nan
    a = 2 / (9 * dof)
    return ((statistic / dof) ** (1 / 3) - (1 - a)) / math.sqrt(a)
