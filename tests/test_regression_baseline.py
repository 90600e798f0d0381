"""The load regression, least squares as practitioners calibrate (``load = C z + b``), beside the paper's form."""

from __future__ import annotations

import math

import pytest
import torch
from omegaconf import OmegaConf

from sfmnet.data.calibration_datamodule import FixedCalibrationDataModule
from sfmnet.data.recording import CalibrationData, CalibrationRecording
from sfmnet.linalg.least_squares import regress_loads, regression_offset, regression_standard_errors
from sfmnet.models.regression import LoadRegression
from sfmnet.training.cross_validation import held_out_groups, leave_one_group_out
from sfmnet.training.fitting import fit
from sfmnet.tasks.base import MethodResult
from sfmnet.tasks.calibration import against_best_baseline
from tests.conftest import compose_config

DTYPE = torch.float64


def linear_session(
    n: int, p: int, rows: int, noise: float, seed: int, groups: int = 1
) -> tuple[CalibrationRecording, torch.Tensor, torch.Tensor]:
    """Readings ``Z = M S + 1 o^T + noise`` of random loads (``rows x n``), every load known; with ``S`` and ``o``."""
    generator = torch.Generator().manual_seed(seed)
    shape = torch.randn(n, p, generator=generator, dtype=DTYPE)
    offset = torch.randn(p, generator=generator, dtype=DTYPE)
    loads = 10 * torch.randn(rows, n, generator=generator, dtype=DTYPE)
    readings = loads @ shape + offset + noise * torch.randn(rows, p, generator=generator, dtype=DTYPE)
    return CalibrationRecording(readings, loads, groups=torch.arange(rows) % groups), shape, offset


@pytest.mark.parametrize("n,p", [(3, 3), (3, 8), (6, 8)])
def test_regression_is_exact_on_noise_free_linear_data(n: int, p: int):
    recording, shape, offset = linear_session(n, p, rows=40, noise=0.0, seed=n + p)
    model = LoadRegression()
    model.initialise(recording)
    calibration = model.calibration_matrix()
    # Fresh noise-free readings: their loads come back exactly, whatever left inverse C is.
    new, _, _ = linear_session(n, p, rows=10, noise=0.0, seed=99)
    new_readings = new.loads @ shape + offset
    assert torch.allclose((new_readings - model.physical_offset()) @ calibration.T, new.loads, atol=1e-9)
    if p == n:
        # A square sensor has one calibration: C = S^-T and o.
        assert torch.allclose(calibration, torch.linalg.inv(shape).T, atol=1e-10)
        assert torch.allclose(model.physical_offset(), offset, atol=1e-9)


def test_offset_form_is_the_intercept_form():
    recording, _, _ = linear_session(3, 8, rows=30, noise=0.1, seed=1)
    matrix, intercept = regress_loads(recording.readings, recording.loads, 0.0, intercept=True)
    offset = regression_offset(matrix, intercept)
    assert torch.allclose(matrix @ offset, -intercept, atol=1e-10)
    # Ordinary least squares of [Z 1] by another route.
    design = torch.cat([recording.readings, torch.ones(30, 1, dtype=DTYPE)], dim=1)
    direct = torch.linalg.lstsq(design, recording.loads).solution
    assert torch.allclose(matrix, direct[:8].T, atol=1e-8)
    assert torch.allclose(intercept, direct[8], atol=1e-8)


def test_standard_errors_match_the_spread_over_repeated_loads():
    """Fixed readings, loads with white noise: the coefficients' spread over trials is their standard error.

    (The offsets' errors are first order: small load noise, so that the delta method applies.)
    """
    recording, _, _ = linear_session(3, 6, rows=30, noise=0.3, seed=2)
    readings = recording.readings
    true_matrix, true_intercept = regress_loads(readings, recording.loads, 0.0, intercept=True)
    generator = torch.Generator().manual_seed(3)
    matrices, offsets, matrix_stds, offset_stds = [], [], [], []
    for _ in range(600):
        loads = readings @ true_matrix.T + true_intercept + 0.05 * torch.randn(30, 3, generator=generator, dtype=DTYPE)
        matrix, intercept = regress_loads(readings, loads, 0.0, intercept=True)
        offset = regression_offset(matrix, intercept)
        matrix_std, offset_std, _ = regression_standard_errors(readings, loads, matrix, offset, 0.0, intercept=True)
        matrices.append(matrix), offsets.append(offset), matrix_stds.append(matrix_std), offset_stds.append(offset_std)
    matrix_ratio = torch.stack(matrices).std(dim=0) / torch.stack(matrix_stds).pow(2).mean(dim=0).sqrt()
    offset_ratio = torch.stack(offsets).std(dim=0) / torch.stack(offset_stds).pow(2).mean(dim=0).sqrt()
    assert matrix_ratio.min() > 0.85 and matrix_ratio.max() < 1.15
    assert offset_ratio.min() > 0.85 and offset_ratio.max() < 1.15


