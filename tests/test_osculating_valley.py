"""The osculating family of a cap of directions, and the check that the likelihood is quadratic along it."""

from __future__ import annotations

import math

import pytest
import torch
from hydra.utils import instantiate

from sfmnet.data.recording import CalibrationRecording
from sfmnet.eval.diagnostics import calibration_diagnostics
from sfmnet.linalg.directions import direction_grid
from sfmnet.linalg.frame import orthogonal_procrustes
from sfmnet.linalg.osculating_valley import load_change, osculating_shape
from sfmnet.linalg.uncertainty import load_error_rms
from sfmnet.models.shape_from_motion import ShapeFromMotion
from sfmnet.training.fitting import refine_in_process
from tests.conftest import compose_config

F = 9.81


def sensor(seed: int, p: int = 6, n: int = 3) -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    return torch.randn(n, p, generator=generator, dtype=torch.float64), torch.randn(p, generator=generator, dtype=torch.float64)


def test_the_osculating_shape_keeps_the_pole_and_its_curvature():
    shape, offset = sensor(0)
    axis = torch.tensor([0.0, 0.6, 0.8], dtype=torch.float64)
    lateral = 0.3
    moved, moved_offset = osculating_shape(shape, offset, axis, lateral, 2 * lateral, F)
    loads_of = lambda z: (z - moved_offset) @ torch.linalg.pinv(moved)  # noqa: E731
    pole = F * axis @ shape + offset
    assert torch.allclose(loads_of(pole[None]), F * axis[None], atol=1e-9)
    # A load at angle t from the pole keeps |m'| = F to second order in t: the miss shrinks as t^4.
    across = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    misses = []
    for t in (0.1, 0.05):
        load = F * (math.cos(t) * axis + math.sin(t) * across)
        misses.append(abs(float(loads_of((load @ shape + offset)[None]).norm()) - F))
    assert misses[1] < misses[0] / 12
    # Off the valley (s != l^2) the miss is second order.
    moved, moved_offset = osculating_shape(shape, offset, axis, lateral, lateral, F)
    load = F * (math.cos(0.05) * axis + math.sin(0.05) * across)
    miss = abs(float((((load @ shape + offset) - moved_offset) @ torch.linalg.pinv(moved)).norm()) - F)
    assert miss > 10 * misses[1]


def test_the_load_change_is_the_rms_over_the_sphere():
    axis = torch.tensor([0.6, 0.0, 0.8], dtype=torch.float64)
    lateral, axial = math.log(1.3), math.log(0.7)
    generator = torch.Generator().manual_seed(1)
    units = torch.randn(200_000, 3, generator=generator, dtype=torch.float64)
    units = units / units.norm(dim=1, keepdim=True)
    outer = torch.outer(axis, axis)
    a = 1.3 * (torch.eye(3, dtype=torch.float64) - outer) + 0.7 * outer
    moved = F * units @ a + F * (1 - 0.7) * axis
    sampled = float((moved - F * units).pow(2).sum(dim=1).mean().sqrt()) / F
    assert load_change(axis, lateral, axial, F) == pytest.approx(sampled, rel=5e-3)


def cap_session(seed: int, half_angle_deg: float | None, rows: int = 2000, noise: float = 0.03) -> tuple[CalibrationRecording, torch.Tensor]:
    """A hostile tester's session: 6 channels, 3 axes, offsets, no known loads, directions uniform in a cap
    round the last axis (None: the whole sphere); noise a fraction of the readings' own spread."""
    generator = torch.Generator().manual_seed(seed)
    matrix = torch.randn(3, 6, generator=generator, dtype=torch.float64)
    shape = torch.linalg.pinv(matrix).T
    if half_angle_deg is None:
        directions = torch.randn(rows, 3, generator=generator, dtype=torch.float64)
    else:
        cos_min = math.cos(math.radians(half_angle_deg))
        height = cos_min + (1 - cos_min) * torch.rand(rows, generator=generator, dtype=torch.float64)
        azimuth = 2 * math.pi * torch.rand(rows, generator=generator, dtype=torch.float64)
        across = (1 - height**2).sqrt()
        directions = torch.stack([across * azimuth.cos(), across * azimuth.sin(), height], dim=1)
    directions = directions / directions.norm(dim=1, keepdim=True)
    clean = F * directions @ shape + 0.5
    spread = float((clean - clean.mean(dim=0)).pow(2).mean().sqrt())
    readings = clean + noise * spread * torch.randn(clean.shape, generator=generator, dtype=torch.float64)
    return CalibrationRecording(readings=readings, loads=torch.full((rows, 3), math.nan, dtype=torch.float64), magnitude=F), matrix


def load_error(model: ShapeFromMotion, matrix: torch.Tensor) -> float:
    """RMS load error over unit loads on the whole sphere, a fraction of ``F``, the fit's frame turned onto the truth's."""
    units = direction_grid(3, 2000)
    readings = F * units @ torch.linalg.pinv(matrix).T + 0.5
    fitted = (readings - model.physical_offset()) @ model.calibration_matrix().T
    turn = orthogonal_procrustes(fitted, F * units)
    return float((fitted @ turn - F * units).pow(2).sum(dim=1).mean().sqrt()) / F


def valley_check(recording: CalibrationRecording) -> tuple[ShapeFromMotion, float, float, list[str]]:
    model = refine_in_process(ShapeFromMotion(), recording, instantiate(compose_config().optimizer))
    loads = model.fitted_loads(recording)
    bars = model.uncertainty(recording, loads)
    metrics, warnings, _ = calibration_diagnostics(model, recording, [f"c{i}" for i in range(6)], loads, bars, "N")
    predicted = load_error_rms(model.physical_shape(), model.calibration_matrix(), bars, F)
    return model, predicted, metrics["goodness/valley_bars_ratio"], warnings


def test_a_narrow_cap_of_directions_is_rarely_silently_wrong():
    """30 degrees round one axis, offsets, no known loads: the fit lands anywhere on the osculating valley.

    The scan bounds the likelihood from above (only the valley's two scales are moved), so it can miss:
    of the sessions here wrong by over 3x what the bars predict, all are flagged but seed 5 (whose valley
    reaches 2.2x the bars, under the 2.5x limit); the right one (seed 4) is not."""
    flagged = {}
    for seed in range(6):
        recording, matrix = cap_session(seed, 30.0)
        model, predicted, _, warnings = valley_check(recording)
        error = load_error(model, matrix) / predicted
        flagged[seed] = (error, any("explain the readings as well as this one" in w for w in warnings))
    wrong = [warned for error, warned in flagged.values() if error > 3]
    # Where on the flat valley a fit stops is chaotic (seed 1 has come out 2.6x and 3.7x): count, don't list.
    assert len(wrong) >= 3 and sum(wrong) >= len(wrong) - 1, flagged
    assert not any(warned for error, warned in flagged.values() if error < 1.5), flagged


def test_directions_over_the_sphere_raise_no_valley_warning():
    # Noise 2 % of the spread: SNR 65-80, so auto fits by the alternation, whose fits the valley check scans (at 3 %,
    # SNR 44-53, seed 0 took the marginal).
    for seed in range(3):
        model, _, ratio, warnings = valley_check(cap_session(seed, None, noise=0.02)[0])
        assert model.refinement == "alternation"
        assert ratio < 1.0
        assert not any("explain the readings as well" in w for w in warnings)
