"""The law of directions as a log-density on the grid: its harmonic basis, its fit and the choice of its degree."""

from __future__ import annotations

import math

import pytest
import torch

from sfmnet.linalg.directions import direction_grid
from sfmnet.linalg.orientation_law import LAW_DEGREES, fit_log_density, fit_orientation_law, harmonic_basis


@pytest.mark.parametrize("dims", [2, 3])
@pytest.mark.parametrize("degree", [0, 1, 2, 4])
def test_the_harmonic_basis_is_orthogonal_with_mean_zero(dims: int, degree: int):
    grid = direction_grid(dims, 512 if dims == 2 else 2000)
    basis = harmonic_basis(grid, degree)
    assert basis.shape == (len(grid), 2 * degree if dims == 2 else (degree + 1) ** 2 - 1)
    assert torch.allclose(basis.T @ basis, len(grid) * torch.eye(basis.shape[1], dtype=grid.dtype), atol=1e-6 * len(grid))
    assert torch.allclose(basis.mean(dim=0), torch.zeros(basis.shape[1], dtype=grid.dtype), atol=1e-9)


def residual_outside(basis: torch.Tensor, values: torch.Tensor) -> float:
    """RMS of what of ``values`` (mean removed) the basis's span does not hold."""
    values = values - values.mean()
    return float((values - basis @ (basis.T @ values) / len(basis)).pow(2).mean().sqrt())


def test_the_sphere_basis_of_degree_l_spans_exactly_the_harmonics_up_to_l():
    grid = direction_grid(3, 2000)
    x, y, z = grid.T
    quadrupole, octupole = 3 * z**2 - 1, x * y * z
    assert residual_outside(harmonic_basis(grid, 1), quadrupole) > 0.5
    assert residual_outside(harmonic_basis(grid, 2), quadrupole) < 1e-9
    assert residual_outside(harmonic_basis(grid, 2), octupole) > 0.05
    assert residual_outside(harmonic_basis(grid, 3), octupole) < 1e-9


def sharp_log_likelihood(grid: torch.Tensor, directions: torch.Tensor, spread: float = 0.05) -> torch.Tensor:
    """``f x K`` grid log-likelihoods of rows observed at ``directions`` with angular noise ``spread`` (radians)."""
    return -(directions[:, None, :] - grid[None]).pow(2).sum(dim=2) / (2 * spread**2)


def test_a_log_density_of_degree_one_is_recovered():
    """Directions drawn from ``w ~ exp(2 z)`` on the sphere: the fit's mean direction is the law's, ``coth 2 - 1/2``."""
    grid = direction_grid(3, 2000)
    generator = torch.Generator().manual_seed(0)
    weights = torch.softmax(2 * grid[:, 2], dim=0)
    drawn = grid[torch.multinomial(weights, 3000, replacement=True, generator=generator)]
    basis = harmonic_basis(grid, 1)
    theta, _ = fit_log_density(sharp_log_likelihood(grid, drawn), basis, basis.new_zeros(3))
    law = torch.softmax(basis @ theta, dim=0)
    mean = law @ grid
    assert abs(float(mean[2]) - (1 / math.tanh(2) - 0.5)) < 0.03, mean
    assert float(mean[:2].norm()) < 0.03, mean


@pytest.mark.parametrize(
    "zone, chosen", [("uniform", lambda degree: degree == 0), ("band", lambda degree: degree >= 2)]
)
def test_the_information_criterion_picks_no_more_degree_than_the_directions_show(zone, chosen):
    """Uniform directions get the uniform law (degree 0, no parameters); a band near the equator needs degree 2 or more."""
    grid = direction_grid(3, 2000)
    generator = torch.Generator().manual_seed(1)
    drawn = torch.randn(400, 3, generator=generator, dtype=grid.dtype)
    drawn = drawn / drawn.norm(dim=1, keepdim=True)
    if zone == "band":
        drawn = drawn[drawn[:, 2].abs() < 0.5]
    bases = {degree: harmonic_basis(grid, degree) for degree in LAW_DEGREES}
    start = torch.full((len(grid),), -math.log(len(grid)), dtype=grid.dtype)
    log_weights, degree = fit_orientation_law(sharp_log_likelihood(grid, drawn, spread=0.2), bases, start)
    assert chosen(degree), degree
    assert torch.isclose(log_weights.exp().sum(), torch.tensor(1.0, dtype=grid.dtype))
