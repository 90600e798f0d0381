"""The distribution of load directions as a smooth log-density on a direction grid, learnt from the data.

The marginal likelihood (method §5) weights each grid direction ``u_k`` by ``w_k``, the probability
that a sample's load points there. The law is not assumed: it is a log-density of low degree,

    log w_k = phi(u_k) . theta - log sum_l exp(phi(u_l) . theta),

``phi`` the circular (Fourier) or spherical harmonics up to a degree ``L``, and ``L`` is chosen by the
Bayesian information criterion. A robot that keeps the mass below the sensor, a band near the equator
or a cone are smooth laws of degree 1-4; a uniform law is degree 0 and costs no parameters.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

# The degrees of log-density the Bayesian information criterion chooses among: 0 (uniform) to 4
# (on the sphere 24 parameters, on the circle 8). Measured on the orientation laws of
# bench/crb_ratio.py --laws (README, "Error against the Cramér-Rao bound").
LAW_DEGREES = (0, 1, 2, 3, 4)
# Newton steps of one law's fit at most; it stops sooner once a step gains under 1e-10 nats a row.
NEWTON_STEPS = 50


def harmonic_basis(grid: torch.Tensor, degree: int) -> torch.Tensor:
    """The harmonics of degree 1 to ``degree`` at the grid's directions: ``K x m``, columns orthogonal, ``Phi^T Phi = K I``.

    Args:
        grid: ``K x d`` unit vectors spread evenly (:func:`~sfmnet.linalg.directions.direction_grid`), ``d`` 2 or 3.
        degree: ``L >= 0``.

    Returns:
        On the circle ``cos(j a), sin(j a)`` for ``j = 1..L`` (``m = 2L``, ``a`` the angle); on the sphere
        the span of the monomials ``x^a y^b z^c``, ``1 <= a + b + c <= L``, less the constant, orthonormalised
        over the grid: the spherical harmonics of degree 1 to ``L`` (``m = (L + 1)^2 - 1``). Degree 0: ``K x 0``.
    """
    count, dims = grid.shape
    if degree == 0:
        return grid.new_zeros(count, 0)
    if dims == 2:
        angle = torch.atan2(grid[:, 1], grid[:, 0])
        columns = [wave(j * angle) for j in range(1, degree + 1) for wave in (torch.cos, torch.sin)]
        return math.sqrt(2) * torch.stack(columns, dim=1)
    monomials = torch.stack(
        [
            grid[:, 0] ** a * grid[:, 1] ** b * grid[:, 2] ** c
            for a in range(degree + 1)
            for b in range(degree + 1 - a)
            for c in range(degree + 1 - a - b)
            if a + b + c > 0
        ],
        dim=1,
    )
    # On the sphere x^2 + y^2 + z^2 = 1 makes the monomials dependent: their span is the harmonics up to L.
    left, _, _ = torch.linalg.svd(monomials - monomials.mean(dim=0), full_matrices=False)
    return math.sqrt(count) * left[:, : (degree + 1) ** 2 - 1]


def fit_log_density(log_likelihood: torch.Tensor, basis: torch.Tensor, start: torch.Tensor) -> tuple[torch.Tensor, float]:
    """Maximum-likelihood ``theta`` of the law ``w = softmax(basis @ theta)`` given each row's grid likelihoods.

    Damped Newton ascent on ``l(theta) = sum_j log sum_k w_k L_jk``, with ``P_jk`` the posterior of row ``j``
    over the grid, ``r = sum_j P_j`` and ``Phi = basis``:

        grad = Phi^T (r - f w),
        hess = Phi^T (diag(r) - P^T P - f (diag(w) - w w^T)) Phi,

    a step taken only where it raises ``l`` (the mixture's likelihood need not be concave in ``theta``).

    Args:
        log_likelihood: ``f x K``, ``log L_jk = log p(z_j | u_k)`` up to a constant per row.
        basis: ``K x m``, :func:`harmonic_basis`.
        start: ``m``, where the ascent starts.

    Returns:
        ``theta`` (``m``) and the maximised ``l``.
    """
    rows, m = len(log_likelihood), basis.shape[1]

    def evaluate(theta: torch.Tensor) -> tuple[float, torch.Tensor, torch.Tensor]:
        """``l(theta)``, the law's log-weights and each row's posterior over the grid (one pass over ``f x K``)."""
        log_weights = torch.log_softmax(basis @ theta, dim=0)
        joint = log_likelihood + log_weights
        row_evidence = torch.logsumexp(joint, dim=1, keepdim=True)
        return float(row_evidence.sum()), log_weights, joint - row_evidence

    theta = start
    current, log_weights, log_posterior = evaluate(start)
    damping = 1e-8
    for _ in range(NEWTON_STEPS if m else 0):
        posterior, weights = log_posterior.exp(), log_weights.exp()
        counts = posterior.sum(dim=0)
        gradient = basis.T @ (counts - rows * weights)
        projected, weighted = posterior @ basis, weights @ basis
        curvature = (
            basis.T @ ((counts - rows * weights)[:, None] * basis) - projected.T @ projected + rows * torch.outer(weighted, weighted)
        )
        scale = float(rows * (weights @ basis.pow(2)).max())
        while True:
            step = torch.linalg.solve(damping * scale * torch.eye(m, dtype=basis.dtype) - curvature, gradient)
            trial = evaluate(theta + step)
            if trial[0] >= current or damping > 1e6:
                break
            damping = max(10 * damping, 1e-4)
        if trial[0] < current:
            break
        gained = trial[0] - current
        theta, (current, log_weights, log_posterior) = theta + step, trial
        damping /= 10
        if gained < 1e-10 * rows:
            break
    return theta, current


def fit_orientation_law(
    log_likelihood: torch.Tensor, bases: dict[int, torch.Tensor], log_weights: torch.Tensor
) -> tuple[torch.Tensor, int]:
    """The law of directions the rows support: each degree's best log-density, the degree by the BIC.

    Each degree ``L`` is fitted (:func:`fit_log_density`), started from the projection of the current
    law ``log_weights`` (``K``) on its basis, and scored ``log-likelihood - (m_L / 2) log f``; the best
    is returned as log-weights (``K``, summing to one in the exponent) with its degree.

    Args:
        log_likelihood: ``f x K`` grid log-likelihoods of ``f`` rows.
        bases: degree to :func:`harmonic_basis` on the grid.
        log_weights: ``K``, the current law.
    """
    rows, count = log_likelihood.shape
    best: tuple[float, torch.Tensor, int] | None = None
    for degree, basis in bases.items():
        # The bases are orthogonal with Phi^T Phi = K I and mean zero: the projection is Phi^T log w / K.
        theta, fitted = fit_log_density(log_likelihood, basis, basis.T @ log_weights / count)
        score = fitted - 0.5 * basis.shape[1] * math.log(rows)
        if best is None or score > best[0]:
            best = (score, torch.log_softmax(basis @ theta, dim=0), degree)
    return best[1], best[2]


# Free directions split this way for :func:`held_out_log_likelihood`, the same split at every update.
HELD_OUT_SEED = 0


def held_out_log_likelihood(log_likelihood: torch.Tensor, fit_law: Callable[[torch.Tensor], torch.Tensor]) -> float:
    """Two-fold cross-validated log-likelihood of a rule that fits a law of directions.

    The rows are split in two at random (:data:`HELD_OUT_SEED`); the law fitted to each half,
    ``w = fit_law(L_half)``, scores the other: ``sum_j log sum_k w_k L_jk`` over the held-out rows,
    summed over both halves. A law with many free weights (a weight per grid direction) scores in-sample
    far above a uniform law even where the directions are uniform; held out, its extra weights count
    only where they predict directions they were not fitted to.

    Args:
        log_likelihood: ``g x K``, ``log L_jk = log p(z_j | u_k)`` up to a constant per row (``g >= 2``).
        fit_law: ``h x K`` grid log-likelihoods of ``h`` rows to the law's log-weights, ``K``.
    """
    rows = len(log_likelihood)
    half = torch.randperm(rows, generator=torch.Generator().manual_seed(HELD_OUT_SEED)) % 2 == 0
    total = 0.0
    for fitted, held_out in ((half, ~half), (~half, half)):
        log_weights = fit_law(log_likelihood[fitted])
        total += float(torch.logsumexp(log_weights + log_likelihood[held_out], dim=1).sum())
    return total
