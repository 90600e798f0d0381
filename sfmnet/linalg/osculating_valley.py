"""Calibrations as likely as the fit, where a cap of directions leaves the likelihood flat: the osculating family (method §5).

Orientations crowded on one side of the sphere (a cap, an arc) trace a patch that a paraboloid fits
as well as the sphere does. Every calibration that turns the patch into another sphere of radius
``F`` with the same curvature at its centre then explains the readings about as well: with unit
axis ``a`` (the patch's mean direction), lateral scale ``l`` and axial scale ``s``

    m' = A m + F (1 - s) a,    A = l (I - a a^T) + s a a^T                                 (V1)

keeps the pole ``F a`` in place and, for ``s = l^2``, the curvature there. Error bars from the
Fisher information assume a log-likelihood quadratic over their own width; along (V1) it can
instead stay within a few nats over calibrations tens of percent apart, and a fit that stopped
anywhere on that valley reports bars that exclude the truth. :func:`valley_scan` measures the
negative log-likelihood along the valley, for the goodness of fit to compare with the error bars.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from sfmnet.linalg.motion import unit_motion

# Lateral scales from 1/VALLEY_SPAN to VALLEY_SPAN along the valley (s = l^2), VALLEY_STEPS of them; at each
# the axial scale is searched within a factor OFF_VALLEY_SPAN of l^2 either way, to OFF_VALLEY_TOLERANCE (log).
VALLEY_SPAN = 2.0
VALLEY_STEPS = 41
OFF_VALLEY_SPAN = 1.3
OFF_VALLEY_TOLERANCE = 3e-3
# The walk out from the fit along each side stops once the valley is this many nats above it.
STOP_NATS = 50.0
# Calibrations within this many nats of the fit are as likely as it (chi-square, 1 dof, 95 %: 3.84 / 2).
LIKELY_NATS = 1.92
# Rows used for the scan: an evenly spaced sample stands for longer recordings (nats scaled back up).
VALLEY_SAMPLE_ROWS = 5_000


@dataclass(frozen=True)
class ValleyScan:
    """The negative log-likelihood along the osculating family (V1), relative to the fit.

    Attributes:
        nats: ``-log L`` at each lateral scale walked (its best axial scale) minus the fit's (negative:
            more likely than the fit), the fit itself first.
        change: each point's RMS change of unit loads over the sphere (:func:`load_change`).
    """

    nats: torch.Tensor
    change: torch.Tensor

    @property
    def likely_change(self) -> float:
        """The largest load change among points as likely as the fit (within :data:`LIKELY_NATS`), a fraction of ``F``."""
        likely = self.nats <= LIKELY_NATS
        return float(self.change[likely].max()) if bool(likely.any()) else 0.0

    @property
    def better(self) -> float:
        """How many nats the best point is below the fit (0 when none is)."""
        return max(0.0, -float(self.nats.min()))


def osculating_shape(
    shape: torch.Tensor, offset: torch.Tensor, axis: torch.Tensor, log_lateral: float, log_axial: float, magnitude: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """The shape and offsets that turn each load ``m`` of ``(shape, offset)`` into ``m'`` of (V1).

    ``z = m S + o = m' S' + o'`` with ``S' = A^-T S`` and ``o' = o - b S'``, ``b = F (1 - s) a``.

    Args:
        shape: ``S``, ``n x p``; offset: ``o``, ``p``; axis: ``a``, unit ``n``.
        log_lateral, log_axial: ``log l``, ``log s``.
        magnitude: ``F``.
    """
    outer = torch.outer(axis, axis)
    lateral, axial = math.exp(log_lateral), math.exp(log_axial)
    # A is symmetric with eigenvalues l (across a) and s (along a): its inverse is the same form.
    inverse = (torch.eye(len(axis), dtype=shape.dtype) - outer) / lateral + outer / axial
    moved = inverse @ shape
    return moved, offset - magnitude * (1 - axial) * axis @ moved


def load_change(axis: torch.Tensor, log_lateral: float, log_axial: float, magnitude: float) -> float:
    """RMS of ``|m' - m| / F`` over unit loads on the sphere under (V1): ``sqrt(|A - I|_F^2 / n + (1 - s)^2)``.

    ``m' - m = (A - I) m + F (1 - s) a``; over ``m = F u``, ``u`` uniform, the cross term averages out.
    """
    n = len(axis)
    lateral, axial = math.exp(log_lateral), math.exp(log_axial)
    return math.sqrt(((n - 1) * (lateral - 1) ** 2 + (axial - 1) ** 2) / n + (1 - axial) ** 2)


def negative_log_likelihood(
    readings: torch.Tensor,
    known_readings: torch.Tensor,
    known_loads: torch.Tensor,
    shape: torch.Tensor,
    offset: torch.Tensor,
    magnitude: float,
    noise_std: float,
    weight: float | torch.Tensor = 1.0,
) -> float:
    """``(sum_j w_j min_{|u|=1} |z_j - o - F u S|^2 + sum_k |z_k - o - m_k S|^2) / (2 sigma^2)``: unknown rows ``j``
    (each at its best direction), known rows ``k``; ``w`` (scalar or ``f``) is how many rows each stands for (a
    sample of the rows, or the mean of a pose's rows, which share one direction)."""
    unknown = readings - offset
    directions = unit_motion(unknown, magnitude * shape)
    squares = (weight * (unknown - magnitude * directions @ shape).pow(2).sum(dim=1)).sum()
    squares = squares + (known_readings - offset - known_loads @ shape).pow(2).sum()
    return float(squares) / (2 * noise_std**2)


def valley_scan(
    readings: torch.Tensor,
    shape: torch.Tensor,
    offset: torch.Tensor,
    magnitude: float,
    noise_std: float,
    known_readings: torch.Tensor,
    known_loads: torch.Tensor,
    weight: float | torch.Tensor = 1.0,
) -> ValleyScan:
    """The likelihood along the osculating family (V1) of a fitted calibration.

    Walking out from the fit to either side, at each lateral scale ``l`` the axial scale is searched
    near ``l^2`` (until the valley is :data:`STOP_NATS` above the fit); each point's directions are
    re-fitted (the exact constrained least squares per row), the rest of the shape and offsets are
    not: ``nats`` bounds the profile likelihood from above, so a point found as likely as the fit is
    (at least) that likely.

    Args:
        readings: ``f x p`` unknown-load rows (raw units); shape: ``S``, ``n x p``; offset: ``o``, ``p``.
        magnitude: ``F``; noise_std: ``sigma`` per channel (raw units).
        known_readings: ``k x p``; known_loads: ``k x n`` (``k`` may be 0).
        weight: how many unknown-load rows each of ``readings`` stands for (a streamed fit's sample), or ``f``
            (the rows are the means of poses whose rows share one direction, each weighted by its row count).

    Returns:
        A :class:`ValleyScan` over (part of) ``|log l| <= log VALLEY_SPAN``.
    """
    weight = torch.broadcast_to(torch.as_tensor(weight, dtype=readings.dtype), (len(readings),))
    if len(readings) > VALLEY_SAMPLE_ROWS:
        sample = torch.linspace(0, len(readings) - 1, VALLEY_SAMPLE_ROWS).long()
        weight = weight[sample] * (weight.sum() / weight[sample].sum())
        readings = readings[sample]
    loads = (readings - offset) @ torch.linalg.pinv(shape)
    axis = weight @ loads
    axis = axis / axis.norm()

    def nats(log_lateral: float, log_axial: float) -> float:
        moved, moved_offset = osculating_shape(shape, offset, axis, log_lateral, log_axial, magnitude)
        return negative_log_likelihood(
            readings, known_readings, known_loads, moved, moved_offset, magnitude, noise_std, weight
        )

    fit = nats(0.0, 0.0)
    profile, changes = [0.0], [0.0]
    step = 2 * math.log(VALLEY_SPAN) / (VALLEY_STEPS - 1)
    for side in (1, -1):
        for k in range(1, VALLEY_STEPS // 2 + 1):
            log_lateral = side * k * step
            off, value = golden_section(lambda t: nats(log_lateral, 2 * log_lateral + t), math.log(OFF_VALLEY_SPAN))
            profile.append(value - fit)
            changes.append(load_change(axis, log_lateral, 2 * log_lateral + off, magnitude))
            if value - fit > STOP_NATS:
                break
    return ValleyScan(nats=torch.tensor(profile, dtype=torch.float64), change=torch.tensor(changes, dtype=torch.float64))


def golden_section(function: Callable[[float], float], half_width: float) -> tuple[float, float]:
    """The minimum of ``function`` on ``[-half_width, half_width]`` by golden-section search to :data:`OFF_VALLEY_TOLERANCE`:
    its argument and value."""
    ratio = (math.sqrt(5) - 1) / 2
    low, high = -half_width, half_width
    left, right = high - ratio * (high - low), low + ratio * (high - low)
    left_value, right_value = function(left), function(right)
    while high - low > OFF_VALLEY_TOLERANCE:
        if left_value < right_value:
            high, right, right_value = right, left, left_value
            left = high - ratio * (high - low)
            left_value = function(left)
        else:
            low, left, left_value = left, right, right_value
            right = low + ratio * (high - low)
            right_value = function(right)
    return (left, left_value) if left_value < right_value else (right, right_value)
