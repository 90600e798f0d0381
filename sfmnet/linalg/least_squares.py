"""Least-squares calibration, the traditional baselines: every load known (method §7).

Two forms. The paper's fits the shape from the loads, ``S, o = lstsq([M 1], Z)`` (eq. 5 with
``M`` known), and calibrates with ``C = pinv(S)^T``; practitioners regress the loads on the
readings, ``C, b = lstsq([Z 1], M)``, which minimises the load error itself (optionally with a
ridge penalty). Which is better depends on the data.
"""

from __future__ import annotations

import math

import torch
from torch.func import jacrev

from sfmnet.errors import SfmnetError


def least_squares_shape(
    loads: torch.Tensor, readings: torch.Tensor, estimate_offset: bool
) -> tuple[torch.Tensor, torch.Tensor]:
    """Solve ``Z = M S + 1 o^T`` for ``S`` (and ``o``) given known loads ``M``.

    Args:
        loads: ``M``, ``k x n``, load units.
        readings: ``Z``, ``k x p``, raw units.
        estimate_offset: fit ``o`` too (a column of ones); else ``o = 0`` (tared readings).

    Returns:
        ``(S, o)``: ``n x p`` and ``p``.

    Raises:
        SfmnetError: if the loads do not span all ``n`` axes or are fewer than the unknowns.
    """
    k, n = loads.shape
    design = torch.cat([loads, torch.ones(k, 1, dtype=loads.dtype)], dim=1) if estimate_offset else loads
    if k < design.shape[1]:
        raise SfmnetError(
            f"least squares needs at least {design.shape[1]} known loads for {n} axes"
            f"{' and offsets' if estimate_offset else ''}, got {k}"
        )
    singular = torch.linalg.svdvals(design)
    if singular[-1] <= 1e-9 * singular[0]:
        raise SfmnetError(
            "the known loads do not span every load axis (collinear or coplanar): "
            "apply loads in directions that cover all axes"
        )
    solution = torch.linalg.lstsq(design, readings).solution
    offset = solution[n] if estimate_offset else torch.zeros(readings.shape[1], dtype=readings.dtype)
    return solution[:n], offset


