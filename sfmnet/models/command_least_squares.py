"""Least squares from standardised sensors to commands: the baseline beside the primordial learners."""

from __future__ import annotations

import torch
from torch import nn

from sfmnet.data.sensorimotor import SensorimotorData
from sfmnet.models.sensorimotor_learner import SensorimotorLearner


class CommandLeastSquares(SensorimotorLearner):
    """``W = argmin |Y - X W|^2``: the one-hot commands ``Y`` regressed on the sensors ``X``, both standardised
    on the training vectors (so centred: the intercept is the commands' mean).

    The map is the affine subspace ``{[x; W^T x]}`` of the same vectors, rank ``p_s``, with basis
    ``[I | W]``: the learners' masked projection of the sensors returns them unchanged and the
    commands as ``x W``, decoded by each block's largest entry as for the other learners. The sensors
    are always reconstructed exactly, so the confidence is 1 everywhere: least squares has none
    (its ``confidence_auroc`` is 0.5, a tie). The closed form is the minimum; the trainer's steps on
    the same squared error only confirm it.
    """

    name = "least_squares"

    def __init__(self) -> None:
        super().__init__()
        self.weight: nn.Parameter | None = None

    def initialise(self, data: SensorimotorData) -> None:
        # The subspace has one dimension per sensor: no rank to choose.
        self.rank = len(data.sensors)
        super().initialise(data)

    def start(self, standardised: torch.Tensor) -> None:
        sensors, commands = standardised[:, : self.sensor_count], standardised[:, self.sensor_count :]
        self.weight = nn.Parameter(torch.linalg.lstsq(sensors, commands).solution)

    def loss(self, batch: tuple[torch.Tensor, torch.Tensor]) -> dict[str, torch.Tensor]:
        _, vectors = batch
        standardised = self.standardise(vectors)
        error = standardised[:, : self.sensor_count] @ self.weight - standardised[:, self.sensor_count :]
        terms = {"command_error": error.pow(2).sum(dim=1).mean()}
        terms["loss"] = terms["command_error"]
        return terms

    def basis(self) -> torch.Tensor:
        identity = torch.eye(self.sensor_count, dtype=self.weight.dtype)
        return torch.cat([identity, self.weight.detach()], dim=1)

    def centre(self) -> torch.Tensor:
        return torch.zeros_like(self.column_mean)

    def reconstruct(self, standardised: torch.Tensor) -> torch.Tensor:
        """The sensors kept, the commands predicted from them."""
        sensors = standardised[:, : self.sensor_count]
        return torch.cat([sensors, sensors @ self.weight], dim=1)
