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
few hundred rows, while the ones the magnitudes' check needs, the channels that carry the load, are the ones the readings
off the load space see least. So (H1) is solved as a Bayesian regression with a wide prior about equal noise: the
variances' posterior mean, where the rows tell a combination, is the rows'; where they do not it stays near equal noise,
and the posterior covariance says how far each combination is from being known, which the checks carry into their
verdicts instead of trusting the prior.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import torch

from sfmnet.linalg.chi_square import chi_square_quantile
from sfmnet.linalg.group_means import group_means

# The prior's standard deviations of each channel's noise variance about the channels' mean, in units of that mean,
# among which the readings choose (the largest evidence): narrow where the channels are alike, so that a few hundred
# rows do not read noise into the combinations they barely tell apart, wide where gains and amplifiers differ by
# several times (a tester's sensor with three channels amplified 10x, its noise 0.5 % of each channel's span:
# variances 100x apart, which a prior fixed at 0.2 had held near the mean, 1.5-4.6x under the truth in the load space,
# and 5 of 6 clean sessions were disowned).
NOISE_PRIOR_SDS = (0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0)
# Rows whose squared reading off the load space is past this many times the median row's are left out of (H1): a bump
# or a glitch there would pass for a channel's noise. Clean rows stay under it even with channels 30x apart in noise
# (one channel's chi-square with one degree of freedom reaches 33x its median once in 10,000 rows).
OFF_SPACE_TRIM = 50.0
# Each row's noise in the load space is taken this many of its standard deviations up where outliers are judged
# (:func:`residual_spread`).
LOAD_SPACE_SDS = 2.0


@dataclass(frozen=True)
class ChannelNoise:
    """Each channel's noise variance as the readings off the load space tell it (:func:`channel_noise`).

    Attributes:
        variances: ``p``, the posterior mean (raw units squared), none negative.
        covariance: ``p x p``, their posterior covariance (raw units to the fourth): a combination ``w^T v`` is known to
            ``sqrt(w^T covariance w)``.
    """

    variances: torch.Tensor
    covariance: torch.Tensor

    def combination_sd(self, weights: torch.Tensor) -> float:
        """The standard deviation of ``weights^T v`` (``weights``: ``p``) under the posterior."""
        return math.sqrt(max(float(weights @ self.covariance @ weights), 0.0))


def off_load_space_projector(matrix: torch.Tensor) -> torch.Tensor:
    """``Q = I - C^+ C``, ``p x p``: the projector off the row space of ``C`` (``n x p``), where a linear sensor reads
    noise only."""
    return torch.eye(matrix.shape[1], dtype=matrix.dtype) - torch.linalg.pinv(matrix) @ matrix


def equal_channel_noise(off_space: torch.Tensor, matrix: torch.Tensor) -> ChannelNoise | None:
    """One noise variance for every channel, ``sigma^2 = |E|^2 / ((f - n)(p - n))``, and its sampling covariance
    (``2 sigma^4 / ((f - n)(p - n))`` on every combination of unit weight): the assumption where (H1) cannot tell the
    channels apart. None without rows or channels off the load space.

    Args:
        off_space: ``f x p`` (:func:`channel_noise`); matrix: ``C``, ``n x p``.
    """
    f, p = off_space.shape
    dof = (f - matrix.shape[0]) * (p - matrix.shape[0])
    if dof <= 0:
        return None
    mean = float(off_space.square().sum()) / dof
    ones = torch.ones(p, p, dtype=matrix.dtype)
    return ChannelNoise(torch.full((p,), mean, dtype=matrix.dtype), 2 * mean**2 / dof * ones)