def standardisation(readings: torch.Tensor, intercept: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """Centre (the channel means with an intercept, else zeros) and scale (RMS about the centre) of ``k x p`` readings.

    A constant channel keeps scale 1, so it is left as it is rather than divided by zero.
    """
    centre = readings.mean(dim=0) if intercept else torch.zeros(readings.shape[1], dtype=readings.dtype)
    scale = (readings - centre).pow(2).mean(dim=0).sqrt()
    return centre, torch.where(scale > 0, scale, torch.ones_like(scale))


def regress_loads(
    readings: torch.Tensor, loads: torch.Tensor, strength: float, intercept: bool
) -> tuple[torch.Tensor, torch.Tensor]:
    """Regress the loads on the readings: ``load = C z + b``.

    With the readings standardised, ``x = (z - mu) / s`` per channel, each load axis ``i``
    minimises ``(1/k) sum_j (f_ji - w_i . x_j - b0_i)^2 + strength |w_i|^2`` (ridge on the
    standardised slopes, never on the intercept); then ``C = W^T diag(1/s)`` and
    ``b = b0 - C mu``. ``strength = 0`` is ordinary least squares, ``lstsq([Z 1], M)``, its
    minimum-norm solution where the readings are rank deficient (noise-free data). Centred ``x``
    makes ``b0`` the mean load; the penalty enters as ``sqrt(k strength) I`` rows under ``x``.

    Args:
        readings: ``Z``, ``k x p`` raw units.
        loads: ``M``, ``k x n`` load units, every row known.
        strength: the ridge strength (dimensionless: per row, on unit-variance readings), ``>= 0``.
        intercept: fit ``b`` (untared readings); else ``b = 0`` and the readings are only scaled.

    Returns:
        ``(C, b)``: ``n x p`` (load units per raw unit) and ``n`` (load units).

    Raises:
        SfmnetError: without ridge, if there are fewer rows than coefficients per axis.
    """
    k, p = readings.shape
    if strength == 0 and k < p + intercept:
        raise SfmnetError(
            f"regressing the loads on {p} channels{' and an intercept' if intercept else ''} needs at least "
            f"{p + intercept} known loads, got {k}: record more, or set ridge=true"
        )
    centre, scale = standardisation(readings, intercept)
    mean_load = loads.mean(dim=0) if intercept else torch.zeros(loads.shape[1], dtype=loads.dtype)
    design = torch.cat([(readings - centre) / scale, math.sqrt(k * strength) * torch.eye(p, dtype=readings.dtype)])
    target = torch.cat([loads - mean_load, loads.new_zeros(p, loads.shape[1])])
    slopes = torch.linalg.lstsq(design, target, driver="gelsd").solution
    matrix = (slopes / scale[:, None]).T
    return matrix, mean_load - matrix @ centre


def regression_offset(matrix: torch.Tensor, intercept: torch.Tensor) -> torch.Tensor:
    """Offsets ``o = -pinv(C) b`` that write ``load = C z + b`` as ``load = C (z - o)``.

    Any ``o`` with ``C o = -b`` does (``p > n`` leaves ``p - n`` directions free); this one is the
    minimum-norm solution, exact in load space whenever ``C`` (``n x p``) has full row rank.
    """
    return -torch.linalg.pinv(matrix) @ intercept


def regression_standard_errors(
    readings: torch.Tensor,
    loads: torch.Tensor,
    matrix: torch.Tensor,
    offset: torch.Tensor,
    strength: float,
    intercept: bool,
) -> tuple[torch.Tensor, torch.Tensor, float]:
    """Standard errors of a load regression's ``C`` and ``o``, the known loads taken as exact readings' targets.

    With standardised readings ``X`` (``k x p``, as in :func:`regress_loads`),
    ``A = X^T X + k strength I`` and the load residuals' covariance across axes
    ``Sigma = R^T R / (k - tr(A^-1 X^T X) - [intercept])``, the slopes of axes ``i, i'`` have
    covariance ``Sigma_ii' A^-1 X^T X A^-1`` (ordinary least squares: ``Sigma_ii' (X^T X)^-1``; ridge:
    the sandwich form) and the intercepts ``Sigma_ii' / k`` (centred ``X``: uncorrelated with the
    slopes). ``C``'s errors follow by the scale; ``o = -pinv(C) b`` (:func:`regression_offset`) by
    its Jacobian (the delta method: first order, so it overstates ``o``'s spread once ``C``'s
    relative errors are large, e.g. 1.6x at 10 %). Ridge's errors are the spread about the shrunk estimate (its
    bias not counted), with ``Sigma`` from residuals that hold that bias too.
    The model has no reading noise of its own; the white reading noise that would give ``Sigma``
    through ``C``, ``sigma_z^2 = mean_i Sigma_ii / (C C^T)_ii``, stands for it (raw units).

    Args:
        readings: ``Z``, ``k x p``; loads: ``M``, ``k x n``: the rows fitted.
        matrix: ``C``, ``n x p``; offset: ``o``, ``p``: the fitted calibration, ``load = C (z - o)``.
        strength, intercept: as given to :func:`regress_loads`.

    Returns:
        ``(matrix_std, offset_std, noise_std)``: ``n x p``, ``p`` (zeros without an intercept) and
        ``sigma_z``. NaN where undefined: no residual degrees of freedom, or (no ridge) readings of
        rank below ``p``.
    """
    k, p = readings.shape
    centre, scale = standardisation(readings, intercept)
    x = (readings - centre) / scale
    gram = x.T @ x
    eigenvalues = torch.linalg.eigvalsh(gram)
    nan = float("nan")
    undefined = torch.full_like(matrix, nan), torch.full_like(offset, nan if intercept else 0.0), nan
    if strength == 0 and eigenvalues[0] <= 1e-12 * eigenvalues[-1]:
        return undefined
    inverse = torch.linalg.inv(gram + k * strength * torch.eye(p, dtype=x.dtype))
    dof = k - float(torch.trace(inverse @ gram)) - intercept
    if dof <= 1e-9 * k:  # as many coefficients as rows (up to rounding): no freedom left
        return undefined
    residual = loads - (readings - offset) @ matrix.T
    sigma = residual.T @ residual / dof
    slope_cov = inverse @ gram @ inverse
    matrix_std = (sigma.diagonal()[:, None] * slope_cov.diagonal()[None, :]).sqrt() / scale
    noise_std = float((sigma.diagonal() / (matrix @ matrix.T).diagonal()).mean().sqrt())
    if not intercept:
        return matrix_std, torch.zeros_like(offset), noise_std
    n = matrix.shape[0]

    def offset_of(coefficients: torch.Tensor) -> torch.Tensor:
        """``o`` from the standardised coefficients ``[W; b0]`` (``(p + 1) x n``)."""
        c = (coefficients[:p] / scale[:, None]).T
        return regression_offset(c, coefficients[p] - c @ centre)

    coefficients = torch.cat([(matrix * scale).T, (matrix @ (centre - offset))[None]])
    jacobian = jacrev(offset_of)(coefficients).reshape(p, (p + 1) * n)
    per_axis = torch.block_diag(slope_cov, torch.tensor([[1.0 / k]], dtype=x.dtype))
    covariance = torch.kron(per_axis, sigma)
    offset_var = torch.einsum("ab,bc,ac->a", jacobian, covariance, jacobian)
    return matrix_std, offset_var.clamp_min(0).sqrt(), noise_std


def ridge_strength_by_cross_validation(
    readings: torch.Tensor, loads: torch.Tensor, strengths: torch.Tensor, folds: torch.Tensor, intercept: bool
) -> tuple[float, torch.Tensor]:
    """The ridge strength of :func:`regress_loads` with the least cross-validated load error.

    For each fold label, regress on the other rows (standardised on those rows alone) and
    predict the fold's; the error is ``sum_j sum_i ((f^_ji - f_ji) / r_i)^2`` with ``r_i`` the RMS
    load of axis ``i`` over all the rows given (so forces and torques weigh alike). Only the rows
    given are ever used: hand it the training rows.

    Args:
        readings: ``k x p``; loads: ``k x n``: the training rows.
        strengths: the grid to choose from (e.g. a log grid), each ``> 0``.
        folds: ``k`` (long), each row's fold (e.g. its pose, for leave-one-group-out), at least two labels.
        intercept: as for :func:`regress_loads`.

    Returns:
        ``(strength, errors)``: the chosen strength (the smallest on a tie) and the error per strength.
    """
    labels = folds.unique()
    if len(labels) < 2:
        raise SfmnetError("cross-validation needs at least two folds of training rows")
    axis_scale = loads.pow(2).mean(dim=0).sqrt()
    errors = torch.zeros(len(strengths), dtype=readings.dtype)
    for label in labels:
        held = folds == label
        for i, strength in enumerate(strengths.tolist()):
            matrix, bias = regress_loads(readings[~held], loads[~held], strength, intercept)
            errors[i] += ((readings[held] @ matrix.T + bias - loads[held]) / axis_scale).pow(2).sum()
    return float(strengths[int(errors.argmin())]), errors
