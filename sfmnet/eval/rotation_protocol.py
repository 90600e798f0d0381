"""The paper's evaluation (section 5, method §7): turn each test mass once round, read |force|.

Accuracy: the mean magnitude and its error against the true load. Precision: the standard
deviation of the magnitude after a moving average removes the electrical noise, i.e. how
far the calibrated sensor is from reading the same magnitude in every direction.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from sfmnet.calibration import Calibration
from sfmnet.data.recording import EvaluationSweep


def moving_average(values: torch.Tensor, window: int) -> torch.Tensor:
    """Mean of each run of ``window`` consecutive values: ``k`` in, ``k - window + 1`` out."""
    window = max(1, min(window, len(values)))
    return F.avg_pool1d(values[None, None], kernel_size=window, stride=1)[0, 0]


def evaluate_sweep(calibration: Calibration, sweep: EvaluationSweep, window: int) -> dict[str, float]:
    """Accuracy and precision of one test mass.

    Returns:
        ``mean`` (load units), ``error_pct`` (``100 |mean - F| / F``), ``std_dev`` (of the
        smoothed magnitude, load units).
    """
    magnitude = calibration.apply(sweep.readings).norm(dim=1)
    mean = float(magnitude.mean())
    return {
        "mean": mean,
        "error_pct": 100 * abs(mean - sweep.magnitude) / sweep.magnitude,
        "std_dev": float(moving_average(magnitude, window).std()),
    }


def evaluate_sweeps(calibration: Calibration, sweeps: list[EvaluationSweep], window: int) -> dict[str, float]:
    """Flat metrics ``eval/<mass>/<figure>`` for every sweep, plus the worst error over all masses."""
    metrics: dict[str, float] = {}
    for sweep in sweeps:
        for name, value in evaluate_sweep(calibration, sweep, window).items():
            metrics[f"eval/{sweep.magnitude:g}/{name}"] = value
    if sweeps:
        metrics["eval/max_error_pct"] = max(v for k, v in metrics.items() if k.endswith("/error_pct"))
        metrics["eval/max_std_dev"] = max(v for k, v in metrics.items() if k.endswith("/std_dev"))
    return metrics
