"""The closed form of paper section 4 (method §2-4) on noise-free and degenerate data."""

from __future__ import annotations

import pytest
import torch

from sfmnet.calibration import calibration_matrix
from sfmnet.simulators.simulated_sensor import FingertipDataModule, ForceSensor3DataModule
from sfmnet.errors import SfmnetError
from sfmnet.linalg.factorisation import (
    metric_gram,
    quadratic_design,
    symmetric_from_upper,
    truncated_svd_factors,
)
from sfmnet.linalg.frame import MirrorHint, frame_rotation
from sfmnet.linalg.least_squares import least_squares_shape
from sfmnet.models.least_squares import LeastSquaresCalibration
from sfmnet.models.shape_from_motion import ShapeFromMotion


def noise_free(module_cls, rank: int, **kwargs):
    magnitude = 111.4 if rank == 2 else 9.81
    dm = module_cls(magnitude=magnitude, noise_fraction=0.0, errors={"angle_error_deg": 0.0}, **kwargs)
    dm.setup()
    return dm.data


def relative_error(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).norm() / b.norm())


@pytest.mark.parametrize(
    "module_cls,rank,known,hint",
    [
        (FingertipDataModule, 2, 1, True),
        (FingertipDataModule, 2, 2, False),
        (ForceSensor3DataModule, 3, 2, True),
        (ForceSensor3DataModule, 3, 3, False),
    ],
)
@pytest.mark.parametrize("offsets", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_closed_form_recovers_true_calibration(module_cls, rank, known, hint, offsets, seed):
    data = noise_free(
        module_cls, rank, known_loads=known, mirror_hint=hint, offset_scale=0.5 if offsets else 0.0, seed=seed
    )
    model = ShapeFromMotion(rank=rank, estimate_offset=offsets)
    model.initialise(data.recordings["rotation"])
    assert relative_error(model.calibration_matrix(), data.truth.matrix) < 1e-6
    if offsets:
        assert relative_error(model.physical_offset(), data.truth.offset) < 1e-6


def test_many_channels_closed_form_exact():
    data = noise_free(ForceSensor3DataModule, 3, channels=16, known_loads=3, mirror_hint=False)
    model = ShapeFromMotion(rank=3)
    model.initialise(data.recordings["rotation"])
    assert relative_error(model.calibration_matrix(), data.truth.matrix) < 1e-6


def test_least_squares_exact_on_noise_free_loads():
    data = noise_free(FingertipDataModule, 2, least_squares_masses=[60.4, 111.4], offset_scale=0.3)
    model = LeastSquaresCalibration(estimate_offset=True)
    model.initialise(data.recordings["least_squares"])
    assert relative_error(model.calibration_matrix(), data.truth.matrix) < 1e-9
    assert relative_error(model.physical_offset(), data.truth.offset) < 1e-9


def test_wrong_mirror_side_without_hint_is_the_mirror_image():
    """With n - 1 known loads the data cannot pick the mirror side: the hint is what does it."""
    data = noise_free(FingertipDataModule, 2, known_loads=1, mirror_hint=True)
    recording = data.recordings["rotation"]
    hint = recording.mirror_hint
    flipped = MirrorHint(sample=hint.sample, axis=hint.axis, sign=-hint.sign)
    model = ShapeFromMotion(rank=2)
    model.initialise(recording.__class__(recording.readings, recording.loads, recording.magnitude, flipped))
    mirrored = data.truth.matrix * torch.tensor([[1.0], [-1.0]], dtype=torch.float64)
    assert relative_error(model.calibration_matrix(), mirrored) < 1e-6


def test_n_minus_one_known_loads_without_hint_is_an_error():
    data = noise_free(ForceSensor3DataModule, 3, known_loads=2, mirror_hint=False)
    with pytest.raises(SfmnetError, match="mirror"):
        ShapeFromMotion(rank=3).initialise(data.recordings["rotation"])


def test_collinear_motion_is_an_error():
    data = noise_free(FingertipDataModule, 2, motion_span=1)
    with pytest.raises(SfmnetError, match="collinear or coplanar"):
        ShapeFromMotion(rank=2).initialise(data.recordings["rotation"])


def test_coplanar_motion_is_an_error_in_3d():
    data = noise_free(ForceSensor3DataModule, 3, known_loads=3, motion_span=2)
    with pytest.raises(SfmnetError, match="collinear or coplanar"):
        ShapeFromMotion(rank=3).initialise(data.recordings["rotation"])


def test_the_marginal_without_the_metric_constraint_is_refused_when_built():
    # It integrates over the unit sphere, which an unconstrained factorisation does not have (it used to fail later,
    # in initialise, on a name its noise estimate had not bound).
    with pytest.raises(SfmnetError, match="it needs metric_weight > 0"):
        ShapeFromMotion(metric_weight=0, refinement="marginal")


def test_fewer_samples_than_unknowns_is_an_error():
    data = noise_free(ForceSensor3DataModule, 3, samples=5, known_loads=3)
    with pytest.raises(SfmnetError, match="only 8 samples for 9 unknowns of the metric constraint with offsets"):
        ShapeFromMotion(rank=3).initialise(data.recordings["rotation"])


def test_indefinite_metric_is_an_error():
    # Points on the hyperbola m1^2 - m2^2 = 1: the least-squares Q is diag(1, -1).
    t = torch.linspace(-1, 1, 20, dtype=torch.float64)
    motion = torch.stack([t.cosh(), t.sinh()], dim=1)
    with pytest.raises(SfmnetError, match="positive-definite"):
        metric_gram(motion, 1.0)


def test_quadratic_design_matches_quadratic_form():
    generator = torch.Generator().manual_seed(0)
    points = torch.randn(10, 3, generator=generator, dtype=torch.float64)
    q = torch.randn(3, 3, generator=generator, dtype=torch.float64)
    q = q + q.T
    rows, cols = torch.triu_indices(3, 3)
    packed = q[rows, cols]
    assert torch.allclose(quadratic_design(points) @ packed, torch.einsum("fi,ij,fj->f", points, q, points))
    assert torch.equal(symmetric_from_upper(packed, 3), q)


def test_affine_factors_reproduce_the_best_rank_n_matrix():
    generator = torch.Generator().manual_seed(1)
    z = torch.randn(50, 6, generator=generator, dtype=torch.float64)
    factors = truncated_svd_factors(z, 2)
    u, s, vt = torch.linalg.svd(z, full_matrices=False)
    assert torch.allclose(factors.motion @ factors.shape, (u[:, :2] * s[:2]) @ vt[:2])


def test_frame_rotation_with_full_known_loads_is_procrustes():
    generator = torch.Generator().manual_seed(2)
    rotation, _ = torch.linalg.qr(torch.randn(3, 3, generator=generator, dtype=torch.float64))
    loads = torch.randn(4, 3, generator=generator, dtype=torch.float64)
    assert torch.allclose(frame_rotation(loads @ rotation.T, loads), rotation, atol=1e-12)


@pytest.mark.parametrize("axis", [0, 2])
def test_a_mirror_hint_picks_the_image_only_where_the_images_differ_in_sign(axis: int):
    """Two known loads in the x-y plane leave z free: a hint row loaded along (0.9, 0.1, 0.42) has fx > 0 in both
    mirror images, so a hint on fx cannot choose and is refused; on fz it picks the true frame (a user's hint on the
    row's largest component had silently taken the mirror image, 116 % load error)."""
    generator = torch.Generator().manual_seed(3)
    rotation, _ = torch.linalg.qr(torch.randn(3, 3, generator=generator, dtype=torch.float64))
    known = torch.tensor([[9.81, 0.0, 0.0], [0.0, 9.81, 0.0]], dtype=torch.float64)
    hint_load = torch.nn.functional.normalize(torch.tensor([[0.9, 0.1, 0.42]], dtype=torch.float64)) * 9.81
    hint = MirrorHint(sample=0, axis=axis, sign=1)
    if axis == 0:
        with pytest.raises(SfmnetError, match=r"cannot pick the mirror image: its row's load has sign \+1 on axis 0 \(0-based\)"):
            frame_rotation(known @ rotation.T, known, hint_load @ rotation.T, hint)
        # The readers pass the user's name for the axis (its load column), and the refusal uses it.
        named = MirrorHint(sample=0, axis=axis, sign=1, axis_name="fx")
        with pytest.raises(SfmnetError, match=r"has sign \+1 on axis fx in both images"):
            frame_rotation(known @ rotation.T, known, hint_load @ rotation.T, named)
    else:
        assert torch.allclose(frame_rotation(known @ rotation.T, known, hint_load @ rotation.T, hint), rotation, atol=1e-12)
        # A row loaded within the known loads' plane (a hostile tester's, in a known pose's hold): its fz is noise.
        in_plane = torch.nn.functional.normalize(torch.tensor([[0.9, 0.4, 0.03]], dtype=torch.float64)) * 9.81
        with pytest.raises(SfmnetError, match=r"cannot pick the mirror image: its row's load lies 1.7 degrees out of the known "
                           r"loads' span, where noise sets its sign on axis 2 \(0-based\)"):
            frame_rotation(known @ rotation.T, known, in_plane @ rotation.T, hint)


def test_least_squares_refuses_loads_that_do_not_span():
    loads = torch.tensor([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]], dtype=torch.float64)
    with pytest.raises(SfmnetError, match="span"):
        least_squares_shape(loads, torch.randn(3, 4, dtype=torch.float64), estimate_offset=False)


def test_calibration_matrix_inverts_shape():
    generator = torch.Generator().manual_seed(3)
    shape = torch.randn(2, 5, generator=generator, dtype=torch.float64)
    assert torch.allclose(calibration_matrix(shape) @ shape.T, torch.eye(2, dtype=torch.float64))
