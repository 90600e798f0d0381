"""Each channel's noise from the readings off the load space (eq. H1): what the rows tell, and owning up to what not."""

from __future__ import annotations

import torch

from sfmnet.linalg.channel_noise import channel_noise, off_load_space_projector, within_pose_channel_noise


def off_space_noise(
    seed: int, channels: int, rows: int, variances: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``C`` (``3 x channels``, the first three channels amplified 10x), the channels' noise variances (given, or each
    channel's squared span: an amplifier's noise grows with its gain) and ``rows`` rows of that independent noise seen
    off the load space (``E = N Q``), as a fit's residuals off the load space are."""
    generator = torch.Generator().manual_seed(seed)
    shape = torch.randn(3, channels, generator=generator, dtype=torch.float64)
    shape[:, :3] *= 10
    variances = shape.square().sum(dim=0) if variances is None else variances
    matrix = torch.linalg.pinv(shape).T
    noise = torch.randn(rows, channels, generator=generator, dtype=torch.float64) * variances.sqrt()
    return matrix, noise @ off_load_space_projector(matrix), variances


def load_space_share(matrix: torch.Tensor) -> torch.Tensor:
    """The weights of the channels' variances in a load's noise, averaged over directions: ``mean_u (C^T u)^2``."""
    return matrix.square().sum(dim=0) / matrix.shape[0]


def test_loud_channels_noise_is_read_from_the_rows_within_its_error_bars():
    """Variances 100x apart, the loud channels carrying the load: each channel's error is about its own standard
    deviation (RMS over 8 channels and 4 sessions; a narrow prior about the mean noise had put the loud channels tens of
    them off), and the noise in the load space is within 10 % and 3 standard deviations."""
    variances = torch.tensor([100.0, 100.0, 100.0, 1.0, 1.0, 1.0, 1.0, 1.0], dtype=torch.float64)
    scores = []
    for seed in range(4):
        matrix, off_space, _ = off_space_noise(seed, 8, 3000, variances)
        noise = channel_noise(off_space, matrix)
        assert noise is not None
        scores.append((noise.variances - variances) / noise.covariance.diagonal().sqrt())
        weights = load_space_share(matrix)
        assert abs(float(weights @ (noise.variances - variances))) < 0.1 * float(weights @ variances)
        assert abs(float(weights @ (noise.variances - variances))) < 3 * noise.combination_sd(weights)
    rms = float(torch.stack(scores).square().mean().sqrt())
    assert 0.6 < rms < 1.5, rms


def test_what_the_rows_cannot_tell_is_not_vouched_for():
    """6 channels for 3 axes and 600 rows: as many equations as channels, the loud channels barely seen off the load
    space. Whatever the estimate of the noise in the load space, its standard deviation covers its error (40 sessions,
    noise growing with each channel's span): taken from a prior the evidence chose, it had vouched for equal noise
    there, 5.4 of its standard deviations off here and 24 in a fitted session."""
    scores = []
    for seed in range(40):
        matrix, off_space, variances = off_space_noise(seed, 6, 600)
        noise = channel_noise(off_space, matrix)
        assert noise is not None
        weights = load_space_share(matrix)
        scores.append(float(weights @ (noise.variances - variances)) / noise.combination_sd(weights))
    scores = torch.tensor(scores)
    assert float(scores.abs().max()) < 4.5 and float(scores.square().mean().sqrt()) < 1.5, scores


def test_equal_noise_stays_equal_on_a_few_hundred_rows():
    """8 channels of equal noise, 300 rows: the combinations the rows barely tell do not pick up their noise."""
    variances = torch.ones(8, dtype=torch.float64)
    for seed in range(4):
        matrix, off_space, _ = off_space_noise(seed, 8, 300, variances)
        noise = channel_noise(off_space, matrix)
        assert noise is not None
        assert float((noise.variances / noise.variances.mean() - 1).abs().max()) < 0.15, noise.variances


def test_held_poses_measure_every_channel_whole():
    """Rows held at poses: each channel's variance about its pose means, loud or quiet, in or off the load space."""
    generator = torch.Generator().manual_seed(0)
    variances = torch.tensor([100.0, 1.0, 4.0, 0.25], dtype=torch.float64)
    poses = torch.arange(40).repeat_interleave(50)
    means = 1000 * torch.randn(40, 4, generator=generator, dtype=torch.float64)
    readings = means[poses] + torch.randn(2000, 4, generator=generator, dtype=torch.float64) * variances.sqrt()
    noise = within_pose_channel_noise(readings, poses)
    assert noise is not None
    assert bool(((noise.variances / variances - 1).abs() < 0.15).all()), noise.variances
    assert within_pose_channel_noise(readings[:3], torch.arange(3)) is None
