"""Properties of the estimators, checked on random sensors by hypothesis (a fixed number of examples for CI)."""

from __future__ import annotations

import torch
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from sfmnet.data.recording import CalibrationRecording
from sfmnet.linalg.factorisation import metric_unknowns
from sfmnet.linalg.frame import orthogonal_procrustes
from sfmnet.models.shape_from_motion import ShapeFromMotion
from tests.test_uncertainty import refined

SETTINGS = settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
F = 2.5


def session(seed: int, n: int, p: int, noise: float, offsets: bool, known: int) -> tuple[CalibrationRecording, torch.Tensor]:
    """Random sensor (``n x p`` shape, condition number checked by the caller) and a session; returns (recording, true S)."""
    generator = torch.Generator().manual_seed(seed)
    shape = torch.randn(n, p, generator=generator, dtype=torch.float64)
    offset = torch.randn(p, generator=generator, dtype=torch.float64) * 3 if offsets else torch.zeros(p, dtype=torch.float64)
    f = 4 * metric_unknowns(n, offsets)
    directions = torch.randn(f, n, generator=generator, dtype=torch.float64)
    loads = F * directions / directions.norm(dim=1, keepdim=True)
    loads[:known] = F * torch.eye(n, dtype=torch.float64)[:known]
    readings = loads @ shape + offset + noise * torch.randn(f, p, generator=generator, dtype=torch.float64)
    believed = loads.clone()
    believed[known:] = float("nan")
    return CalibrationRecording(readings, believed, magnitude=F, true_loads=loads), shape


def aligned_error(estimate: torch.Tensor, truth: torch.Tensor) -> float:
    """Relative error of ``S`` after the best orthogonal change of load frame (none is fixed without known loads)."""
    rotation = orthogonal_procrustes(estimate.T, truth.T)
    return float((rotation.T @ estimate - truth).norm() / truth.norm())


@SETTINGS
@given(seed=st.integers(0, 10_000), n=st.sampled_from([2, 3, 6]), extra=st.integers(0, 10), offsets=st.booleans())
def test_closed_form_is_exact_on_noise_free_data(seed: int, n: int, extra: int, offsets: bool):
    p = min(16, n + extra)
    recording, shape = session(seed, n, p, noise=0.0, offsets=offsets, known=0)
    singular = torch.linalg.svdvals(shape)
    assume(singular[0] / singular[-1] < 30)
    model = ShapeFromMotion(estimate_offset=offsets)
    model.initialise(recording)
    assert aligned_error(model.physical_shape(), shape) < 1e-6


def fitted(recording: CalibrationRecording) -> ShapeFromMotion:
    return refined(ShapeFromMotion(), recording, epochs=3)


def well_conditioned(shape: torch.Tensor) -> bool:
    singular = torch.linalg.svdvals(shape)
    return bool(singular[0] / singular[-1] < 30)


@SETTINGS
@given(seed=st.integers(0, 10_000), n=st.sampled_from([2, 3]), p=st.integers(3, 16))
def test_calibration_is_unchanged_by_permuting_samples(seed: int, n: int, p: int):
    recording, shape = session(seed, n, p, noise=0.02, offsets=True, known=n)
    assume(well_conditioned(shape))
    order = torch.randperm(len(recording.readings), generator=torch.Generator().manual_seed(seed))
    permuted = CalibrationRecording(recording.readings[order], recording.loads[order], magnitude=F)
    first, second = fitted(recording), fitted(permuted)
    assert torch.allclose(first.calibration_matrix(), second.calibration_matrix(), rtol=1e-7, atol=1e-9)
    assert torch.allclose(first.physical_offset(), second.physical_offset(), rtol=1e-7, atol=1e-7)


@SETTINGS
@given(seed=st.integers(0, 10_000), n=st.sampled_from([2, 3]), p=st.integers(3, 16))
def test_calibration_turns_with_the_load_frame(seed: int, n: int, p: int):
    """Known loads given in a frame turned by ``Q``: the calibration turns with it, ``C' = Q^T C``."""
    recording, shape = session(seed, n, p, noise=0.02, offsets=True, known=n)
    assume(well_conditioned(shape))
    q, _ = torch.linalg.qr(torch.randn(n, n, generator=torch.Generator().manual_seed(seed + 1), dtype=torch.float64))
    turned = CalibrationRecording(recording.readings, recording.loads @ q, magnitude=F)
    first, second = fitted(recording), fitted(turned)
    assert torch.allclose(second.calibration_matrix(), q.T @ first.calibration_matrix(), rtol=1e-6, atol=1e-8)


@SETTINGS
@given(seed=st.integers(0, 10_000), n=st.sampled_from([2, 3]), p=st.integers(3, 16), scale=st.floats(1e-3, 1e3))
def test_calibration_scales_with_the_readings(seed: int, n: int, p: int, scale: float):
    """Readings in other units (``a z``): the matrix becomes ``C / a`` and the offsets ``a o``."""
    recording, shape = session(seed, n, p, noise=0.02, offsets=True, known=n)
    assume(well_conditioned(shape))
    scaled = CalibrationRecording(recording.readings * scale, recording.loads, magnitude=F)
    first, second = fitted(recording), fitted(scaled)
    assert torch.allclose(second.calibration_matrix() * scale, first.calibration_matrix(), rtol=1e-6, atol=1e-9)
    assert torch.allclose(second.physical_offset() / scale, first.physical_offset(), rtol=1e-6, atol=1e-8)
