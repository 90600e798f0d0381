"""How far to trust a calibration without a reference sensor: figures and plain-language warnings."""

from __future__ import annotations

import math

import torch

from sfmnet.data.recording import CalibrationRecording
from sfmnet.models.linear_calibrator import LinearCalibrator

# Below these the data hardly supports a rank-n calibration (see README, "Diagnostics").
WARN_RANK_GAP = 3.0
WARN_COVERAGE = 0.5


def calibration_diagnostics(
    model: LinearCalibrator, recording: CalibrationRecording, channels: list[str], residuals: torch.Tensor
) -> tuple[dict[str, float], list[str]]:
    """Diagnostic metrics of a fitted model and the warnings they call for.

    Args:
        residuals: ``f x p``, from :meth:`LinearCalibrator.fitted_residuals`.

    Returns:
        ``rank_gap`` (singular value n over n+1 of the readings), ``condition_number`` (of the
        calibration matrix), ``coverage`` (shape from motion: 1 for orientations spread over
        the whole circle or sphere), ``residual_rms/<channel>`` (raw units); and warnings.
    """
    n = recording.rank
    singular = model.singular_values
    metrics: dict[str, float] = {}
    warnings: list[str] = []
    if len(singular) > n:
        metrics["rank_gap"] = float(singular[n - 1] / singular[n])
        if metrics["rank_gap"] < WARN_RANK_GAP:
            warnings.append(
                f"rank gap {metrics['rank_gap']:.2f} (< {WARN_RANK_GAP:g}): the readings are barely rank {n}; "
                "the sensor is noisy or nonlinear, or the loads do not span every axis"
            )
    matrix_singular = torch.linalg.svdvals(model.calibration_matrix())
    metrics["condition_number"] = float(matrix_singular[0] / matrix_singular[-1])
    coverage = model.coverage
    if math.isfinite(coverage):
        metrics["coverage"] = coverage
        if coverage < WARN_COVERAGE:
            warnings.append(
                f"coverage {coverage:.2f} (< {WARN_COVERAGE:g}; 1 is a full {'circle' if n == 2 else 'sphere'}): "
                "the orientations leave part of the load space unvisited; turn the mass through more of it"
            )
    residual = residuals.pow(2).mean(dim=0).sqrt()
    metrics.update({f"residual_rms/{name}": float(value) for name, value in zip(channels, residual)})
    return metrics, warnings
