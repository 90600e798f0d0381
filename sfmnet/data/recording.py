"""What a calibration data module hands to the models: recordings, evaluation sweeps, and (simulated) truth."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from sfmnet.linalg.frame import MirrorHint


@dataclass(frozen=True)
class CalibrationRecording:
    """Raw readings, with the load of each row where it is known.

    Attributes:
        readings: ``f x p`` raw units.
        loads: ``f x n`` load units; NaN on the rows whose load is unknown.
        magnitude: ``F``, the constant load magnitude of the unknown rows (load units).
        mirror_hint: the bit that picks the frame's mirror side when only ``n - 1`` loads are known.
        true_loads: ``f x n``, the loads really applied, where known (simulations).
    """

    readings: torch.Tensor
    loads: torch.Tensor
    magnitude: float = float("nan")
    mirror_hint: MirrorHint | None = None
    true_loads: torch.Tensor | None = None

    @property
    def known(self) -> torch.Tensor:
        """Boolean ``f``: rows whose load is known."""
        return ~torch.isnan(self.loads).any(dim=1)

    @property
    def rank(self) -> int:
        return self.loads.shape[1]


@dataclass(frozen=True)
class EvaluationSweep:
    """A test mass turned through a full rotation (paper section 5, NOTES 7).

    Attributes:
        magnitude: the true load magnitude (load units).
        readings: ``k x p``, in the order of the rotation (so smoothing along it makes sense).
        loads: ``k x n``, the true loads.
    """

    magnitude: float
    readings: torch.Tensor
    loads: torch.Tensor


@dataclass(frozen=True)
class SensorTruth:
    """The simulated sensor's true calibration, for error metrics."""

    matrix: torch.Tensor
    offset: torch.Tensor


@dataclass
class CalibrationData:
    """Everything a calibration run reads.

    Attributes:
        recordings: by name: ``"rotation"`` (unknown orientations plus a few known loads) and,
            where available, ``"least_squares"`` (every load known).
        evaluations: test sweeps for the paper's accuracy and precision protocol.
        channels: the ``p`` raw channel names.
        axes: the ``n`` load axis names.
        load_unit: e.g. ``"gf"`` or ``"N"``.
        truth: the true calibration, where the data is simulated.
    """

    recordings: dict[str, CalibrationRecording]
    channels: list[str]
    axes: list[str]
    load_unit: str
    evaluations: list[EvaluationSweep] = field(default_factory=list)
    truth: SensorTruth | None = None