def test_standard_errors_undefined_without_residual_freedom():
    recording, _, _ = linear_session(3, 8, rows=9, noise=0.1, seed=4)
    model = LoadRegression()
    model.initialise(recording)
    uncertainty = model.uncertainty(recording, recording.loads)
    assert torch.isnan(uncertainty.matrix_std).all() and math.isnan(uncertainty.noise_std)


def test_regression_through_the_trainer_keeps_its_closed_form():
    recording, _, _ = linear_session(3, 8, rows=30, noise=0.1, seed=5)
    data = CalibrationData({"least_squares": recording}, [f"s{i}" for i in range(8)], ["fx", "fy", "fz"], "N")
    for ridge in (False, True):
        model = LoadRegression(ridge=ridge)
        cfg = compose_config(["trainer.max_epochs=3"])
        fit(model, cfg, FixedCalibrationDataModule(data), logger=False, enable_checkpointing=False)
        matrix, intercept = regress_loads(recording.readings, recording.loads, model.strength, intercept=True)
        assert torch.allclose(model.calibration_matrix(), matrix, rtol=1e-8, atol=1e-10)
        assert torch.allclose(model.calibration_matrix() @ model.physical_offset(), -intercept, atol=1e-8)
        assert (model.strength > 0) == ridge


# The strength each fold's model chose, in the order the folds are fitted.
CHOSEN: list[float] = []
GROUPS = 8


class RecordingRegression(LoadRegression):
    """A ridge regression that notes the strength it chose."""

    def initialise(self, recording: CalibrationRecording) -> None:
        super().initialise(recording)
        CHOSEN.append(self.strength)


def ridge_strengths_per_fold(data: CalibrationData) -> dict[int, float]:
    """``{held-out group: strength}`` from the trainer's leave-one-group-out, one ridge regression per fold."""
    CHOSEN.clear()
    cfg = compose_config(["trainer.max_epochs=1"])
    model_cfg = OmegaConf.create({"_target_": f"{__name__}.RecordingRegression", "ridge": True})
    leave_one_group_out(cfg, data, {"regression": model_cfg}, "rotation", progress=False)
    return dict(zip(held_out_groups(data, "rotation"), CHOSEN, strict=True))


def test_ridge_strength_is_chosen_without_the_held_out_group():
    """Poison one group's rows: the fold that holds it out chooses the same strength, folds that see it do not."""
    recording, _, _ = linear_session(3, 8, rows=4 * GROUPS, noise=3.0, seed=6, groups=GROUPS)
    rotation = CalibrationRecording(
        recording.readings,
        torch.where((recording.groups == 0)[:, None], recording.loads, math.nan),
        magnitude=10.0,
        groups=recording.groups,
    )
    channels = [f"s{i}" for i in range(8)]

    def data_of(least_squares: CalibrationRecording) -> CalibrationData:
        return CalibrationData({"rotation": rotation, "least_squares": least_squares}, channels, ["fx", "fy", "fz"], "N")

    clean = ridge_strengths_per_fold(data_of(recording))
    poisoned_group = 3
    poison = (recording.groups == poisoned_group)[:, None]
    generator = torch.Generator().manual_seed(7)
    wrong_loads = torch.where(poison, 50 * torch.randn(recording.loads.shape, generator=generator, dtype=DTYPE), recording.loads)
    poisoned = ridge_strengths_per_fold(data_of(CalibrationRecording(recording.readings, wrong_loads, groups=recording.groups)))
    assert sorted(clean) == list(range(1, GROUPS))  # group 0 carries the known loads: never held out
    assert poisoned[poisoned_group] == clean[poisoned_group]
    # The poison is visible to every fold that trains on it.
    assert any(poisoned[g] != clean[g] for g in clean if g != poisoned_group)


def test_every_least_squares_experiment_has_both_forms():
    for experiment in ("table1", "ft6dof", "ft_printed_sensor", "ft_printed_sensor_6dof"):
        baselines = compose_config([f"experiment={experiment}"]).baselines
        assert {"least_squares", "regression"} <= set(baselines), experiment


def test_headline_names_the_better_least_squares_form():
    def result(name: str, error: float) -> MethodResult:
        return MethodResult(name, metrics={"lopo/force_rms": error, "eval/max_error_pct": 0.1})

    results = {"shape_from_motion": result("shape_from_motion", 5.2), "least_squares": result("least_squares", 4.8)}
    results["regression"] = result("regression", 3.2)
    line = against_best_baseline(results, "shape_from_motion")
    assert "by lopo/force_rms: 5.2 against regression 3.2 (beside least_squares 4.8)" in line
