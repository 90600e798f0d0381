"""Never silently wrong: goodness-of-fit checks, the robust loss, sensors with as many channels as axes (p = n),
calibration without known loads, and the real accelerometer stream."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import NamedTuple

import lightning as L
import numpy as np
import pytest
import torch
from hydra.utils import instantiate

import sfmnet
from sfmnet.calibration import calibration_matrix
from sfmnet.data.calibration_datamodule import FixedCalibrationDataModule
from sfmnet.data.recording import CalibrationData, CalibrationRecording
from sfmnet.simulators.simulated_sensor import FingertipDataModule
from sfmnet.simulators.simulation import circle_directions
from sfmnet.simulators.simulated_stream import simulate_stream, stream_sensor, write_stream_csv
from sfmnet.errors import SfmnetError
from sfmnet.eval.diagnostics import calibration_diagnostics
from sfmnet.eval.goodness_of_fit import (
    GAIN_SPREAD_Z, MAX_BIAS_BARS_RATIO, MAX_KNOWN_LOAD_RATIO, MAX_KNOWN_LOAD_SCALE_Z, MAX_POSE_MISFIT_RATIO,
    MAX_RELATIVE_MATRIX_STD, MAX_RELATIVE_MATRIX_STD_LEARNT_LAW, MIN_UNKNOWN_ROW_CENTRED_COVERAGE,
    MIN_UNKNOWN_ROW_COVERAGE, POSE_MISFIT_Z, SERIAL_MISFIT_Z, GoodnessOfFit, magnitude_misfit,
)
from sfmnet.linalg.channel_noise import ChannelNoise
from sfmnet.linalg.uncertainty import CalibrationUncertainty, relative_matrix_std
from sfmnet.linalg.frame import orthogonal_procrustes
from sfmnet.models.shape_from_motion import ShapeFromMotion
from sfmnet.training.learner_module import LearnerModule
from sfmnet.training.run import train
from tests.conftest import SMALL_SPHERE_GRID, compose_config, real_data



def triad_session(seed: int, rows: int = 300, snr: float = 100.0, known: int = 3) -> tuple[CalibrationRecording, torch.Tensor, torch.Tensor]:
    """An accelerometer-like triad (p = n = 3: near-orthogonal axes, equal gains, offsets) in gravity."""
    generator = torch.Generator().manual_seed(seed)
    shape = 0.1 * (torch.eye(3, dtype=torch.float64) + 0.05 * torch.randn(3, 3, generator=generator, dtype=torch.float64))
    offset = 0.2 * torch.randn(3, generator=generator, dtype=torch.float64)
    directions = torch.randn(rows, 3, generator=generator, dtype=torch.float64)
    loads = 9.81 * directions / directions.norm(dim=1, keepdim=True)
    loads[:known] = 9.81 * torch.eye(3, dtype=torch.float64)[:known]
    noise = 9.81 * float(shape.norm(dim=0).mean()) / snr
    readings = loads @ shape + offset + noise * torch.randn(rows, 3, generator=generator, dtype=torch.float64)
    given = torch.full_like(loads, math.nan)
    given[:known] = loads[:known]
    return CalibrationRecording(readings=readings, loads=given, magnitude=9.81), calibration_matrix(shape), offset


def fit(recording: CalibrationRecording, **model_options) -> ShapeFromMotion:
    channels = [f"c{i}" for i in range(recording.readings.shape[1])]
    data = CalibrationData(recordings={"rotation": recording}, channels=channels, axes=["x", "y", "z"], load_unit="N")
    datamodule = FixedCalibrationDataModule(data)
    model = ShapeFromMotion(**model_options)
    trainer = L.Trainer(
        max_epochs=5, precision="64-true", accelerator="cpu", logger=False, enable_checkpointing=False,
        enable_progress_bar=False, enable_model_summary=False,
    )
    trainer.fit(LearnerModule(model, instantiate(compose_config().optimizer)), datamodule=datamodule)
    return model


def test_error_bars_cover_the_truth_when_channels_equal_axes():
    """p = n: no residual outside the load space, so the bars rest on the constraint residuals alone: ~68 % coverage."""
    inside, residual = [], []
    for seed in range(30):
        recording, true_matrix, true_offset = triad_session(seed)
        model = fit(recording, refinement="alternation")
        bars = model.uncertainty(recording, model.fitted_loads(recording))
        inside.append(float(((model.calibration_matrix() - true_matrix).abs() <= bars.matrix_std).double().mean()))
        inside.append(float(((model.physical_offset() - true_offset).abs() <= bars.offset_std).double().mean()))
        residual.append(model.residual_rms(recording))
    assert 0.60 <= np.mean(inside) <= 0.76
    # The residual is the constraint's, not zero as a projection on the (whole) load space would make it.
    assert min(residual) > 1e-4


def test_error_bars_of_an_isotropic_sensor_are_finite_and_positive():
    """Equal singular values (a triad) and many rows once gave zero or garbage bars (SVD derivative, gauge rounding)."""
    recording, _, _ = triad_session(0, rows=20_000, known=0)
    model = fit(recording, refinement="alternation")
    bars = model.uncertainty(recording, model.fitted_loads(recording))
    relative = bars.matrix_std / model.calibration_matrix().abs().max()
    assert bool((relative > 1e-5).all()) and bool((relative < 1e-2).all())


def test_huber_loss_keeps_a_few_bad_rows_from_pulling_the_shape():
    recording, true_matrix, _ = triad_session(1, rows=400, snr=200)
    bumped = recording.readings.clone()
    # 4 % of the rows carry a bump: a large extra load.
    bumped[10:26] += torch.tensor([0.6, -0.4, 0.5], dtype=torch.float64)
    recording = CalibrationRecording(readings=bumped, loads=recording.loads, magnitude=9.81)
    errors = {}
    for robust in (None, "huber"):
        model = fit(recording, refinement="alternation", robust=robust)
        errors[robust] = float((model.calibration_matrix() - true_matrix).norm() / true_matrix.norm())
    assert errors["huber"] < errors[None] / 3


def one_row_poses(seed: int, slip: float = 1.0, bumps: int = 0) -> CalibrationRecording:
    """300 orientations of one 1 kg mass, one row each, on an 8-channel sensor: nothing to group, nothing repeated."""
    generator = np.random.default_rng(seed)
    shape, offset = generator.normal(size=(3, 8)) * 0.05, generator.normal(size=8) * 0.3
    directions = generator.normal(size=(300, 3))
    loads = 9.80665 * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    loads[150:] *= slip
    readings = loads @ shape + offset + generator.normal(scale=0.002, size=(300, 8))
    readings[10 : 10 + bumps] += generator.normal(size=(bumps, 3)) * 4 @ shape
    given = np.full((300, 3), np.nan)
    given[:3] = loads[:3]
    return CalibrationRecording(readings=torch.from_numpy(readings), loads=torch.from_numpy(given), magnitude=9.80665)


def nonlinear_poses(seed: int, nonlinearity: float = 0.0, poses: int = 30, rows: int = 100) -> tuple[CalibrationRecording, torch.Tensor]:
    """An 8-channel sensor with offsets held at ``poses`` random poses (the first three the known loads along the axes) of
    ``rows`` rows each, noise 0.05; each channel ``nonlinearity`` of its full scale from linear, an odd square law."""
    generator = np.random.default_rng(seed)
    shape, offset = generator.normal(size=(3, 8)), 2 * generator.normal(size=8)
    directions = generator.normal(size=(poses, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    directions[:3] = np.eye(3)
    loads = np.repeat(9.81 * directions, rows, axis=0)
    linear = loads @ shape
    readings = linear + nonlinearity * linear * np.abs(linear) / np.abs(linear).max(axis=0)
    readings = readings + offset + generator.normal(scale=0.05, size=linear.shape)
    given = np.full_like(loads, np.nan)
    given[: 3 * rows] = loads[: 3 * rows]
    recording = CalibrationRecording(
        readings=torch.from_numpy(readings), loads=torch.from_numpy(given), magnitude=9.81,
        groups=torch.arange(poses).repeat_interleave(rows),
    )
    return recording, calibration_matrix(torch.from_numpy(shape))


class Diagnosed(NamedTuple):
    model: ShapeFromMotion
    warnings: list[str]
    goodness: GoodnessOfFit
    uncertainty: CalibrationUncertainty


def diagnosed(recording: CalibrationRecording, **model_options) -> Diagnosed:
    """A fit (:func:`fit`) with its error bars, warnings and goodness of fit, as a calibration run computes them."""
    model = fit(recording, **model_options)
    loads = model.fitted_loads(recording)
    uncertainty = model.uncertainty(recording, loads)
    channels = [f"c{i}" for i in range(recording.readings.shape[1])]
    _, warnings, goodness = calibration_diagnostics(model, recording, channels, loads, uncertainty, "N")
    return Diagnosed(model, warnings, goodness, uncertainty)


def test_a_slipped_mass_is_flagged_with_no_repeated_pose():
    """With p > n the readings off the load space measure the noise, so the magnitudes can be judged row by row."""
    clean = diagnosed(one_row_poses(0), refinement="alternation").goodness
    assert clean.trustworthy and clean.metrics["goodness/constraint_noise_ratio"] < 1.1
    slipped = diagnosed(one_row_poses(0, slip=0.97), refinement="alternation").goodness
    assert not slipped.trustworthy and slipped.metrics["goodness/constraint_noise_ratio"] > 3


def test_poses_missing_the_model_by_more_than_chance_are_flagged_under_the_ratio_limit():
    """A sensor 0.3 % of full scale from linear, held at 30 poses: each pose's direction soaks up most of the distortion, so
    the pose means miss by only 1.1-1.2x (under the ratio's limit of 2), yet with 3000 rows the bars shrank to a sixth
    of the matrix's error. Over so many poses that small a miss is not chance; on the linear sensor it is."""
    scores = []
    for seed in range(8):
        clean = diagnosed(nonlinear_poses(seed)[0])
        assert clean.goodness.trustworthy, clean.warnings
        scores.append(clean.goodness.metrics["goodness/pose_misfit_z"])
    # A standard normal when the pose means' degrees of freedom are counted right (the global parameters left out:
    # counting them in, the mean falls to about -1.7).
    assert abs(np.mean(scores)) < 0.8 and max(scores) < POSE_MISFIT_Z, scores
    recording, truth = nonlinear_poses(0, nonlinearity=0.003)
    model, warnings, goodness, uncertainty = diagnosed(recording)
    matrix = model.calibration_matrix()
    error_over_bars = float((matrix - truth).norm()) / float(uncertainty.matrix_std.norm())
    assert error_over_bars > 4 and goodness.metrics["goodness/pose_misfit_ratio"] < MAX_POSE_MISFIT_RATIO
    assert goodness.metrics["goodness/pose_misfit_z"] > POSE_MISFIT_Z and not goodness.trustworthy
    assert any("more than chance allows over 30 poses" in warning for warning in warnings), warnings


def test_huber_error_bars_describe_the_rows_it_kept(tmp_path: Path):
    relative = {}
    for name, bumps, robust in (("clean", 0, "null"), ("bumped", 5, "huber"), ("plain", 5, "null")):
        recording = one_row_poses(1, bumps=bumps)
        table = np.concatenate([recording.readings.numpy(), recording.loads.numpy()], axis=1)
        header = ",".join([*(f"s{i}" for i in range(8)), "fx", "fy", "fz"])
        np.savetxt(tmp_path / f"{name}.csv", table, delimiter=",", header=header, comments="")
        cfg = compose_config([
            "experiment=calibrate_csv", f"data.path={tmp_path / name}.csv", "data.magnitude=9.80665", f"model.robust={robust}",
            f"model.marginal_grid={SMALL_SPHERE_GRID}",
        ])
        metrics = train(cfg, tmp_path / name)
        relative[name] = metrics["matrix_std_relative"]
        calibration = json.loads((tmp_path / name / "calibration.json").read_text())
        if robust == "huber":
            assert sorted(calibration["outlier_rows"]) == list(range(10, 15)) and calibration["error_bars_trustworthy"]
        elif bumps:
            # Pulled by the bumps, plain least squares pushes good rows off the model too.
            assert set(range(10, 15)) <= set(calibration["outlier_rows"]) and not calibration["error_bars_trustworthy"]
    # The bumps inflate plain least squares' noise; Huber's bars are those of the clean session.
    assert relative["plain"] > 2 * relative["clean"]
    assert relative["bumped"] == pytest.approx(relative["clean"], rel=0.1)


def calibrate(path: Path, run_dir: Path, *overrides: str) -> tuple[dict, dict]:
    cfg = compose_config(
        ["experiment=calibrate_csv", f"data.path={path}", "data.magnitude=9.81", "data.time_column=time", *overrides]
    )
    metrics = train(cfg, run_dir)
    return json.loads((run_dir / "calibration.json").read_text()), metrics


@pytest.fixture(scope="module")
def stream(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A continuous recording: 12 poses held 2 s, 1.5 s moves between them, the logger running throughout."""
    generator = torch.Generator().manual_seed(3)
    sensor = stream_sensor(8, 9.81, 0.01, 0.2, generator)
    recording = simulate_stream(sensor, 1.0, poses=12, rate=50.0, generator=generator)
    path = tmp_path_factory.mktemp("stream") / "stream.csv"
    write_stream_csv(recording, path)
    return path


def test_rows_in_motion_are_flagged_when_static_intervals_are_off(stream: Path, tmp_path: Path):
    calibration, metrics = calibrate(stream, tmp_path / "all", "data.static_intervals=false")
    assert calibration["error_bars_trustworthy"] is False and metrics["goodness/outliers"] > 10
    assert any("far off the model" in warning for warning in calibration["warnings"])
    calibration, metrics = calibrate(stream, tmp_path / "static")
    assert calibration["error_bars_trustworthy"] is True, calibration["warnings"]
    assert 0.8 < metrics["goodness/noise_ratio"] < 1.2 and metrics["goodness/pose_misfit_ratio"] < 2


def test_motion_the_static_detector_let_in_is_blamed_on_its_threshold(stream: Path, tmp_path: Path):
    """A hostile tester's: the outlier warning told a user who had given a time column to give one."""
    calibration, _ = calibrate(stream, tmp_path / "loose", "data.static.threshold=30")
    warnings = [warning for warning in calibration["warnings"] if "far off the model" in warning]
    assert len(warnings) == 1 and "tighten the static intervals (a lower data.static.threshold" in warnings[0]
    assert "fit only the static intervals (a time column)" not in warnings[0]


def test_a_wrong_known_load_is_flagged(stream: Path, tmp_path: Path):
    lines = stream.read_text().splitlines()
    header = lines[0].split(",")
    # Push every known load's fx by 0.8 N and re-normalise: still the magnitude, but up to 5 degrees off.
    fx = header.index("fx")
    for i, line in enumerate(lines[1:], start=1):
        cells = line.split(",")
        if cells[fx]:
            load = np.array([float(c) for c in cells[fx : fx + 3]])
            load[0] += 0.8
            load *= 9.81 / np.linalg.norm(load)
            cells[fx : fx + 3] = [f"{v:.6f}" for v in load]
            lines[i] = ",".join(cells)
    path = tmp_path / "wrong.csv"
    path.write_text("\n".join(lines) + "\n")
    calibration, metrics = calibrate(path, tmp_path / "run")
    assert metrics["goodness/known_load_ratio"] > 2.5 and calibration["error_bars_trustworthy"] is False
    assert any("known loads sit" in warning for warning in calibration["warnings"])


@pytest.mark.parametrize("tied", [True, False])
def test_no_known_loads_calibrates_up_to_a_rotation(stream: Path, tmp_path: Path, tied: bool):
    """In memory and streamed, a static interval's rows tied to one direction (the default) or each row its own."""
    no_loads = ["data.load_columns=[]", "data.axes=[x,y,z]", "data.channel_columns=[s0,s1,s2,s3,s4,s5,s6,s7]",
                f"model.tie_directions={str(tied).lower()}"]
    calibration, metrics = calibrate(stream, tmp_path / "run", *no_loads, "model.refinement=alternation")
    assert calibration["axes"] == ["x", "y", "z"] and calibration["frame"].startswith("arbitrary")
    assert calibration["load_unit"] == "N" and metrics["matrix_std_relative"] < 0.05
    streamed, _ = calibrate(stream, tmp_path / "stream", "experiment=calibrate_stream", *no_loads)
    assert streamed["method"] == "streamed_shape_from_motion"
    assert calibration["tied_directions"] is tied and streamed["tied_directions"] is tied
    # The frame is arbitrary, the metric C^T C is not: the same from memory and from the stream.
    gram = [np.array(c["matrix"]).T @ np.array(c["matrix"]) for c in (calibration, streamed)]
    assert np.abs(gram[0] - gram[1]).max() < 1e-6 * np.abs(gram[0]).max()


def test_imu_accelerometer_matches_the_triad_baseline(tmp_path: Path):
    """The real hand-held accelerometer stream: static intervals, p = n = 3, no known loads, held-out intervals."""
    real_data("imu_xsens")
    cfg = compose_config(["experiment=imu_accelerometer"])
    metrics = train(cfg, tmp_path / "imu")
    assert metrics["static/intervals"] >= 30
    ours, baseline = metrics["test/magnitude_rms"], metrics["bias_scale_misalignment/test/magnitude_rms"]
    assert ours <= 1.25 * baseline and ours < 0.005
    calibration = json.loads((tmp_path / "imu" / "calibration.json").read_text())
    assert calibration["load_unit"] == "m/s^2" and all(s > 0 for row in calibration["matrix_std"] for s in row)
    # No known load: the frame is the channels' own, each axis nearest its channel (C symmetric with positive gains),
    # so right-handed as the accelerometer's axes are, not a mirror image half the time.
    matrix = np.array(calibration["matrix"])
    assert calibration["frame"].startswith("channels") and np.linalg.det(matrix) > 0
    assert np.abs(matrix - matrix.T).max() < 1e-3 * np.abs(matrix).max() and (np.linalg.eigvalsh(matrix) > 0).all()
    # The whole stream, hand motion included, as every row was taken before: flagged, not silently wrong.
    cfg = compose_config(
        ["experiment=imu_accelerometer", "data.static_intervals=false",
         "data.held_out_intervals=false", "~baselines.bias_scale_misalignment"]
    )
    metrics = train(cfg, tmp_path / "whole")
    assert metrics["error_bars_trustworthy"] == 0 and metrics["goodness/outlier_fraction"] > 0.05


def test_known_loads_that_mirror_a_triad_are_pointed_out():
    """A hostile tester's accelerometer: every known load negated (gravity typed pointing down, where an accelerometer
    at rest reads +g up) or x and y swapped gives a mirror image that every check passes (960x and 430x the bars,
    trusted, silent). With as many channels as axes a left-handed frame is said, in the warnings."""
    rng = np.random.default_rng(5)
    shape = (np.eye(3) + 0.1 * rng.normal(size=(3, 3))) / 9.81 * 100
    directions = rng.normal(size=(30, 3))
    loads = 9.81 * np.repeat(directions / np.linalg.norm(directions, axis=1, keepdims=True), 20, axis=0)
    readings = loads @ shape + 300 * rng.normal(size=3) + 0.01 * 100 * rng.normal(size=loads.shape)
    poses = np.repeat(np.arange(30.0), 20)
    # The last two: the triad turned 40 degrees about z in its housing, the known loads given in the housing's frame.
    turn = np.array([[np.cos(0.7), -np.sin(0.7), 0.0], [np.sin(0.7), np.cos(0.7), 0.0], [0.0, 0.0, 1.0]])
    cases = ((1, [0, 1, 2], False, np.eye(3)), (-1, [0, 1, 2], True, np.eye(3)), (1, [1, 0, 2], True, np.eye(3)),
             (-1, [0, 1, 2], True, turn), (1, [0, 1, 2], False, turn))
    for sign, swap, mirrored, housing in cases:
        known = np.where((poses < 3)[:, None], sign * (loads @ housing)[:, swap], np.nan)
        calibration = sfmnet.calibrate(readings, magnitude=9.81, loads=known, poses=poses)
        said = [warning for warning in calibration.warnings if "mirror image of the channels'" in warning]
        assert bool(said) is mirrored and bool(np.linalg.det(calibration.matrix.numpy()) < 0) is mirrored
    # Two strain gauges turned every way (a fingertip) are no triad: their order has no handedness, and a negative
    # determinant says nothing (a hostile tester's clean sessions were told their frame was mirrored in about half);
    # only three channels for three axes are judged.
    for seed in range(6):
        rng = np.random.default_rng(seed)
        gauges = rng.normal(size=(2, 2)) * 100
        angles = rng.uniform(0, 2 * np.pi, 400)
        loads = 1.96 * np.c_[np.cos(angles), np.sin(angles)]
        readings = loads @ gauges + 50 * rng.normal(size=2) + 2.0 * rng.normal(size=loads.shape)
        known = np.full_like(loads, np.nan)
        known[:2] = loads[:2]
        calibration = sfmnet.calibrate(readings, magnitude=1.96, loads=known, axes=["fx", "fy"])
        assert not [warning for warning in calibration.warnings if "mirror image of the channels'" in warning]


@pytest.mark.parametrize("refinement", ["alternation", "marginal"])
def test_a_triad_without_known_loads_ends_in_the_channels_frame(refinement: str):
    """A hostile tester's magnetometer (soft iron, 300 rows on a hemisphere, noise 2 %): turned to the channels' frame
    at the closed form, the refinement turned it 7.4 degrees on, and the calibration file said "C symmetric" of a
    matrix 18 % from symmetric, its run trusted."""
    rng = np.random.default_rng(0)
    field = 48.0
    shape = (np.eye(3) + np.array([[0.3, 0.25, 0.1], [0.25, -0.2, 0.15], [0.1, 0.15, 0.4]])) / field
    directions = rng.normal(size=(300, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    directions[:, 2] = np.abs(directions[:, 2])
    clean = field * directions @ shape + np.array([3.0, -2.0, 1.5])
    readings = clean + 0.02 * np.linalg.norm(shape, axis=0).mean() * field * rng.normal(size=clean.shape)
    calibration = sfmnet.calibrate(readings, magnitude=field, axes=["x", "y", "z"], **{"model.refinement": refinement})
    matrix = calibration.matrix.numpy()
    assert calibration.extra["frame"].startswith("channels")
    assert np.abs(matrix - matrix.T).max() < 1e-9 * np.abs(matrix).max() and (np.linalg.eigvalsh(matrix) > 0).all()
    # The truth's channel frame is its symmetric polar factor: the fit lies within a fraction of a degree of it.
    truth = np.linalg.inv(shape).T
    u, _, vt = np.linalg.svd(truth)
    turn = orthogonal_procrustes(torch.from_numpy(matrix.T), torch.from_numpy((vt.T @ np.diag(np.linalg.svd(truth)[1]) @ vt).T))
    assert math.degrees(math.acos(min(1.0, (float(torch.trace(turn)) - 1) / 2))) < 1.0


def test_auto_says_when_a_long_low_snr_session_is_too_big_for_the_marginal():
    recording, _, _ = triad_session(2, rows=3_000, snr=10, known=0)
    model = ShapeFromMotion()
    model.initialise(recording)
    assert model.refinement == "alternation" and "model.refinement=marginal" in model.fit_warnings[0]
    small, _, _ = triad_session(2, rows=500, snr=10, known=0)
    model = ShapeFromMotion()
    model.initialise(small)
    assert model.refinement == "marginal" and not model.fit_warnings


def held_poses(seed: int, poses: int, rows: int = 1200, noise: float = 0.01) -> tuple[CalibrationRecording, torch.Tensor]:
    """6 channels, 3 axes, offsets: ``poses`` random orientations, each held for ``rows / poses`` rows, ``noise`` a fraction
    of the readings' spread; and the true ``C``."""
    rng = np.random.default_rng(seed)
    shape = rng.normal(size=(3, 6))
    directions = rng.normal(size=(poses, 3))
    directions = np.repeat(directions / np.linalg.norm(directions, axis=1, keepdims=True), rows // poses, axis=0)
    clean = 9.81 * directions @ shape + rng.normal(size=6)
    readings = clean + noise * clean.std() * rng.normal(size=clean.shape)
    unknown = torch.full((len(readings), 3), math.nan, dtype=torch.float64)
    return CalibrationRecording(readings=torch.from_numpy(readings), loads=unknown, magnitude=9.81), calibration_matrix(torch.from_numpy(shape))


@pytest.mark.parametrize("poses", [6, 8, 12])
def test_too_few_poses_for_the_unknowns_are_flagged_however_many_rows_repeat_them(poses: int):
    """8 orientations give 8 equations for the 9 unknowns of a 3-axis shape with offsets: a hostile tester's session
    of 8 poses x 250 rows came out 24x its error bars with no warning."""
    recording, _ = held_poses(poses, poses)
    _, warnings, goodness, _ = diagnosed(recording)
    flagged = any("distinct orientations (poses) for the 9 unknowns" in w for w in warnings)
    assert flagged == (poses < 9)
    if flagged:
        assert not goodness.trustworthy


@pytest.mark.parametrize("along_known", [False, True])
def test_a_pose_along_a_known_load_adds_no_equation(along_known: bool):
    """3 known loads (9 equations, 3 of them the frame's) and 6 held poses give 12 equations for 9 unknowns; with 3 of
    the poses along the known loads only 9, exactly the unknowns (a hostile tester's session: trusted at 2.1x its bars)."""
    rng = np.random.default_rng(4)
    shape = rng.normal(size=(3, 6))
    directions = rng.normal(size=(6, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    if along_known:
        directions[3:] = np.eye(3)
    held = np.repeat(np.concatenate([np.eye(3), directions]), 150, axis=0)
    clean = 9.81 * held @ shape + rng.normal(size=6)
    readings = clean + 0.01 * clean.std() * rng.normal(size=clean.shape)
    loads = torch.full((len(held), 3), math.nan, dtype=torch.float64)
    loads[:450] = torch.from_numpy(9.81 * held[:450])
    recording = CalibrationRecording(
        readings=torch.from_numpy(readings), loads=loads, magnitude=9.81, groups=torch.arange(len(held)) // 150
    )
    _, warnings, goodness, _ = diagnosed(recording)
    assert goodness.metrics["goodness/pose_equations"] == (9 if along_known else 10)
    assert any("only just determine the 9 unknowns" in w for w in warnings) == along_known


@pytest.mark.parametrize(
    "law, noise, samples, seed, flagged",
    [("cone", 0.3, 40, 2, True), ("hemisphere", 0.5, 150, 2, True), ("uniform", 0.15, 150, 1, False)],
)
def test_error_bars_too_large_for_first_order_theory_are_not_trusted(
    law: str, noise: float, samples: int, seed: int, flagged: bool, tmp_path: Path
):
    """Fingertip sessions at SNR 2-7 (marginal refinement): bars over 15 % of the matrix understate its error 3-5x here."""
    cfg = compose_config(
        ["experiment=fingertip", f"data.orientation_law={law}", f"data.noise_fraction={noise}",
         f"data.samples={samples}", f"seed={seed}"]
    )
    metrics = train(cfg, tmp_path / "run")
    calibration = json.loads((tmp_path / "run" / "calibration.json").read_text())
    error_over_bars = metrics["matrix_error_relative"] / metrics["matrix_std_relative"]
    assert calibration["refinement"] == "marginal"
    warned = any("first order" in warning for warning in calibration["warnings"])
    if flagged:
        # The premise: the bars are over 15 % and the error several times them; the run says so.
        assert metrics["matrix_std_relative"] > 0.15 and error_over_bars > 3
        assert warned and calibration["error_bars_trustworthy"] is False
    else:
        assert metrics["matrix_std_relative"] < 0.15 and error_over_bars < 1.5
        assert not warned and calibration["error_bars_trustworthy"] is True, calibration["warnings"]


@pytest.mark.parametrize("law, seed, flagged", [("band", 1, True), ("band", 10, True), ("hemisphere", 0, False)])
def test_bars_resting_on_a_learnt_law_of_directions_are_not_trusted_as_far(law: str, seed: int, flagged: bool):
    """The bench's 2-axis sessions at SNR 5 (96 rows, tared): bars of 11-15 % of the matrix resting on a learnt band came
    out 2.2-2.7x too small and passed the uniform law's 15 % limit; 4 % bars on a learnt hemisphere hold."""
    datamodule = FingertipDataModule(
        noise_fraction=0.2, known_loads=0, mirror_hint=False, offset_scale=0.0, orientation_law=law, seed=seed,
        errors={"angle_error_deg": 0.0}, magnitude=111.4, samples=96,
    )
    datamodule.setup()
    recording = datamodule.data.recordings["rotation"]
    model, warnings, goodness, uncertainty = diagnosed(recording, estimate_offset=False)
    assert model.learnt_orientation_law
    relative = relative_matrix_std(uncertainty.matrix_std, model.calibration_matrix())
    error_over_bars = aligned_error(model, datamodule.data.truth.matrix) / relative
    warned = any("leave out what learning the law of directions" in warning for warning in warnings)
    if flagged:
        # The premise: under the uniform law's limit, yet the error twice the bars or more.
        assert MAX_RELATIVE_MATRIX_STD_LEARNT_LAW < relative < MAX_RELATIVE_MATRIX_STD and error_over_bars > 1.8
        assert warned and not goodness.trustworthy
    else:
        assert relative < MAX_RELATIVE_MATRIX_STD_LEARNT_LAW and error_over_bars < 1.5
        assert not warned and goodness.trustworthy, warnings


def cap_session(seed: int, rows: int, cap_deg: float = 60.0, noise_fraction: float = 0.1) -> tuple[CalibrationRecording, torch.Tensor]:
    """A random 3 x 6 shape, offsets, directions uniform in a cap around one axis, noise a fraction of the readings' spread."""
    generator = torch.Generator().manual_seed(seed)
    shape = torch.randn(3, 6, generator=generator, dtype=torch.float64)
    height = 1 - (1 - math.cos(math.radians(cap_deg))) * torch.rand(rows, generator=generator, dtype=torch.float64)
    azimuth = 2 * math.pi * torch.rand(rows, generator=generator, dtype=torch.float64)
    across = (1 - height**2).sqrt()
    directions = torch.stack([across * azimuth.cos(), across * azimuth.sin(), height], dim=1)
    readings = 9.81 * directions @ shape + torch.randn(6, generator=generator, dtype=torch.float64)
    spread = float(readings.std(dim=0).mean())
    readings = readings + noise_fraction * spread * torch.randn(rows, 6, generator=generator, dtype=torch.float64)
    unknown = torch.full((rows, 3), math.nan, dtype=torch.float64)
    return CalibrationRecording(readings=readings, loads=unknown, magnitude=9.81), calibration_matrix(shape)


def aligned_error(model: ShapeFromMotion, truth: torch.Tensor) -> float:
    """Relative matrix error after the best orthogonal map of the fit's arbitrary frame onto the truth's."""
    matrix = model.calibration_matrix()
    turn = orthogonal_procrustes(matrix.T, truth.T)
    return float((turn.T @ matrix - truth).norm() / truth.norm())


def test_a_cap_of_directions_with_bars_under_the_uniform_laws_limit_is_not_trusted():
    """A 45-degree cap with offsets at direction SNR 17 (200 untied rows): the marginal learnt a law of degree 1, its bars
    of 12 % passed every other check, and its matrix came out 20x them (a hostile tester's case: 5.8x on its caps); 21x
    on this test's SMALL_SPHERE_GRID. On that grid one direction's spread is under its spacing, where auto takes the
    alternation (no valley on its fit); it is as wrong (32x its bars) and not trusted either."""
    recording, truth = cap_session(0, 200, cap_deg=45.0)
    model, warnings, goodness, uncertainty = diagnosed(recording, marginal_grid=SMALL_SPHERE_GRID, refinement="marginal")
    relative = relative_matrix_std(uncertainty.matrix_std, model.calibration_matrix())
    assert model.learnt_orientation_law and relative < MAX_RELATIVE_MATRIX_STD and aligned_error(model, truth) > 5 * relative
    assert any("leave out what learning the law of directions" in warning for warning in warnings)
    assert not goodness.trustworthy


def test_a_marginal_fit_far_from_the_alternation_beside_it_is_not_trusted():
    """A 60-degree cap with offsets at direction SNR 21.5: the marginal comes out 4.3x its bars, the alternation beside it
    4x nearer, and the two differ by more than twice the bars (4.6x, 4.4x and 2.9x on SMALL_SPHERE_GRID, used for the
    cap); on the whole sphere they agree to a fraction of one (0.17 on the default grid; 0.81 on the small one). On the
    cap auto takes the alternation, which stops on the cap's osculating valley (within its bars), so the marginal is asked for."""
    recording, truth = cap_session(2, rows=200)
    model, warnings, goodness, uncertainty = diagnosed(recording, refinement="marginal", marginal_grid=SMALL_SPHERE_GRID)
    bars = relative_matrix_std(uncertainty.matrix_std, model.calibration_matrix())
    assert model.refinement == "marginal" and aligned_error(model, truth) > 3 * bars
    assert aligned_error(model.alternation_beside(recording), truth) < aligned_error(model, truth) / 3
    assert goodness.metrics["goodness/refinement_disagreement"] > 2 and not goodness.trustworthy
    assert any("alternation fitted to the same rows differ" in warning for warning in warnings)
    # auto: the alternation stopped on the valley, 6.8 % off with bars of 9.7 %, against the marginal's 29 % (default grid).
    model, _, goodness, uncertainty = diagnosed(recording)
    bars = relative_matrix_std(uncertainty.matrix_std, model.calibration_matrix())
    assert model.refinement == "alternation" and aligned_error(model, truth) < bars and goodness.trustworthy
    sphere, truth = cap_session(0, rows=200, cap_deg=180.0, noise_fraction=0.05)
    model, _, goodness, _ = diagnosed(sphere)
    assert model.refinement == "marginal" and goodness.metrics["goodness/refinement_disagreement"] < 1
    assert goodness.trustworthy, goodness.warnings


def test_the_alternation_is_fitted_beside_marginal_fits_only_where_its_bias_is_within_its_bars():
    recording, _ = cap_session(0, rows=60, cap_deg=180.0, noise_fraction=0.3)
    model = fit(recording)
    assert model.refinement == "marginal" and model.direction_snr < 10 and model.alternation_beside(recording) is None
    recording, _ = cap_session(0, rows=60, cap_deg=180.0, noise_fraction=0.005)
    model = fit(recording)
    assert model.refinement == "alternation" and model.alternation_beside(recording) is None


def test_untied_rows_held_at_too_few_poses_for_their_error_bars_are_flagged():
    """10 poses x 60 rows for 9 unknowns at 10 % noise, each row's direction fitted on its own (the marginal): the
    bars come out too small (seeds 0-5: 3.9, 0.7, 0.7, 1.4, 3.2 and 2.7x them, RMS 2.4; this is seed 0), and the check
    fired on all six; the same rows tied to their poses, 20 poses, or a continuous 60-degree cap pass.

    The marginal's grid here is SMALL_SPHERE_GRID, not 2000 directions (the check does not look at it): seed 0 then
    comes out 4.3x its bars. One direction's spread is under that grid's spacing, where auto takes the alternation
    (seeds 0-2: 1.1, 5.8 and 3.8x its bars, none trusted), so the marginal is asked for."""
    grid = {"marginal_grid": SMALL_SPHERE_GRID}
    recording, truth = held_poses(0, 10, rows=600, noise=0.1)
    model, warnings, goodness, uncertainty = diagnosed(recording, refinement="marginal", **grid)
    bars = relative_matrix_std(uncertainty.matrix_std, model.calibration_matrix())
    assert aligned_error(model, truth) > 3 * bars
    assert any("held at only 10 orientations" in w for w in warnings) and not goodness.trustworthy
    assert goodness.metrics["goodness/pose_scatter_ratio"] < 1
    pose = torch.arange(len(recording.readings)) // 60
    warnings = diagnosed(dataclasses.replace(recording, groups=pose), **grid).warnings
    assert not any("held at only" in w for w in warnings), warnings
    warnings = diagnosed(held_poses(0, 20, rows=600, noise=0.1)[0], **grid).warnings
    assert not any("held at only" in w for w in warnings), warnings
    cap, _ = cap_session(0, rows=400, noise_fraction=0.05)
    warnings = diagnosed(cap, refinement="alternation").warnings
    assert not any("held at only" in w for w in warnings), warnings


def nearly_coplanar_known_loads(seed: int, elevation: float, rows: int = 600) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """6 channels, 3 axes with offsets, SNR 20: three known loads held one row each, 120 degrees apart in azimuth at
    ``elevation`` degrees, then ``rows`` unknown orientations uniform on the sphere. Returns readings, loads (NaN where
    unknown) and the true shape."""
    rng = np.random.default_rng(seed)
    shape = rng.normal(size=(3, 6))
    shape /= np.linalg.norm(shape, axis=0).mean()
    azimuth = np.radians([0.0, 120.0, 240.0]) + rng.uniform(0, 2 * np.pi)
    tilt = np.radians(elevation)
    known = np.stack([np.cos(azimuth) * np.cos(tilt), np.sin(azimuth) * np.cos(tilt), np.full(3, np.sin(tilt))], axis=1)
    unknown = rng.normal(size=(rows, 3))
    unknown /= np.linalg.norm(unknown, axis=1, keepdims=True)
    directions = np.vstack([known, unknown])
    readings = 9.81 * directions @ shape + 3 * rng.normal(size=6) + 9.81 / 20 * rng.normal(size=(len(directions), 6))
    loads = np.full((len(directions), 3), np.nan)
    loads[:3] = 9.81 * known
    return readings, loads, shape


@pytest.mark.parametrize(("elevation", "seed", "ambiguous"), [(2.0, 3, True), (2.0, 4, True), (40.0, 0, False), (40.0, 3, False)])
def test_known_loads_nearly_in_one_plane_do_not_fix_the_mirror(elevation: float, seed: int, ambiguous: bool, tmp_path: Path):
    """Known loads 2 degrees out of one plane (a jig turning about one axis) leave the frame's handedness to the noise:
    seeds 3 and 4 came out mirrored, 171 % and 84 % off (63x and 42x their bars), and were trusted. Spread 40 degrees out
    of it they fix it."""
    readings, loads, shape = nearly_coplanar_known_loads(seed, elevation)
    calibration = sfmnet.calibrate(readings, magnitude=9.81, loads=loads, run_dir=tmp_path / "run",
                                   **{"model.refinement": "alternation"})
    error = np.linalg.norm(calibration.matrix.numpy() - np.linalg.pinv(shape).T) / np.linalg.norm(np.linalg.pinv(shape))
    mirrored = [w for w in calibration.extra["warnings"] if w.startswith("the known loads hardly leave one plane")]
    assert bool(mirrored) == ambiguous
    assert calibration.extra["error_bars_trustworthy"] == (not ambiguous)
    assert (error > 0.5) if ambiguous else (error < 0.1)


def known_pose_session(
    seed: int, mass_error: float = 0.0, known_rows: int = 1, turntable: bool = False, height: float = 0.0
) -> tuple[CalibrationRecording, torch.Tensor]:
    """A 6-channel sensor with offsets, three known poses along the axes held ``known_rows`` rows each, then 600 rows
    of unknown load, noise 0.5 % of each channel's span, the magnitude given as 9.81 N. The mass is ``mass_error`` heavier
    than that (the known loads are its true ones); ``turntable``: the 600 rows turned about one axis (one circle, its
    directions ``height`` along the axis: 0 a great circle) instead of over the sphere."""
    generator = np.random.default_rng(seed)
    shape, offset = generator.normal(size=(3, 6)), 2 * generator.normal(size=6)
    if turntable:
        axis = np.array([0.2, 0.1, 1.0]) / np.linalg.norm([0.2, 0.1, 1.0])
        directions = circle_directions(generator.uniform(0, 2 * np.pi, 600), axis, height)
    else:
        directions = generator.normal(size=(600, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    known = np.repeat(np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), known_rows, axis=0)
    loads = 9.81 * (1 + mass_error) * np.concatenate([known, directions])
    linear = loads @ shape
    readings = linear + offset + generator.normal(size=linear.shape) * 0.005 * np.abs(linear).max(axis=0)
    given = np.full_like(loads, np.nan)
    given[: len(known)] = loads[: len(known)]
    recording = CalibrationRecording(readings=torch.from_numpy(readings), loads=torch.from_numpy(given), magnitude=9.81)
    return recording, calibration_matrix(torch.from_numpy(shape))


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("mass_error", [0.0, 0.01])
def test_a_mass_one_percent_off_the_magnitude_is_flagged_along_the_known_loads(seed: int, mass_error: float):
    """Known loads held for one row each, the mass 1 % heavier than the magnitude given: spread over every axis of every
    pose the known-load misfit reads 1.8x (under its 2.5) with the matrix 2.6-2.9x its bars; along the loads themselves
    it is one number, 5 standard deviations out (goodness.known_load_scale)."""
    recording, truth = known_pose_session(seed, mass_error)
    result = diagnosed(recording, refinement="alternation")
    metrics = result.goodness.metrics
    error_over_bars = float((result.model.calibration_matrix() - truth).norm() / result.uncertainty.matrix_std.norm())
    if mass_error:
        assert metrics["goodness/known_load_ratio"] < MAX_KNOWN_LOAD_RATIO and error_over_bars > 2
        assert metrics["goodness/known_load_scale_z"] < -MAX_KNOWN_LOAD_SCALE_Z
        assert metrics["goodness/known_load_scale_pct"] == pytest.approx(-100 * mass_error, abs=0.5)
        assert [w for w in result.goodness.warnings if w.startswith("the calibration puts the known loads")]
        assert not result.goodness.trustworthy
    else:
        assert abs(metrics["goodness/known_load_scale_z"]) < 3 and result.goodness.trustworthy


@pytest.mark.parametrize("seed", [0, 1])
def test_a_turntable_is_not_trusted_across_its_plane(seed: int):
    """The mass turned about one axis only (one great circle), three known poses of 20 rows off it: the magnitude
    constraint says nothing across the plane to first order, and the matrix is 3.5-4.5x its bars; only the unknown rows'
    own coverage (0.06-0.09 where every row's is 0.3) tells (goodness.MIN_UNKNOWN_ROW_COVERAGE). Over the sphere
    (the test above's clean sessions) it is near 1."""
    recording, truth = known_pose_session(seed, known_rows=20, turntable=True)
    result = diagnosed(recording, refinement="alternation")
    assert float((result.model.calibration_matrix() - truth).norm() / result.uncertainty.matrix_std.norm()) > 3
    assert result.goodness.metrics["goodness/unknown_row_coverage"] < MIN_UNKNOWN_ROW_COVERAGE
    assert [w.startswith("the rows of unknown load were turned nearly in one plane") for w in result.goodness.warnings] == [True]
    sphere = diagnosed(known_pose_session(seed, known_rows=20)[0], refinement="alternation")
    assert sphere.goodness.metrics["goodness/unknown_row_coverage"] > 0.9


def test_one_tilted_circle_of_orientations_is_not_trusted():
    """The mass turned about one axis only, its directions 30 degrees off the turntable's plane (a small circle), three
    known poses of 20 rows: the constant magnitude passes a pencil of ellipsoids through the circle, and the matrix is
    2.5x its bars with no other check failing; the unknown rows' coverage about their mean (0.005, where the sphere's is
    near 1) tells (goodness.MIN_UNKNOWN_ROW_CENTRED_COVERAGE). Their coverage about the origin (0.5) does not."""
    recording, truth = known_pose_session(6, known_rows=20, turntable=True, height=0.5)
    result = diagnosed(recording, refinement="alternation")
    assert float((result.model.calibration_matrix() - truth).norm() / result.uncertainty.matrix_std.norm()) > 2
    assert result.goodness.metrics["goodness/unknown_row_coverage"] > MIN_UNKNOWN_ROW_COVERAGE
    assert result.goodness.metrics["goodness/unknown_row_centred_coverage"] < MIN_UNKNOWN_ROW_CENTRED_COVERAGE
    assert [w.startswith("the rows of unknown load lie nearly on one circle") for w in result.goodness.warnings] == [True]
    sphere = diagnosed(known_pose_session(6, known_rows=20)[0], refinement="alternation")
    assert sphere.goodness.metrics["goodness/unknown_row_centred_coverage"] > 0.9 and sphere.goodness.trustworthy


def test_known_loads_placed_badly_by_one_circle_say_so():
    """A circle 45 degrees off the plane with known poses of 5 rows: the frame's fit puts a known load far from where
    the readings do, and the refusal names the circle (the unknown rows' readings about their mean barely rank 3), not
    known loads that contradict each other."""
    recording, _ = known_pose_session(1, known_rows=5, turntable=True, height=0.707)
    with pytest.raises(SfmnetError, match="^the rows of unknown load lie on one circle of orientations"):
        diagnosed(recording, refinement="alternation")


@pytest.mark.parametrize(("magnitude_error", "seed"), [(0.0, 0), (0.0, 1), (0.01, 0), (0.01, 1)])
def test_a_magnitude_the_known_loads_disagree_with_is_not_trusted(magnitude_error: float, seed: int):
    """``p = n = 3``, 600 rows on the sphere at 0.3 % noise, three known poses held 30 rows each, the magnitude given
    1 % high (within the input check's 2 %). The unknown rows fit any scale exactly, so only the known loads see it:
    1 % off at 10-13x the bars, and trusted, while the known-load check judged each row alone (1.2-1.5x). Their
    pose's rows, given one load, are averaged first now."""
    rng = np.random.default_rng(seed)
    shape, offset = rng.normal(size=(3, 3)), 5 * rng.normal(size=3)
    directions = rng.normal(size=(600, 3))
    known_directions = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    loads = 9.81 * np.vstack([np.repeat(known_directions, 30, axis=0), directions / np.linalg.norm(directions, axis=1, keepdims=True)])
    clean = loads @ shape + offset
    readings = clean + 0.003 * clean.std(axis=0).mean() * rng.normal(size=clean.shape)
    given = np.full_like(loads, np.nan)
    given[:90] = loads[:90]
    calibration = sfmnet.calibrate(readings, 9.81 * (1 + magnitude_error), given, axes=3)
    warned = any("known loads sit" in warning for warning in calibration.extra["warnings"])
    assert warned == (magnitude_error > 0) and calibration.extra["error_bars_trustworthy"] == (magnitude_error == 0)


def swept_rows(
    seed: int, defect: str = "", channels: int = 6, rows: int = 3000, seconds: float | None = None
) -> tuple[CalibrationRecording, torch.Tensor]:
    """One 1 kg mass swept continuously (no holds) over most of the sphere for ``seconds`` (default: at 100 Hz), no
    known load, noise 1 % of the signal per channel; ``defect``: "drift" (each channel's offset drifts 1 % of its full
    scale over the recording) or "nonlinear" (each channel 0.5 % of its full scale from linear, a square law)."""
    generator = np.random.default_rng(seed)
    shape, offset = generator.normal(size=(3, channels)), generator.normal(size=channels) * 5
    time = np.arange(rows) * ((seconds or rows / 100) / rows)
    elevation = 1.2 * np.sin(0.31 * time + generator.uniform(0, 2 * np.pi))
    azimuth = 0.47 * time
    loads = 9.81 * np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], 1)
    linear = loads @ shape
    scale = np.abs(linear).max(axis=0)
    readings = linear + offset
    if defect == "drift":
        readings += np.outer(time / time[-1], 0.01 * scale * generator.choice([-1, 1], size=channels))
    elif defect == "nonlinear":
        readings += 0.005 * linear**2 / scale
    noise = 0.01 * 9.81 * np.linalg.norm(shape) / math.sqrt(3 * channels)
    readings += generator.normal(scale=noise, size=readings.shape)
    recording = CalibrationRecording(
        readings=torch.from_numpy(readings), loads=torch.full((rows, 3), math.nan, dtype=torch.float64), magnitude=9.81
    )
    return recording, calibration_matrix(torch.from_numpy(shape))


def bars_ratio(result: Diagnosed, truth: torch.Tensor) -> float:
    """The matrix error over its bars, up to the frame (no known load: any orthogonal transform of the truth)."""
    matrix = result.model.calibration_matrix()
    turn = orthogonal_procrustes(truth.T, matrix.T)
    return float((turn.T @ truth - matrix).norm() / result.uncertainty.matrix_std.norm())


@pytest.mark.parametrize("defect", ["", "drift", "nonlinear"])
def test_a_continuous_sweep_that_drifts_or_bends_is_flagged_by_its_neighbouring_rows(defect):
    """Swept with no holds there are no poses to compare: a misfit the slowly turning rows share shows in their batch
    means (goodness.serial_misfit), while the clean sweep's stay within chance."""
    result = diagnosed(*swept_rows(3, defect)[:1], refinement="alternation")
    z = result.goodness.metrics["goodness/serial_misfit_z"]
    serial = [w for w in result.goodness.warnings if w.startswith("neighbouring rows miss the model together")]
    if not defect:
        assert z < SERIAL_MISFIT_Z and result.goodness.trustworthy
        assert bars_ratio(result, swept_rows(3)[1]) < 2
    else:
        # The defect matters (the bars do not cover it) and is named.
        assert bars_ratio(result, swept_rows(3, defect)[1]) > 2
        assert z > SERIAL_MISFIT_Z and serial


@pytest.mark.parametrize("defect", ["", "drift"])
def test_a_short_sweeps_slow_drift_is_flagged_by_a_few_long_batches(defect):
    """200 rows logged over a minute's sweep: a slow drift shows in means over 32 rows, of which there are only 6
    (goodness.MIN_SERIAL_BATCHES); asking for 16 batches had left only the 4-row means, and this drift at z = 1.7."""
    result = diagnosed(swept_rows(3, defect, rows=200, seconds=60)[0], refinement="alternation")
    z = result.goodness.metrics["goodness/serial_misfit_z"]
    if defect:
        assert z > SERIAL_MISFIT_Z and not result.goodness.trustworthy
        assert result.goodness.metrics["goodness/serial_batch_rows"] >= 16
    else:
        assert z < SERIAL_MISFIT_Z and result.goodness.trustworthy


@pytest.mark.parametrize("defect", ["", "drift", "nonlinear"])
def test_a_sweep_given_in_shuffled_order_is_judged_by_rows_of_neighbouring_directions(defect):
    """The sweeps above with their rows shuffled: recording order shares nothing any more (a hostile tester's shuffled
    drifting and nonlinear sweeps: 3-10x the bars, trusted), but the misfit still goes with the orientation, so rows of
    neighbouring directions share it (goodness.serial_misfit with directions)."""
    recording, truth = swept_rows(3, defect)
    order = torch.randperm(len(recording.readings), generator=torch.Generator().manual_seed(3))
    shuffled = CalibrationRecording(readings=recording.readings[order], loads=recording.loads[order], magnitude=9.81)
    result = diagnosed(shuffled, refinement="alternation")
    assert result.goodness.metrics["goodness/serial_misfit_z"] < SERIAL_MISFIT_Z
    flagged = any(w.startswith("rows of neighbouring orientations miss") for w in result.goodness.warnings)
    if defect:
        assert bars_ratio(result, truth) > 2 and flagged and not result.goodness.trustworthy
    else:
        assert bars_ratio(result, truth) < 2 and not flagged and result.goodness.trustworthy


@pytest.mark.parametrize("step", [0.0, 10.0])
def test_held_poses_quantised_more_coarsely_than_their_noise_are_flagged_without_a_time_column(step):
    """An accelerometer triad held at 30 poses x 100 rows, read in counts 10x its noise and given no time column: rows
    held still repeat one count, so no pose is found to check, and the rounding, the same for every row of a pose, does
    not average out (a hostile tester's sessions: 4-9x the bars, trusted). Consecutive rows share it (serial misfit)."""
    generator = torch.Generator().manual_seed(0)
    shape = 0.1 * (torch.eye(3, dtype=torch.float64) + 0.05 * torch.randn(3, 3, generator=generator, dtype=torch.float64))
    offset = 0.2 * torch.randn(3, generator=generator, dtype=torch.float64)
    directions = torch.randn(30, 3, generator=generator, dtype=torch.float64).repeat_interleave(100, 0)
    loads = 9.81 * directions / directions.norm(dim=1, keepdim=True)
    noise = 0.01 * 9.81 * float(shape.norm(dim=0).mean())
    readings = loads @ shape + offset + noise * torch.randn(3000, 3, generator=generator, dtype=torch.float64)
    if step:
        readings = step * noise * torch.round(readings / (step * noise))
    recording = CalibrationRecording(readings=readings, loads=torch.full_like(loads, math.nan), magnitude=9.81)
    result = diagnosed(recording, refinement="alternation")
    serial = any(w.startswith("neighbouring rows miss the model together") for w in result.goodness.warnings)
    if step:
        assert bars_ratio(result, calibration_matrix(shape)) > 2
        assert serial and not result.goodness.trustworthy
    else:
        assert bars_ratio(result, calibration_matrix(shape)) < 2
        assert not serial and result.goodness.trustworthy


@pytest.mark.parametrize("seed", [0, 3, 9, 10])
def test_held_poses_of_a_sensor_with_a_weak_axis_keep_one_magnitude(seed: int):
    """A hostile tester's 4-channel sensors with strong coupling, 12 poses held for 40 rows, noise 1 %: clean sessions
    were disowned as "the load's magnitude changes along the recording" (1.4-2.1x). Along a weak axis (here an SNR of
    10-20) a row's noise turns its own direction as it moves its magnitude, and rows weighed and regressed by their own
    directions came out biased pose by pose: the true calibration read z 4.4-5.1 in three of these four sessions.
    Neighbours' directions are free of the row's noise."""
    generator = np.random.default_rng(seed)
    shape = np.diag([1.0, 1.1, 0.9]) @ (np.eye(3) + 0.35 * generator.normal(size=(3, 3))) @ generator.normal(size=(3, 4))
    directions = generator.normal(size=(12, 3))
    loads = 9.81 * np.repeat(directions / np.linalg.norm(directions, axis=1, keepdims=True), 40, axis=0)
    noise = 0.01 * 9.81 * np.linalg.norm(shape, axis=0).mean()
    readings = loads @ shape + noise * generator.normal(size=(len(loads), 4))
    assert 9.81 * np.linalg.svd(shape, compute_uv=False)[-1] / noise < 25
    matrix = torch.from_numpy(np.linalg.pinv(shape).T)
    equal = ChannelNoise(torch.full((4,), noise**2, dtype=torch.float64), torch.zeros(4, 4, dtype=torch.float64))
    misfit = magnitude_misfit(torch.from_numpy(readings) @ matrix.T, 9.81, matrix, equal)
    assert misfit.z < SERIAL_MISFIT_Z and misfit.ratio < 1.3


def test_a_mass_that_changes_between_tumbled_rows_is_flagged(tmp_path: Path):
    """A third tester's: rows each in its own direction (tumbled, in time order), the mass 2 % heavier on the last
    30 %, a weak axis. Weighed by its neighbours' directions, which say nothing of a tumbled row's, the check no longer
    took out the calibration's own error and missed the change (z 2.0-4.8, 8 of 10 trusted); each row's own direction
    is kept where its neighbours' lies far from it."""
    rng = np.random.default_rng(1000)
    gauges = rng.normal(size=(4, 3))
    u, singular, vt = np.linalg.svd(gauges, full_matrices=False)
    gauges = u @ np.diag(np.array([1.0, 1.0, 0.12]) * singular.mean()) @ vt
    directions = rng.normal(size=(1200, 3))
    loads = 9.81 * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    loads[840:] *= 1.02
    readings = loads @ gauges.T + rng.normal(size=4) + 0.01 * np.linalg.norm(gauges, 2) * 9.81 * rng.normal(size=(1200, 4))
    calibration = sfmnet.calibrate(readings, magnitude=9.81, axes=["x", "y", "z"], run_dir=tmp_path / "run")
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["goodness/magnitude_misfit_z"] > SERIAL_MISFIT_Z and not calibration.error_bars_trustworthy
    assert any("the load's magnitude changes along the recording" in warning for warning in calibration.warnings)


def unequal_channel_noise(
    seed: int,
    spread: float,
    slip: float = 1.0,
    rows: int = 3000,
    channels: int = 8,
    amplified: int = 0,
    poses: int = 0,
    gain: float = 10.0,
    warming: float = 0.0,
) -> CalibrationRecording:
    """``channels`` channels, 3 axes, offsets, uniform orientations (``poses``: ``rows`` rows held at each of that many,
    labelled), no known load; each channel's noise (1 % of the signal on average) drawn log-uniform over a factor
    ``spread``, or (``amplified``) that many channels amplified ``gain`` times and every channel's noise 0.5 % of its span
    (an amplifier's noise grows with its gain); the last 30 % of the rows' magnitude times ``slip``; the first channel's
    gain rising by ``warming`` (a fraction) from the first row to the last, to the shape's at the end."""
    generator = np.random.default_rng(seed)
    shape, offset = generator.normal(size=(3, channels)), generator.normal(size=channels)
    shape[:, :amplified] *= gain
    directions = generator.normal(size=(poses or rows, 3))
    loads = 9.81 * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    if poses:
        loads = np.repeat(loads, rows, axis=0)
    loads[int(0.7 * len(loads)):] *= slip
    scales = np.exp(generator.uniform(0, math.log(spread), size=channels))
    noise = 0.01 * 9.81 * np.linalg.norm(shape) / math.sqrt(3 * channels) * scales / np.sqrt(np.mean(scales**2))
    if amplified:
        noise = 0.005 * np.abs(loads @ shape).max(axis=0)
    signal = loads @ shape
    signal[:, 0] *= 1 + warming * (np.linspace(0, 1, len(loads)) - 1)
    readings = signal + offset + generator.normal(size=loads.shape[:1] + (channels,)) * noise
    return CalibrationRecording(
        readings=torch.from_numpy(readings),
        loads=torch.full((len(loads), 3), math.nan, dtype=torch.float64),
        magnitude=9.81,
        groups=torch.arange(poses).repeat_interleave(rows) if poses else None,
    )


@pytest.mark.parametrize("slip", [1.0, 0.98])
def test_channels_of_unequal_noise_are_not_taken_for_a_model_that_misses(slip):
    """Channels 10x apart in noise: weighed as if equal, the off-load-space noise mispredicts the magnitudes' scatter and
    the residuals' tail (a hostile tester's clean sessions: 1.75x and 72 of 3,000 rows outlying, not trusted). Each
    channel's noise estimated from the readings off the load space (eqs. H1, H2) clears the clean session and still
    flags a mass 2 % light on 30 % of the rows."""
    result = diagnosed(unequal_channel_noise(1, 10.0, slip), refinement="alternation").goodness
    if slip == 1.0:
        assert result.trustworthy, result.warnings
        assert result.metrics["goodness/constraint_noise_ratio"] < 1.2
    else:
        assert not result.trustworthy and result.metrics["goodness/constraint_noise_ratio"] > 1.5
    assert result.metrics.get("goodness/channel_noise_max_ratio", 1.0) > 1.5  # the noisiest channel, against the RMS


@pytest.mark.parametrize("slip", [1.0, 0.98])
def test_amplified_channels_are_not_taken_for_a_model_that_misses(slip):
    """Three of 8 channels amplified 10x, each channel's noise 0.5 % of its span: the loud channels carry the load and
    are the ones the readings off the load space see least. Held near the channels' mean noise by a narrow prior, their
    noise in the load space came out 1.5-4.6x too small, and clean sessions were disowned (here 1.85x, 69 of 3,000 rows
    outlying). (H1) read with its sampling covariance and a prior the rows choose clears the clean session and still
    flags a mass 2 % light on 30 % of the rows."""
    result = diagnosed(unequal_channel_noise(0, 1.0, slip, amplified=3), refinement="alternation").goodness
    if slip == 1.0:
        assert result.trustworthy, result.warnings
        assert result.metrics["goodness/constraint_noise_ratio"] < 1.1 and result.metrics["goodness/outliers"] <= 3
    else:
        assert not result.trustworthy and result.metrics["goodness/constraint_noise_ratio"] > 1.5


@pytest.mark.parametrize("slip", [1.0, 0.98])
def test_a_mass_that_slips_partway_shows_in_recording_order_where_the_noise_cannot_judge_its_scatter(slip):
    """6 channels, noise 30x apart between channels, 500 rows: the readings off the load space barely tell the noise in
    the load space, so the magnitudes' scatter (2.1x with the slip, 3.5x its bars) cannot be told from it and the
    scatter check does not judge it (its prediction is uncertain by far more than the excess). In recording order the
    magnitudes step down where the mass slipped, whatever the noise: the means of consecutive rows' squared
    magnitudes (eq. N3) flag it. The clean twin passes both."""
    result = diagnosed(unequal_channel_noise(2, 30.0, slip, rows=500, channels=6), refinement="alternation")
    metrics = result.goodness.metrics
    order = [w for w in result.goodness.warnings if w.startswith("the load's magnitude changes along the recording")]
    if slip == 1.0:
        assert result.goodness.trustworthy, result.goodness.warnings
        assert metrics["goodness/magnitude_misfit_z"] < SERIAL_MISFIT_Z and not order
    else:
        ratio, square_sd = metrics["goodness/constraint_noise_ratio"], metrics["goodness/constraint_noise_square_sd"]
        assert ratio > 2 and ratio**2 < 1 + 4 * square_sd  # the scatter alone says nothing here
        assert metrics["goodness/magnitude_misfit_z"] > 10 and order and not result.goodness.trustworthy


@pytest.mark.parametrize("warming", [0.0, 0.03])
def test_a_channel_warming_up_is_named_by_its_residuals_along_the_recording(warming):
    """8 channels, noise 10x apart between channels, 2,000 rows in random orientations, the first channel's gain rising
    3 % over the recording (warming up): the residuals' batch means cancel and the magnitudes move by the channel's
    share of the load space alone, so the session was trusted at 4.9x its bars against the sensor at the end. The
    channel's residual off the load space projected on its own signal over consecutive rows (eq. G1) names it and how
    far its gain moved; the clean twin passes."""
    result = diagnosed(unequal_channel_noise(0, 10.0, rows=2000, warming=warming), refinement="alternation").goodness
    named = [w for w in result.warnings if "'s gain changes along the recording" in w]
    if warming == 0.0:
        assert result.trustworthy, result.warnings
        assert result.metrics["goodness/gain_misfit_z"] < SERIAL_MISFIT_Z and not named
    else:
        assert not result.trustworthy and result.metrics["goodness/gain_misfit_z"] > 2 * SERIAL_MISFIT_Z
        assert len(named) == 1 and named[0].startswith("channel c0's gain")
        assert 2.5 < result.metrics["goodness/gain_change_pct"] < 3.5  # 3.0


@pytest.mark.parametrize("warming", [0.0, 0.03])
def test_a_channel_warming_up_in_shuffled_rows_widens_its_noise_with_its_signal(warming):
    """The session above with its rows shuffled: recording order says nothing (the gain check scores 2.9, under its
    limit), and the calibration is the recording's average, 7.9x its bars from the sensor at the end. A gain spread over
    rows widens the channel's residual off the load space in proportion to its signal (eq. G2): z 8.9, and the spread
    read is the drift's own (0.87 % for a uniform 3 %, 0.88 % read). The clean twin shuffled passes."""
    recording = unequal_channel_noise(1, 10.0, rows=2000, warming=warming)
    order = torch.from_numpy(np.random.default_rng(101).permutation(2000))
    recording = dataclasses.replace(recording, readings=recording.readings[order], loads=recording.loads[order])
    result = diagnosed(recording, refinement="alternation").goodness
    named = [w for w in result.warnings if "'s noise grows with its own reading" in w]
    if warming == 0.0:
        assert result.trustworthy, result.warnings
        assert result.metrics["goodness/gain_spread_z"] < GAIN_SPREAD_Z and not named
    else:
        assert not result.trustworthy and result.metrics["goodness/gain_spread_z"] > 2 * GAIN_SPREAD_Z
        assert len(named) == 1 and named[0].startswith("channel c0's noise")
        assert 0.7 < result.metrics["goodness/gain_spread_pct"] < 1.05


@pytest.mark.parametrize("slip", [1.0, 0.99])
def test_held_poses_measure_each_channels_noise_with_few_channels_beyond_the_axes(slip):
    """5 channels for 3 axes, noise 10x apart between channels: two channels off the load space cannot tell the channels'
    noise apart (eq. H1), and taken as equal it disowned this clean session (1.32x). Rows held at 30 poses measure every
    channel's noise within them, the load space's too, so the clean session passes and a mass 1 % light on the last
    30 % of the rows is still flagged."""
    result = diagnosed(unequal_channel_noise(0, 10.0, slip, rows=100, channels=5, poses=30)).goodness
    if slip == 1.0:
        assert result.trustworthy, result.warnings
        assert result.metrics["goodness/constraint_noise_ratio"] < 1.1
    else:
        assert not result.trustworthy
        assert any(w.startswith("the load's magnitude changes along the recording") for w in result.warnings)


@pytest.mark.parametrize("seed", [0, 1])
def test_held_poses_with_amplified_channels_are_not_taken_for_a_model_that_misses(seed):
    """Two of 8 channels amplified 30x, 20 poses x 50 rows, labelled (a hostile tester's sessions: 5 of 6 clean ones
    disowned). Each row of a tied pose keeps its whole noise, the loud channels' noise across the load space too, so it
    is judged as a known load's row is (seed 1: 20 rows had been outliers); and the magnitudes' batch means, each one
    pose, are taken less what the calibration's own error does to them (seed 0: z 4.3 on a clean session)."""
    result = diagnosed(unequal_channel_noise(seed, 1.0, rows=50, channels=8, amplified=2, poses=20, gain=30.0)).goodness
    assert result.trustworthy, result.warnings
    assert result.metrics["goodness/outliers"] <= 3 and result.metrics["goodness/magnitude_misfit_z"] < SERIAL_MISFIT_Z


def test_a_slipped_mass_in_shuffled_rows_does_not_widen_its_own_test():
    """8 channels, noise 30x apart between channels, 2,000 rows shuffled, the mass 1 % light on 30 % of them: recording
    order says nothing, so the magnitudes' scatter (1.5x) is the check. How uncertain it is for the noise being
    estimated is taken at the model: taken at the rows' own squares, the slip widened it (0.42 against 0.13) and the
    session passed (a hostile tester's: 6.7-10.6x the bars at 1-2 %)."""
    recording = unequal_channel_noise(3, 30.0, 0.99, rows=2000)
    order = torch.randperm(2000, generator=torch.Generator().manual_seed(3))
    recording = dataclasses.replace(recording, readings=recording.readings[order], loads=recording.loads[order])
    result = diagnosed(recording, refinement="alternation").goodness
    assert result.metrics["goodness/constraint_noise_ratio"] > 1.4 and result.metrics["goodness/constraint_noise_square_sd"] < 0.2
    assert not result.trustworthy
    assert any(w.startswith("the rows' load magnitudes scatter") for w in result.warnings), result.warnings


@pytest.mark.parametrize("weak_axis", [0.5, 0.02])
def test_the_alternations_bias_beyond_its_bars_is_flagged_on_an_ill_conditioned_sensor(weak_axis):
    """p = n = 3 at 1 % noise: the mean SNR is ~170, but a sensor 50x weaker on one axis reads that axis at SNR ~6, where
    the alternation's bias (about 1 / SNR^2 there) is several times the bars of 3,000 rows. The first-order figure is
    within about 3x (here 5.4x predicted, 2.7x found), which is why it is a warning, not a correction."""
    generator = np.random.default_rng(2)
    turn, _ = np.linalg.qr(generator.normal(size=(3, 3)))
    shape = np.diag([1.0, 0.7, weak_axis]) @ turn
    directions = generator.normal(size=(3000, 3))
    loads = 9.81 * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    noise = 0.01 * 9.81 * np.linalg.norm(shape) / 3
    readings = loads @ shape + generator.normal(scale=noise, size=(3000, 3))
    recording = CalibrationRecording(
        readings=torch.from_numpy(readings), loads=torch.full((3000, 3), math.nan, dtype=torch.float64), magnitude=9.81
    )
    result = diagnosed(recording, refinement="alternation", estimate_offset=False)
    ratio = bars_ratio(result, calibration_matrix(torch.from_numpy(shape)))
    bias = result.goodness.metrics["goodness/bias_bars_ratio"]
    flagged = any(w.startswith("the alternation's bias") for w in result.goodness.warnings)
    if weak_axis > 0.1:
        assert ratio < 2 and bias < MAX_BIAS_BARS_RATIO and not flagged
    else:
        assert ratio > 2 and bias > MAX_BIAS_BARS_RATIO and flagged


def test_a_triads_field_that_changes_partway_is_flagged():
    """As many channels as axes, rows in every direction, the magnitude 2 % smaller on the last 30 % (a magnetometer
    carried near iron, a mass changed): the residuals' batch means cancel over directions, and with nothing off the load
    space the magnitudes' check had not run: 4 of 6 such sessions trusted at 2.4-6.8x their bars
    (`bench/goodness_checks.py`'s uniform rows with 3 channels). Each row's least-squares load, judged in recording
    order against the noise of successive rows, shows the step; the same sessions unchanged are trusted."""
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        shape = np.eye(3) + 0.1 * rng.normal(size=(3, 3))
        directions = rng.normal(size=(2000, 3))
        loads = 48.0 * directions / np.linalg.norm(directions, axis=1, keepdims=True)
        noise = rng.normal(size=loads.shape) * 0.3
        clean = loads @ shape + np.array([20.0, -35.0, 10.0]) + noise
        changed = clean.copy()
        changed[1400:] -= 0.02 * loads[1400:] @ shape
        calibration = sfmnet.calibrate(clean, 48.0, axes=["x", "y", "z"])
        assert calibration.error_bars_trustworthy, calibration.warnings
        calibration = sfmnet.calibrate(changed, 48.0, axes=["x", "y", "z"])
        assert not calibration.error_bars_trustworthy
        assert any("the load's magnitude changes along the recording" in w for w in calibration.warnings), calibration.warnings
