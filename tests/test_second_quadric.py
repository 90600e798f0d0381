"""Rows turned about two axes only: a second quadric through them leaves the calibration free along a family (method §5)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import sfmnet
from sfmnet.calibration import calibration_matrix
from sfmnet.eval.goodness_of_fit import MIN_SECOND_QUADRIC_RATIO
from sfmnet.linalg.frame import orthogonal_procrustes
from sfmnet.linalg.second_quadric import quadric_monomials, second_quadric_ratio
from sfmnet.simulators.simulated_sensor import ForceSensor3DataModule
from sfmnet.simulators.simulation import circle_directions

MAGNITUDE = 9.81
WARNING = "the rows of unknown load lie within"


def two_circles(generator: np.random.Generator, rows: int, heights: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """``rows x 3`` unit directions, half on each of two circles about random axes (``heights`` along them)."""
    axes = generator.normal(size=(2, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return np.concatenate(
        [circle_directions(generator.uniform(0, 2 * np.pi, rows // 2), axis, height) for axis, height in zip(axes, heights)]
    )


def uniform(generator: np.random.Generator, rows: int) -> np.ndarray:
    directions = generator.normal(size=(rows, 3))
    return directions / np.linalg.norm(directions, axis=1, keepdims=True)


@pytest.mark.parametrize("offsets", [True, False])
def test_the_ratio_is_near_one_on_two_great_circles_and_large_over_the_sphere(offsets: bool):
    """Points 2 % of the radius from two great circles (``(a^T x)(b^T x) = 0``, a quadric with or without a linear part)
    sit about their noise off it; spread over the sphere with the same noise, off every quadric but the sphere."""
    generator = np.random.default_rng(0)
    covariance = torch.eye(3, dtype=torch.float64) * 0.02**2
    for directions, expected in ((two_circles(generator, 600), (0.8, 1.25)), (uniform(generator, 600), (100, np.inf))):
        points = torch.from_numpy(directions) + 0.02 * torch.randn(600, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
        ratio = second_quadric_ratio(points, covariance, offsets)
        assert expected[0] < ratio < expected[1]


def test_two_small_circles_are_a_second_quadric_only_where_offsets_are_free():
    """Two circles off the origin, ``(a^T x - h)(b^T x - k) = 0``, have a linear part: with offsets estimated it is a
    second quadric; tared, a calibration's quadric has none (``x^T A x = 1``), and they fix it."""
    generator = np.random.default_rng(2)
    points = torch.from_numpy(two_circles(generator, 600, (0.5, -0.4)))
    points = points + 0.01 * torch.randn(600, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
    covariance = torch.eye(3, dtype=torch.float64) * 0.01**2
    assert second_quadric_ratio(points, covariance, offsets=True) < 1.5
    assert second_quadric_ratio(points, covariance, offsets=False) > 20


def test_the_monomials_gradients_are_their_derivatives():
    points = torch.randn(5, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    values, gradients = quadric_monomials(points, offsets=True)
    assert values.shape == (5, 10)
    numeric = torch.func.jacrev(lambda x: quadric_monomials(x[None], True)[0][0])
    for row in range(5):
        assert torch.allclose(gradients[row], numeric(points[row]), atol=1e-10)


KNOWN_DIRECTIONS = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def accelerometer_session(seed: int, law: str, known: bool = False) -> tuple[np.ndarray, np.ndarray | None, torch.Tensor]:
    """A 3-channel sensor with offsets (an accelerometer's algebra), 600 rows of unknown load on two great circles
    (``law`` "two circles") or over the sphere ("uniform"), noise 0.5 % of each channel's span; ``known``: three known
    poses along the axes after them, 20 rows each. The readings, the known loads (NaN where unknown; None without)
    and ``C``."""
    generator = np.random.default_rng(seed)
    shape, offset = generator.normal(size=(3, 3)), generator.normal(size=3) * 5
    directions = two_circles(generator, 600) if law == "two circles" else uniform(generator, 600)
    linear = MAGNITUDE * directions @ shape
    span = np.abs(linear).max(axis=0)
    readings = linear + offset + generator.normal(size=linear.shape) * 0.005 * span
    if not known:
        return readings, None, calibration_matrix(torch.from_numpy(shape))
    known_loads = MAGNITUDE * np.repeat(KNOWN_DIRECTIONS, 20, axis=0)
    known_readings = known_loads @ shape + offset + generator.normal(size=known_loads.shape) * 0.005 * span
    loads = np.concatenate([np.full_like(directions, np.nan), known_loads])
    return np.concatenate([readings, known_readings]), loads, calibration_matrix(torch.from_numpy(shape))


def error_over_bars(calibration: sfmnet.Calibration, truth: torch.Tensor) -> float:
    """The matrix error over its bars (Frobenius), the truth turned into the fit's frame (no known loads fix it)."""
    matrix = calibration.matrix.to(truth.dtype)
    turn = orthogonal_procrustes(truth.T, matrix.T)
    return float((turn.T @ truth - matrix).norm() / calibration.matrix_std.to(truth.dtype).norm())


def test_an_accelerometer_turned_about_two_axes_is_not_trusted(tmp_path):
    """600 rows on two great circles, no known loads, 3 channels (a hostile tester's session): the alternation stops
    somewhere along the family the two circles leave free, 6.5x its bars, where every other check passes. The rows lie
    within their noise of the second quadric (1.2x), and the run says so. The same sensor turned over the whole sphere
    is trusted, its rows 21x their noise off any second quadric (a sensor of condition number 47, whose weakest axis's
    noise sets that)."""
    options = {"model.refinement": "alternation"}
    readings, _, truth = accelerometer_session(3, "two circles")
    calibration = sfmnet.calibrate(readings, MAGNITUDE, axes=3, run_dir=tmp_path / "two", **options)
    assert error_over_bars(calibration, truth) > 4
    assert [w.startswith(WARNING) for w in calibration.warnings] == [True]
    assert not calibration.error_bars_trustworthy
    readings, _, truth = accelerometer_session(3, "uniform")
    sphere = sfmnet.calibrate(readings, MAGNITUDE, axes=3, run_dir=tmp_path / "sphere", **options)
    assert sphere.error_bars_trustworthy and error_over_bars(sphere, truth) < 2
    metrics = json.loads((tmp_path / "sphere" / "metrics.json").read_text())
    assert metrics["goodness/second_quadric_ratio"] > 5 * MIN_SECOND_QUADRIC_RATIO


def test_known_loads_pin_the_family_and_the_ratio_is_not_asked(tmp_path):
    """The same two circles with three known poses along the axes: the known loads fix the calibration along the
    family (eq. Q1), their information counted in the bars, so the check does not run, and the bars hold."""
    readings, loads, truth = accelerometer_session(3, "two circles", known=True)
    calibration = sfmnet.calibrate(readings, MAGNITUDE, loads, run_dir=tmp_path / "run", **{"model.refinement": "alternation"})
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert "goodness/second_quadric_ratio" not in metrics
    error = float((calibration.matrix.to(truth.dtype) - truth).norm() / calibration.matrix_std.to(truth.dtype).norm())
    assert error < 2


def unequal_noise_session(seed: int) -> tuple[np.ndarray, torch.Tensor]:
    """A hostile tester's session: 1,000 rows on two perpendicular great circles, 6 channels, one with 4x the others'
    span, each channel's noise 2 % of its span (so 4x the others' on that one). The readings and ``C``."""
    generator = np.random.default_rng(seed)
    turn, _ = np.linalg.qr(generator.standard_normal((3, 3)))
    directions = []
    for axis in turn[:2]:
        first = np.cross(axis, generator.standard_normal(3))
        first /= np.linalg.norm(first)
        angles = generator.uniform(0, 2 * np.pi, 500)
        directions.append(np.cos(angles)[:, None] * first + np.sin(angles)[:, None] * np.cross(axis, first))
    shape = generator.standard_normal((3, 6))
    shape[:, 0] *= 4
    offset = generator.uniform(-5, 5, 6)
    span = 2 * MAGNITUDE * np.linalg.norm(shape, axis=0)
    readings = MAGNITUDE * np.concatenate(directions) @ shape + offset + generator.standard_normal((1000, 6)) * 0.02 * span
    return readings, calibration_matrix(torch.from_numpy(shape))


def test_each_channels_own_noise_places_the_rows_off_the_second_quadric(tmp_path):
    """Channels of unequal noise taken as one noise misplace it across the load space: on the tester's session (the
    matrix 70x its bars) the ratio with one noise for all reads 2.3, over the limit; with each channel's noise (the
    readings off the load space tell the six channels apart) 1.25. Other checks disown this session too (the fit had
    not converged, and its rows span the sphere poorly); here the ratio is what is tested."""
    readings, truth = unequal_noise_session(70003)
    calibration = sfmnet.calibrate(readings, MAGNITUDE, axes=3, run_dir=tmp_path / "run", **{"model.refinement": "alternation"})
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    matrix = calibration.matrix.to(torch.float64)
    points = (torch.from_numpy(readings) - calibration.offset.to(torch.float64)) @ matrix.T / MAGNITUDE
    one_noise = calibration.extra["noise_std"] ** 2 * matrix @ matrix.T / MAGNITUDE**2
    assert second_quadric_ratio(points, one_noise, offsets=True) > MIN_SECOND_QUADRIC_RATIO
    assert metrics["goodness/second_quadric_ratio"] < 1.5
    assert any(w.startswith(WARNING) for w in calibration.warnings) and error_over_bars(calibration, truth) > 5


def three_channel_session(law: str, snr: float, seed: int) -> tuple[np.ndarray, torch.Tensor]:
    """``bench/crb_ratio.py --laws --p-equals-n``'s session: a 3-channel sensor with offsets (10 % of the signal), 200
    rows of unknown load drawn from ``law``, white noise at ``snr``. The readings and ``C``."""
    datamodule = ForceSensor3DataModule(
        magnitude=MAGNITUDE, samples=200, channels=3, noise_fraction=1 / snr, known_loads=0, mirror_hint=False,
        offset_scale=0.1, orientation_law=law, seed=seed, errors={"angle_error_deg": 0.0},
    )
    datamodule.setup()
    return datamodule.data.recordings["rotation"].readings.numpy(), datamodule.data.truth.matrix


def test_a_marginal_fit_on_rows_near_a_second_quadric_is_not_trusted(tmp_path):
    """3 channels over a 60-degree cone at SNR 50 (the bench's seed 0): ``auto`` takes the marginal, whose law learnt
    on the rows leaves the calibration free along a family much as two circles do, and it stops 6.7x its bars with
    every other check passing. Its rows read 1.3 (the fit's noise puts its SNR near 50, where the check has power), and
    the run says so. The bench's rows over the sphere at SNR 20 (seed 2) read 16 and keep their trusted bars; at SNR 5
    every quadric is within the noise (they read 1.5, with bars that hold), and the check does not run."""
    readings, truth = three_channel_session("cone", 50, 0)
    calibration = sfmnet.calibrate(readings, MAGNITUDE, axes=3, run_dir=tmp_path / "cone")
    assert calibration.extra["refinement"] == "marginal"
    assert error_over_bars(calibration, truth) > 4
    assert [w.startswith(WARNING) for w in calibration.warnings] == [True]
    assert not calibration.error_bars_trustworthy
    readings, truth = three_channel_session("uniform", 20, 2)
    sphere = sfmnet.calibrate(readings, MAGNITUDE, axes=3, run_dir=tmp_path / "sphere")
    assert sphere.extra["refinement"] == "marginal"
    assert sphere.error_bars_trustworthy and error_over_bars(sphere, truth) < 2
    metrics = json.loads((tmp_path / "sphere" / "metrics.json").read_text())
    assert metrics["goodness/second_quadric_ratio"] > 5 * MIN_SECOND_QUADRIC_RATIO
    readings, truth = three_channel_session("uniform", 5, 2)
    noisy = sfmnet.calibrate(readings, MAGNITUDE, axes=3, run_dir=tmp_path / "noisy")
    assert noisy.extra["refinement"] == "marginal"
    assert noisy.error_bars_trustworthy and error_over_bars(noisy, truth) < 2
    assert "goodness/second_quadric_ratio" not in json.loads((tmp_path / "noisy" / "metrics.json").read_text())
