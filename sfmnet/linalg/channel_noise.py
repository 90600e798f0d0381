"""Each channel's own noise, from the readings off the load space (method §5, "Channels of unequal noise").

A sensor's channels need not be equally noisy in raw units (different gains or amplifiers). The estimators weigh every
channel alike, which stays consistent; the checks that predict how far a row may miss the model from one noise level
do not, and call a clean session wrong. With independent channels of variances ``v`` (``Sigma = diag(v)``) the readings
off the load space, ``E = (Z - o) Q`` with ``Q = I - C^+ C`` the projector off the row space of ``C``, have covariance
``Q Sigma Q``, linear in ``v``:

    E^T E / (f - n) ~ sum_k v_k q_k q_k^T,    q_k the k-th column of Q                                  (H1)

``p (p + 1) / 2`` equations for ``p`` unknowns, but ``Q`` has rank ``p - n``, so at most ``(p - n)(p - n + 1) / 2`` of them
are independent: ``v`` is identified from 3 channels off the load space (6 channels for 3 axes, 5 for 2), not from
fewer (the noise is then taken as equal), and even then some combinations of the channels are barely told apart by a
few hundred rows. So (H1) is solved by ridge regression towards equal noise: a combination the rows do not tell stays
at the mean noise.
"""

from __future__ import annotations

import torch

# The ridge's weight, in standard errors of a covariance entry (``sigma^2 sqrt(2 / f)``): a combination of the channels
# whose design singular value is below this many of them is drawn halfway or more to equal noise, so its estimate's
# own noise stays under a tenth of the noise variance.
NOISE_RIDGE_STANDARD_ERRORS = 5.0
# Rows whose squared reading off the load space is past this many times the median row's are left out of (H1): a bump
# or a glitch there would pass for a channel's noise. Clean rows stay under it even with channels 30x apart in noise
# (one channel's chi-square with one degree of freedom reaches 33x its median once in 10,000 rows).
OFF_SPACE_TRIM = 50.0


def off_load_space_projector(matrix: torch.Tensor) -> torch.Tensor:
    """``Q = I - C^+ C``, ``p x p``: the projector off the row space of ``C`` (``n x p``), where a linear sensor reads
    noise only."""
    return torch.eye(matrix.shape[1], dtype=matrix.dtype) - torch.linalg.pinv(matrix) @ matrix


def channel_noise_variances(off_space: torch.Tensor, matrix: torch.Tensor) -> torch.Tensor | None:
    """Each channel's noise variance from the readings off the load space: (H1) by ridge regression towards the
    channels' mean variance ``sigma^2 = |E|^2 / ((f - n) (p - n))``, rows far off the load space left out; None where
    (H1) cannot identify them (``(p - n)(p - n + 1) / 2 < p``: fewer than 6 channels for 3 axes, 5 for 2).

    Args:
        off_space: ``f x p``, the rows' readings less their offset and their least-squares load's reading
            (``(z_j - o) Q``, raw units); matrix: ``C``, ``n x p``.

    Returns:
        ``p`` variances (raw units squared), none negative; all ``sigma^2`` where the rows cannot tell them apart.
    """
    squares = off_space.square().sum(dim=1)
    off_space = off_space[squares <= OFF_SPACE_TRIM * squares.median()]
    f, p = off_space.shape
    n = matrix.shape[0]
    # Fewer independent equations than channels: a ridge would fill the rest from the mean and put noise on channels
    # the readings off the load space barely see, hiding a misfit in the load space (a tester's 5-channel sensor).
    if f <= n or (p - n) * (p - n + 1) // 2 < p:
        return None
    complement = off_load_space_projector(matrix)
    upper = torch.triu_indices(p, p)
    design = complement[upper[0]] * complement[upper[1]]
    covariance = (off_space.T @ off_space / (f - n))[upper[0], upper[1]]
    mean = float(off_space.square().sum()) / ((f - n) * (p - n))
    ridge = (NOISE_RIDGE_STANDARD_ERRORS**2 * 2 / (f - n)) * torch.eye(p, dtype=matrix.dtype)
    # In units of the mean variance, so the ridge's weight is in standard errors whatever the raw units.
    change = torch.linalg.solve(design.T @ design + ridge, design.T @ (covariance / mean - design.sum(dim=1)))
    return (mean * (1 + change)).clamp(min=0)


def residual_spread(
    variances: torch.Tensor, matrix: torch.Tensor, known: torch.Tensor, directions: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """How each row's squared residual spreads when channels differ in noise: ``|r_j|^2 ~ (mu_j / nu_j) chi2(nu_j)``
    in units of the channels' mean variance (method §5, eq. H2).

    A known load's residual is the row's whole noise (covariance ``Sigma``); an unknown one's, the fit having taken the
    ``n - 1`` directions its orientation moves the reading in, is its noise off the load space and along
    ``a_j = C^T u_j / |C^T u_j|`` (``u_j`` the row's direction): covariance ``M_j = (Q + a_j a_j^T) Sigma (Q + a_j a_j^T)``.
    ``mu_j = tr M_j`` and, matching the variance too (Satterthwaite), ``nu_j = mu_j^2 / tr(M_j^2)``: with equal noise
    ``p`` and ``p`` for a known load, ``p - n + 1`` twice for an unknown one; with unequal noise fewer degrees of freedom
    (a longer tail) and a mean that depends on where the row's direction reads.

    Args:
        variances: ``p`` (:func:`channel_noise_variances`); matrix: ``C``, ``n x p``; known: ``f`` (bool), the rows of
            known load; directions: ``g x n``, the unknown rows' directions (``g`` = their count), in order.

    Returns:
        ``mu``, ``nu``: ``f`` each.
    """
    sigma = variances / variances.mean()
    complement = off_load_space_projector(matrix)
    off = complement * sigma @ complement
    along = directions @ matrix
    along = along / along.norm(dim=1, keepdim=True)
    radial = along.square() @ sigma
    # tr(M_j^2) = tr(off^2) + (a^T Sigma a)^2 + 2 |Q Sigma a|^2, as Q a = 0.
    cross = (along * sigma @ complement).square().sum(dim=1)
    unknown_mean = float(off.trace()) + radial
    unknown_squares = float(off.square().sum()) + radial.square() + 2 * cross
    mean = torch.full(known.shape, float(sigma.sum()), dtype=matrix.dtype)
    dof = torch.full(known.shape, float(sigma.sum() ** 2 / sigma.square().sum()), dtype=matrix.dtype)
    mean[~known], dof[~known] = unknown_mean, unknown_mean.square() / unknown_squares
    return mean, dof
