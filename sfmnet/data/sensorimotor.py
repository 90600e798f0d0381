"""What a sensorimotor data module hands to the learners: [sensors; commands] vectors, train and test.

Commands are categorical (the MK-V's -1/0/+1, or labels such as ``Move-Forward``): each is
one-hot encoded into its own block of columns and decoded back by the largest entry of its
block (method §8).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, TensorDataset

from sfmnet.data.batches import batch_loader
from sfmnet.errors import SfmnetError

if TYPE_CHECKING:
    from sfmnet.simulators.mkv_robot import MkvWorld


@dataclass(frozen=True)
class Command:
    """One command channel and its alphabet (numbers, or text labels)."""

    name: str
    labels: list

    @property
    def signed(self) -> bool:
        """Three-valued reverse/off/forward, as the MK-V's: when-to-act and direction metrics apply."""
        return sorted(self.labels) == [-1, 0, 1]


@dataclass(frozen=True)
class Episode:
    """A stretch of time-ordered samples: ``sensors`` (``t x p_s``) and ``commands`` (``t x c``, label indices)."""

    sensors: np.ndarray
    commands: np.ndarray


@dataclass
class SensorimotorData:
    """Training vectors and held-out episodes.

    Attributes:
        train: the training episodes (concatenated for fitting).
        test: held-out episodes (other rooms, or the last part of a log); the first is plotted.
        sensors: the ``p_s`` sensor names.
        commands: the command channels with their alphabets.
        period: seconds per sample (for plots).
        world: the simulator the test runs came from, for driving a learnt mapping in closed
            loop; None for a recorded log.
    """

    train: list[Episode]
    test: list[Episode]
    sensors: list[str]
    commands: list[Command]
    period: float = 1.0
    world: MkvWorld | None = None

    @property
    def recordings(self) -> dict[str, SensorimotorData]:
        """What a learner initialises from, by its ``recording`` name (as for calibration data)."""
        return {"sensorimotor": self}

    @property
    def columns(self) -> list[str]:
        """Names of the vector's columns: sensors, then ``<command>=<label>`` per one-hot column."""
        return [*self.sensors, *(f"{c.name}={label}" for c in self.commands for label in c.labels)]

    def vectors(self, episodes: list[Episode]) -> torch.Tensor:
        """``[sensors, one-hot commands]``, ``f x (p_s + sum of alphabet sizes)``, float64."""
        sensors = np.concatenate([e.sensors for e in episodes])
        commands = np.concatenate([e.commands for e in episodes])
        blocks = [np.eye(len(c.labels))[commands[:, i]] for i, c in enumerate(self.commands)]
        return torch.from_numpy(np.concatenate([sensors, *blocks], axis=1))


def label_indices(values: np.ndarray, labels: list) -> np.ndarray:
    """Each value's position in ``labels``."""
    lookup = {label: i for i, label in enumerate(labels)}
    return np.array([lookup[v] for v in values.tolist()], dtype=np.int64)


class SensorimotorDataModule(L.LightningDataModule, ABC):
    """Serves the training vectors as ``{"sensorimotor": loader of (index, vectors)}``.

    Args:
        batch_size: rows per batch; None: the whole training set (closed forms, L-BFGS).
    """

    recording = "sensorimotor"
    task = "sensorimotor"

    def __init__(self, batch_size: int | None = None) -> None:
        super().__init__()
        self.batch_size = batch_size
        self.data: SensorimotorData | None = None

    @abstractmethod
    def build(self) -> SensorimotorData:
        """Read or simulate the data."""

    def setup(self, stage: str | None = None) -> None:
        if self.data is None:
            self.data = self.build()
            check_training_vectors(self.data)

    @property
    def rows(self) -> int:
        """The training vectors a fit reads, after :meth:`setup`."""
        assert self.data is not None, "setup() runs first"
        return sum(len(episode.sensors) for episode in self.data.train)

    def train_dataloader(self) -> dict[str, DataLoader]:
        assert self.data is not None, "setup() runs before the loaders"
        vectors = self.data.vectors(self.data.train)
        dataset = TensorDataset(torch.arange(len(vectors)), vectors)
        return {self.recording: batch_loader(dataset, self.batch_size)}


class FixedSensorimotorDataModule(SensorimotorDataModule):
    """Serves data already in memory (the estimators of :mod:`sfmnet.estimators`)."""

    def __init__(self, data: SensorimotorData, batch_size: int | None = None) -> None:
        super().__init__(batch_size=batch_size)
        self.fixed = data

    def build(self) -> SensorimotorData:
        return self.fixed


def check_training_vectors(data: SensorimotorData) -> None:
    """Refuse what no linear learner can use: constant sensors, a command that never varies, fewer samples than
    columns."""
    sensors = np.concatenate([e.sensors for e in data.train])
    # The range, not the standard deviation, which rounding leaves at ~1e-13 for a constant column of most values.
    constant = [name for name, spread in zip(data.sensors, np.ptp(sensors, axis=0)) if spread == 0]
    if constant:
        raise SfmnetError(
            f"sensor column {', '.join(constant)} is constant in the training data: it carries no information; "
            "leave it out of the sensors (in a CSV log, of data.sensor_columns), or record longer or more varied runs "
            "(the simulated robot: more data.steps or data.train_rooms)"
        )
    commands = np.concatenate([e.commands for e in data.train])
    for i, command in enumerate(data.commands):
        if len(np.unique(commands[:, i])) < 2:
            raise SfmnetError(
                f"command column {command.name} takes one value ({command.labels[commands[0, i]]!r}) on every training "
                "row: there is no mapping from sensors to commands to learn; give a log in which the commands vary"
            )
    columns = len(data.columns)
    if len(sensors) <= columns:
        raise SfmnetError(
            f"only {len(sensors)} training samples for {columns} columns ([sensors; one-hot commands]): "
            "a subspace needs more samples than columns; record a longer log"
        )
