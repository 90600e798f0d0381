"""Errors of a calibration on readings it was not fitted to, with their true loads."""

from __future__ import annotations

import torch

from sfmnet.calibration import Calibration
from sfmnet.linalg.group_means import group_means


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


def magnitude_errors(calibration: Calibration, readings: torch.Tensor, groups: torch.Tensor, magnitude: float) -> dict[str, float]:
    """How far each held-out group's mean load is from the known magnitude: ``|C (zbar_k - o)| - F``.

    The check needs no reference at all, only the one constant the calibration was built on (a
    mass in gravity, gravity itself for an accelerometer), and no frame: it is what an
    accelerometer calibration is judged by (IMU-TK, Tedaldi et al. 2014).

    Args:
        readings: ``k x p`` raw units; groups: ``k`` (long), e.g. each row's static interval.
        magnitude: ``F``, load units.

    Returns:
        ``magnitude_rms`` and ``magnitude_max`` (load units, over groups) and ``groups``.
    """
    means, _, counts = group_means(readings, groups)
    error = calibration.apply(means).norm(dim=1) - magnitude
    return {
        "magnitude_rms": float(error.pow(2).mean().sqrt()),
        "magnitude_max": float(error.abs().max()),
        "groups": float(len(counts)),
    }
