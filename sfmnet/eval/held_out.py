"""Errors of a calibration on readings it was not fitted to, with their true loads."""

from __future__ import annotations

import torch

from sfmnet.calibration import Calibration


def load_errors(calibration: Calibration, readings: torch.Tensor, true_loads: torch.Tensor) -> dict[str, float]:
    """RMS over rows of the error vector's norm: ``force_rms`` (first up to three axes), ``torque_rms`` (the rest).

    Args:
        readings: ``k x p`` raw units; true_loads: ``k x n`` load units.
    """
    error = calibration.apply(readings) - true_loads
    metrics = {"force_rms": float(error[:, :3].pow(2).sum(dim=1).mean().sqrt())}
    if error.shape[1] > 3:
        metrics["torque_rms"] = float(error[:, 3:].pow(2).sum(dim=1).mean().sqrt())
    return metrics
