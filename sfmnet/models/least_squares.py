"""Least-squares calibration: the traditional baseline, every load known (paper section 5, method §7)."""

from __future__ import annotations

import torch

from sfmnet.data.recording import CalibrationRecording
from sfmnet.errors import SfmnetError
from sfmnet.linalg.least_squares import least_squares_shape
from sfmnet.models.linear_calibrator import Batch, LinearCalibrator, rms_norm
from sfmnet.models.losses import reconstruction_loss


def require_every_load(recording: CalibrationRecording, method: str) -> None:
    """Raise :class:`SfmnetError` unless every row of ``recording`` has its load."""
    if not bool(recording.known.all()):
        raise SfmnetError(f"{method} needs every load known, but {int((~recording.known).sum())} rows have none")


class LeastSquaresCalibration(LinearCalibrator):
    """``S, o = argmin |Z - F S - 1 o^T|^2`` with the loads ``F`` all known.

    The closed form is already the minimum, so the trainer's steps only confirm it; the model
    runs through the same trainer so that both methods are logged and saved the same way.
    """

    name = "least_squares"
    recording = "least_squares"

    def __init__(self, estimate_offset: bool = True) -> None:
        super().__init__(estimate_offset=estimate_offset)

    def initialise(self, recording: CalibrationRecording) -> None:
        require_every_load(recording, "least squares")
        shape, offset = least_squares_shape(recording.loads, recording.readings, self.estimate_offset)
        self.singular_values = torch.linalg.svdvals(recording.readings - offset)
        # One scale per axis: forces and torques differ by orders of magnitude.
        self.set_solution(shape, offset, rms_norm(recording.readings), load_scale=recording.loads.pow(2).mean(dim=0).sqrt())

    def loss(self, batch: Batch) -> dict[str, torch.Tensor]:
        _, readings, loads = batch
        terms = {
            "reconstruction": reconstruction_loss(
                readings / self.reading_scale, loads / self.load_scale, self.shape, self.offset
            )
        }
        terms["loss"] = terms["reconstruction"]
        return terms
