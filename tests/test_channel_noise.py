"""Each channel's noise from the readings off the load space (eq. H1): what the rows tell, and owning up to what not."""

from __future__ import annotations

import numpy as np
import torch

import sfmnet
from sfmnet.linalg.channel_noise import (
    channel_noise,
    off_load_space_projector,
    residual_channel_noise,
    within_pose_channel_noise,
)


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


def magnetometer_session(seed: int, noise: list[float], rows: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """A 3-axis magnetometer turned over the sphere (48 uT, soft iron within 10 % of identity, hard-iron offsets of
    tens of uT), each channel with its own noise (uT): readings ``rows x 3`` and the true ``C = S^-1``."""
    rng = np.random.default_rng(seed)
    shape = np.eye(3) + 0.1 * rng.uniform(-1, 1, (3, 3))
    shape = (shape + shape.T) / 2
    directions = rng.normal(size=(rows, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    readings = 48.0 * directions @ shape + rng.uniform(10, 60, 3) + rng.normal(size=(rows, 3)) * np.asarray(noise)
    return readings, np.linalg.inv(shape)


def test_the_residuals_tell_each_channels_noise_where_nothing_lies_off_the_load_space():
    """As many channels as axes: a row's residual is its noise along the constant magnitude's normal, so rows at
    different directions weigh the channels differently (eq. H3). Variances 36 : 1 : 1 come back within 3 of their
    standard deviations, the loud one within 10 %, with ten rows far off the model left out, not taken for noise."""
    generator = torch.Generator().manual_seed(0)
    matrix = torch.eye(3, dtype=torch.float64) + 0.1 * torch.randn(3, 3, generator=generator, dtype=torch.float64)
    variances = torch.tensor([0.01, 0.01, 0.36], dtype=torch.float64)
    directions = torch.randn(4000, 3, generator=generator, dtype=torch.float64)
    directions /= directions.norm(dim=1, keepdim=True)
    normals = directions @ matrix
    normals /= normals.norm(dim=1, keepdim=True)
    noise = torch.randn(4000, 3, generator=generator, dtype=torch.float64) * variances.sqrt()
    squares = (normals * noise).sum(dim=1).square()
    squares[:10] += 25.0
    whole = torch.zeros(4000, dtype=torch.bool)
    estimate = residual_channel_noise(squares, matrix, whole, directions, 3.72)
    assert estimate is not None
    scores = (estimate.variances - variances) / estimate.covariance.diagonal().sqrt()
    assert bool((scores.abs() < 3).all()), scores
    assert abs(float(estimate.variances[2] / variances[2]) - 1) < 0.1, estimate.variances


def test_a_magnetometer_with_one_noisier_channel_is_not_disowned():
    """A hostile tester's magnetometers, z 2-6x noisier than x and y (as many are): taken as equal noise, the rows
    along z were called far off the model and 8 of 8 clean sessions disowned. Judged by each channel's own noise as
    the residuals tell it, they are trusted, and rows truly far off are still found."""
    for seed in (0, 1):
        readings, truth = magnetometer_session(seed, [0.1, 0.1, 0.6])
        calibration = sfmnet.calibrate(readings, 48.0, axes=["x", "y", "z"])
        assert calibration.error_bars_trustworthy, calibration.warnings
    readings, _ = magnetometer_session(2, [0.1, 0.1, 0.6])
    readings[100:110] += 8.0
    calibration = sfmnet.calibrate(readings, 48.0, axes=["x", "y", "z"])
    assert any("far off the model" in warning for warning in calibration.warnings), calibration.warnings


def test_rows_of_zeros_far_off_the_model_are_named():
    """Two read errors (every channel 0) among 2,000 magnetometer rows: too few for the outliers' allowance and under
    the noise-spread limit at p = n (1.5-4.6x), a hostile tester's sessions were trusted with bars the rows widened."""
    readings, _ = magnetometer_session(201, [0.3, 0.3, 0.3], 2000)
    clean = sfmnet.calibrate(readings, 48.0, axes=["x", "y", "z"])
    assert clean.error_bars_trustworthy, clean.warnings
    readings[500:502] = 0.0
    calibration = sfmnet.calibrate(readings, 48.0, axes=["x", "y", "z"])
    assert not calibration.error_bars_trustworthy
    assert any("read exactly 0 on every channel (rows 500, 501 of those fitted)" in w for w in calibration.warnings)


def test_known_loads_beside_a_much_noisier_channel_disown_the_bars():
    """A hostile tester's: 3 channels, one with 10x the gain and 10x the noise, three known loads along the axes. The
    bars take one noise for every channel and misjudge the frame the known loads fix: 3.9-4.3x the bars, which the
    outlier check had disowned by chance (its rows 'far off' for equal noise), and the residuals' own noise not. With
    the channels' noise alike the same sessions are trusted."""
    for gain, trusted in ((1.0, True), (10.0, False)):
        for seed in (5, 6):
            rng = np.random.default_rng(seed)
            gains = np.array([1.0, 1.0, gain])
            shape = (np.eye(3) + 0.1 * rng.normal(size=(3, 3))) * gains
            loads = rng.normal(size=(1500, 3))
            loads *= 9.81 / np.linalg.norm(loads, axis=1, keepdims=True)
            loads[:3] = 9.81 * np.eye(3)
            readings = loads @ shape + 0.1 * rng.normal(size=3) + rng.normal(size=loads.shape) * 0.01 * gains
            known = np.full_like(loads, np.nan)
            known[:3] = loads[:3]
            calibration = sfmnet.calibrate(readings, 9.81, known)
            said = [w for w in calibration.warnings if "the channels' noise differs: channel z2's is" in w]
            assert calibration.error_bars_trustworthy is trusted and bool(said) is not trusted, calibration.warnings