def within_pose_channel_noise(readings: torch.Tensor, groups: torch.Tensor) -> ChannelNoise | None:
    """Each channel's noise variance measured about its pose means, where the rows were held still: every channel
    seen whole, the load space as much as the rest, so nothing rests on (H1). Each variance, from ``f - K`` degrees of
    freedom, is known to ``v_k sqrt(2 / (f - K))``. None with no pose of two or more rows.

    Args:
        readings: ``f x p`` (raw units); groups: ``f`` (long), each row's pose.
    """
    means, index, counts = group_means(readings, groups)
    dof = len(readings) - len(counts)
    if dof <= 0:
        return None
    variances = (readings - means[index]).square().sum(dim=0) / dof
    return ChannelNoise(variances, torch.diag(2 * variances.square() / dof))


def channel_noise(off_space: torch.Tensor, matrix: torch.Tensor) -> ChannelNoise | None:
    """Each channel's noise variance from the readings off the load space: (H1) as a Bayesian regression.

    (H1) is written in an orthonormal basis ``B`` of the space off the load space, where it holds each independent
    equation once, ``sum_k v_k B_ka B_kb = S_ab`` (``S`` the sample covariance there, ``a <= b``), the entries read
    together with their sampling covariance ``(S_ac S_bd + S_ad S_bc) / (f - n)`` (Wishart), so that noisy channels'
    entries count for less. The prior is
    ``N(sigma^2, (t sigma^2)^2)`` on each channel about the channels' mean variance ``sigma^2 = |E|^2 / ((f - n)(p - n))``,
    its width ``t`` the one of :data:`NOISE_PRIOR_SDS` the readings make most likely (the linear-Gaussian model's
    evidence). Rows far off the load space are left out. None where (H1) cannot identify the channels
    (``(p - n)(p - n + 1) / 2 < p``: fewer than 6 channels for 3 axes, 5 for 2).

    Args:
        off_space: ``f x p``, the rows' readings less their offset and their least-squares load's reading
            (``(z_j - o) Q``, raw units); matrix: ``C``, ``n x p``.

    Returns:
        The posterior (:class:`ChannelNoise`): its mean where the rows tell the channels apart, near ``sigma^2`` where
        they do not, with a covariance that says which.
    """
    squares = off_space.square().sum(dim=1)
    off_space = off_space[squares <= OFF_SPACE_TRIM * squares.median()]
    f, p = off_space.shape
    n = matrix.shape[0]
    # Fewer independent equations than channels: the load space's noise would rest on the prior, and a mass that slipped
    # could pass for it (a tester's 5-channel sensor at 6.2x its bars; with its rows shuffled, 5 of 8 such sessions at
    # 6-10x, where equal noise flags all 8).
    if f <= n or (p - n) * (p - n + 1) // 2 < p:
        return None
    # (H1) in an orthonormal basis of the space off the load space, where its p - n rows hold every independent
    # equation once; the entries of a sample covariance are correlated (Wishart), so they are read together.
    values, vectors = torch.linalg.eigh(off_load_space_projector(matrix))
    basis = vectors[:, values > 0.5]
    sample = basis.T @ off_space.T @ off_space @ basis / (f - n)
    mean = float(sample.trace()) / (p - n)
    upper = torch.triu_indices(p - n, p - n)
    a, b = upper[0], upper[1]
    design = (basis[:, a] * basis[:, b]).T
    # In units of the mean variance: Cov(S_ab, S_cd) = (S_ac S_bd + S_ad S_bc) / (f - n).
    entries = (sample[a][:, a] * sample[b][:, b] + sample[a][:, b] * sample[b][:, a]) / (mean**2 * (f - n))
    residual = sample[a, b] / mean - design.sum(dim=1)

    def log_evidence(prior_sd: float) -> float:
        spread = entries + prior_sd**2 * design @ design.T
        return -0.5 * float(residual @ torch.linalg.solve(spread, residual) + torch.linalg.slogdet(spread)[1])

    weighted = torch.linalg.solve(entries, design)

    def posterior(prior_sd: float) -> torch.Tensor:
        return torch.linalg.inv(design.T @ weighted + torch.eye(p, dtype=matrix.dtype) / prior_sd**2)

    change = posterior(max(NOISE_PRIOR_SDS, key=log_evidence)) @ (weighted.T @ residual)
    # The evidence chooses the width from the combinations the rows tell; in those they barely tell it favours the
    # narrowest prior, which would vouch for equal noise there. How well the rows fix each combination is theirs alone.
    return ChannelNoise((mean * (1 + change)).clamp(min=0), mean**2 * posterior(max(NOISE_PRIOR_SDS)))


