"""The LightningDataModule shape shared by every calibration data source."""

from __future__ import annotations

from abc import ABC, abstractmethod

import lightning as L
import torch
from torch.utils.data import DataLoader, TensorDataset

from sfmnet.data.batches import batch_loader

from sfmnet.data.recording import CalibrationData


class CalibrationDataModule(L.LightningDataModule, ABC):
    """Serves each recording as its own loader; a training batch is ``{name: (index, readings, loads)}``.

    ``index`` (long, ``b``) is each row's position in its recording, so a model can keep a
    per-sample table (the motion ``M``). Loads are NaN where unknown.

    Args:
        batch_size: rows per batch; ``None`` serves each recording whole (the right choice for
            calibration-sized data, where a full-batch optimiser such as L-BFGS converges fastest).

    ``task``: the kind of run its data is for (:mod:`sfmnet.tasks`), when ``task=`` is not set.
    """

    task = "calibration"

    def __init__(self, batch_size: int | None = None) -> None:
        super().__init__()
        self.batch_size = batch_size
        self.data: CalibrationData | None = None

    @abstractmethod
    def build(self) -> CalibrationData:
        """Read or simulate the data."""

    def setup(self, stage: str | None = None) -> None:
        if self.data is None:
            self.data = self.build()

    @property
    def rows(self) -> int:
        """The rows a fit reads (every recording's), after :meth:`setup`."""
        assert self.data is not None, "setup() runs first"
        return sum(len(recording.readings) for recording in self.data.recordings.values())

    def train_dataloader(self) -> dict[str, DataLoader]:
        assert self.data is not None, "setup() runs before the loaders"
        loaders = {}
        for name, recording in self.data.recordings.items():
            rows = len(recording.readings)
            dataset = TensorDataset(torch.arange(rows), recording.readings, recording.loads)
            loaders[name] = batch_loader(dataset, self.batch_size)
        return loaders


class FixedCalibrationDataModule(CalibrationDataModule):
    """Serves data already in memory (e.g. one fold of a cross-validation)."""

    def __init__(self, data: CalibrationData, batch_size: int | None = None) -> None:
        super().__init__(batch_size=batch_size)
        self.fixed = data

    def build(self) -> CalibrationData:
        return self.fixed