# The prior's standard deviation of each channel's variance about the channels' mean, in units of that mean, where
# the rows' own residuals are the only witness (:func:`residual_channel_noise`): wide, so the rows decide wherever
# their directions tell the channels apart, and only a combination they leave untold stays near equal noise.
RESIDUAL_PRIOR_SD = 10.0
# Rounds of :func:`residual_channel_noise`'s reweighting: each row's weight and whether it is left out depend on the
# variances, which settle within a few.
RESIDUAL_ROUNDS = 4


def residual_channel_noise(
    squares: torch.Tensor, matrix: torch.Tensor, whole: torch.Tensor, directions: torch.Tensor, tail: float
) -> ChannelNoise | None:
    """Each channel's noise variance from the rows' own squared residuals, where the readings off the load space
    cannot tell the channels apart (as many channels as axes, or one or two more; method §5, eq. H3).

    A row that fits has ``E |r_j|^2 = tr M_j`` (:func:`residual_spread`, eq. H2), linear in ``v``:

        E |r_j|^2 = sum_k v_k (Q_kk + a_jk^2)   (a row fitted a direction),   sum_k v_k   (a whole row)     (H3)

    with ``a_j = C^T u_j / |C^T u_j|`` the reading-space normal of the constant magnitude at the row. With as many
    channels as axes (``Q = 0``) the residual is the noise along that normal alone, so rows at different directions
    weigh the channels differently, and their squares tell the channels apart however few there are off the load
    space. (H3) is solved as weighted least squares, each row weighed by its square's variance ``2 tr(M_j^2)``, with
    a wide prior about equal noise (:data:`RESIDUAL_PRIOR_SD`) for the combinations the directions leave untold;
    rows past the chi-square ``tail`` (a standard-normal quantile) of their own spread, the variances reweighted, are
    left out, so a few rows far off do not pass for a channel's noise. None with fewer rows than twice the channels.

    Args:
        squares: ``f``, each row's ``|r_j|^2`` (raw units squared); matrix: ``C``, ``n x p``; whole: ``f`` (bool),
            rows whose residual is their whole noise (a known load, a row of a tied pose); directions: ``g x n``, the
            other rows' unit directions, in order (``g`` = their count); tail: where a row is left out.

    Returns:
        The posterior (:class:`ChannelNoise`), its covariance how well the rows' directions tell each combination.
    """
    p = matrix.shape[1]
    if len(squares) < 2 * p:
        return None
    along = directions @ matrix
    along = along / along.norm(dim=1, keepdim=True)
    design = torch.ones(len(squares), p, dtype=matrix.dtype)
    design[~whole] = off_load_space_projector(matrix).diagonal() + along.square()
    mean = float(squares.median()) / max(float(design.sum(dim=1).median()), torch.finfo(matrix.dtype).tiny)
    noise = ChannelNoise(torch.full((p,), mean, dtype=matrix.dtype), torch.zeros(p, p, dtype=matrix.dtype))
    for _ in range(RESIDUAL_ROUNDS):
        spread = residual_spread(noise, matrix, whole, directions)
        scale = float(noise.variances.mean())
        variance = 2 * (spread.mean * scale).square() / spread.dof
        kept = squares <= chi_square_quantile(spread.dof, tail) * spread.mean * scale / spread.dof
        weighted = design[kept] / variance[kept, None]
        precision = design[kept].T @ weighted + torch.eye(p, dtype=matrix.dtype) / (RESIDUAL_PRIOR_SD * scale) ** 2
        covariance = torch.linalg.inv(precision)
        variances = covariance @ (weighted.T @ squares[kept] + scale / (RESIDUAL_PRIOR_SD * scale) ** 2)
        noise = ChannelNoise(variances.clamp(min=1e-3 * float(variances.mean().clamp(min=0))), covariance)
    return noise


class RowSpread(NamedTuple):
    """How each row's squared residual spreads (:func:`residual_spread`), in units of the channels' mean variance.

    Attributes:
        mean: ``f``, ``mu_j``; dof: ``f``, ``nu_j``; upper: ``f``, ``mu_j`` with the row's noise in the load space taken
            :data:`LOAD_SPACE_SDS` standard deviations up, as far as the readings allow it to be.
    """

    mean: torch.Tensor
    dof: torch.Tensor
    upper: torch.Tensor

    def rows(self, kept: torch.Tensor) -> RowSpread:
        """The spread of the rows ``kept`` (a mask or indices)."""
        return RowSpread(self.mean[kept], self.dof[kept], self.upper[kept])


def residual_spread(noise: ChannelNoise, matrix: torch.Tensor, known: torch.Tensor, directions: torch.Tensor) -> RowSpread:
    """How each row's squared residual spreads when channels differ in noise: ``|r_j|^2 ~ (mu_j / nu_j) chi2(nu_j)``
    in units of the channels' mean variance (method §5, eq. H2).

    A known load's residual is the row's whole noise (covariance ``Sigma``); an unknown one's, the fit having taken the
    ``n - 1`` directions its orientation moves the reading in, is its noise off the load space and along
    ``a_j = C^T u_j / |C^T u_j|`` (``u_j`` the row's direction): covariance ``M_j = (Q + a_j a_j^T) Sigma (Q + a_j a_j^T)``.
    ``mu_j = tr M_j`` and, matching the variance too (Satterthwaite), ``nu_j = mu_j^2 / tr(M_j^2)``: with equal noise
    ``p`` and ``p`` for a known load, ``p - n + 1`` twice for an unknown one; with unequal noise fewer degrees of freedom
    (a longer tail) and a mean that depends on where the row's direction reads. The noise in the load space is known
    only as well as the readings off it tell (``noise.covariance``): ``upper`` takes each row's share of it, ``tr Sigma``
    for a known load and ``a_j^T Sigma a_j`` for an unknown one, :data:`LOAD_SPACE_SDS` standard deviations up, so that
    a row is called far out only if it is under every noise the readings allow.

    Args:
        noise: the channels' noise (:func:`channel_noise`); matrix: ``C``, ``n x p``; known: ``f`` (bool), the rows of
            known load; directions: ``g x n``, the unknown rows' directions (``g`` = their count), in order.
    """
    scale = float(noise.variances.mean())
    sigma = noise.variances / scale
    complement = off_load_space_projector(matrix)
    off = complement * sigma @ complement
    along = directions @ matrix
    along = along / along.norm(dim=1, keepdim=True)
    weights = along.square()
    radial = weights @ sigma
    # tr(M_j^2) = tr(off^2) + (a^T Sigma a)^2 + 2 |Q Sigma a|^2, as Q a = 0.
    cross = (along * sigma @ complement).square().sum(dim=1)
    unknown_mean = float(off.trace()) + radial
    unknown_squares = float(off.square().sum()) + radial.square() + 2 * cross
    mean = torch.full(known.shape, float(sigma.sum()), dtype=matrix.dtype)
    dof = torch.full(known.shape, float(sigma.sum() ** 2 / sigma.square().sum()), dtype=matrix.dtype)
    mean[~known], dof[~known] = unknown_mean, unknown_mean.square() / unknown_squares
    margin = torch.full(known.shape, noise.combination_sd(torch.ones_like(sigma)) / scale, dtype=matrix.dtype)
    margin[~known] = ((weights @ noise.covariance) * weights).sum(dim=1).clamp(min=0).sqrt() / scale
    return RowSpread(mean, dof, mean + LOAD_SPACE_SDS * margin)
