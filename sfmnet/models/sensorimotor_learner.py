"""What the primordial learners share (paper section 6, method §8): standardised [sensors; commands] vectors,
a rank-k subspace, and commands read back from the sensors alone."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from sfmnet.data.sensorimotor import SensorimotorData
from sfmnet.errors import SfmnetError
from sfmnet.models.contracts import FitMode
from sfmnet.linalg.subspace import (
    largest_ratio_rank,
    masked_projection,
    parallel_analysis_rank,
)

RANK_RULES = ("parallel_analysis", "largest_ratio")


@dataclass(frozen=True)
class CommandReading:
    """What a learner makes of sensor readings alone.

    Attributes:
        commands: ``f x c`` label indices, one per command channel.
        confidence: ``f`` in (0, 1]: ``1 / (1 + e)`` with ``e`` the RMS sensor reconstruction error
            (standardised units), high where the sensors lie close to the learnt subspace.
        reconstruction: ``f x m``, the full vector in raw units.
    """

    commands: np.ndarray
    confidence: np.ndarray
    reconstruction: torch.Tensor


class SensorimotorLearner(nn.Module, ABC):
    """A linear subspace of standardised ``x = [sensors; one-hot commands]`` learnt from teleoperated data.

    Run time (method §8): the sensor part alone is projected on the subspace by least squares on
    the observed columns (an explicit mask), the full vector reconstructed, and each
    command's one-hot block decoded by its largest entry.

    Args:
        rank: ``k``; None chooses it by ``rank_rule``.
        rank_rule: ``"parallel_analysis"`` (Horn: components stronger than chance) or
            ``"largest_ratio"`` (the paper: the largest ratio of adjacent singular values).
        seed: for the rule's permutations and any random start.
    """

    name: str
    recording = "sensorimotor"

    def __init__(self, rank: int | None = None, rank_rule: str = "parallel_analysis", seed: int = 0) -> None:
        super().__init__()
        if rank_rule not in RANK_RULES:
            raise SfmnetError(f"model.rank_rule is '{rank_rule}': use one of {', '.join(RANK_RULES)}")
        self.rank = rank
        self.rank_rule = rank_rule
        self.seed = seed
        self.register_buffer("column_mean", None)
        self.register_buffer("column_scale", None)
        self.sensor_count = 0
        self.command_sizes: list[int] = []
        self.singular_values: torch.Tensor | None = None

    @property
    def is_initialised(self) -> bool:
        return self.column_mean is not None

    def initialise(self, data: SensorimotorData) -> None:
        """Standardise on the training vectors, choose the rank, then :meth:`start`."""
        vectors = data.vectors(data.train)
        self.sensor_count = len(data.sensors)
        self.command_sizes = [len(c.labels) for c in data.commands]
        self.column_mean = vectors.mean(dim=0)
        scale = vectors.std(dim=0)
        # A command label used on every training row is a constant column; keep it unscaled.
        self.column_scale = torch.where(scale > 0, scale, torch.ones_like(scale))
        standardised = self.standardise(vectors)
        self.singular_values = torch.linalg.svdvals(standardised)
        if self.rank is None:
            generator = torch.Generator().manual_seed(self.seed)
            chosen = (
                parallel_analysis_rank(standardised, generator)
                if self.rank_rule == "parallel_analysis"
                else largest_ratio_rank(self.singular_values)
            )
            # Above the sensors' count the sensors alone leave a subspace's coordinates undetermined.
            self.rank = min(chosen, self.sensor_count)
        if self.rank > self.sensor_count:
            raise SfmnetError(
                f"model.rank is {self.rank} but there are {self.sensor_count} sensors: commands read from the sensors "
                f"alone are undetermined above rank {self.sensor_count}, and the confidence ranks nothing from it up; "
                f"choose 1 to {self.sensor_count} (below {self.sensor_count} for a confidence)"
            )
        self.start(standardised)

    def fit_mode(self) -> FitMode:
        return FitMode.STEPS

    def prepare_step(self, batch: tuple[torch.Tensor, torch.Tensor]) -> None:
        """Nothing to do before a step."""

    def end_fit(self, data: SensorimotorData) -> None:
        """Nothing to do after the last step."""

    def monitor(self) -> dict[str, float]:
        return {}

    def standardise(self, vectors: torch.Tensor) -> torch.Tensor:
        return (vectors - self.column_mean) / self.column_scale

    @abstractmethod
    def start(self, standardised: torch.Tensor) -> None:
        """Create the parameters from the standardised training vectors (``f x m``) and ``self.rank``."""

    @abstractmethod
    def basis(self) -> torch.Tensor:
        """``k x m`` rows spanning the learnt subspace (standardised units)."""

    @abstractmethod
    def centre(self) -> torch.Tensor:
        """``m``: the subspace's offset (standardised units)."""

    @abstractmethod
    def reconstruct(self, standardised: torch.Tensor) -> torch.Tensor:
        """The learner's own map of full vectors into its subspace, ``b x m`` (for held-out reconstruction error)."""

    @abstractmethod
    def loss(self, batch: tuple[torch.Tensor, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Loss terms of one batch ``(index, vectors)``; key ``"loss"`` is minimised."""

    @property
    def shape(self) -> torch.Tensor:
        """The basis, so the trainer logs its singular values as for every factorisation."""
        return self.basis()

    @torch.no_grad()
    def read_commands(self, sensors: torch.Tensor) -> CommandReading:
        """Commands and confidence from raw sensor readings (``f x p_s``) alone."""
        m = len(self.column_mean)
        vectors = torch.zeros(len(sensors), m, dtype=self.column_mean.dtype)
        vectors[:, : self.sensor_count] = sensors
        standardised = self.standardise(vectors) - self.centre()
        observed = torch.zeros(m, dtype=torch.bool)
        observed[: self.sensor_count] = True
        basis = self.basis().detach()
        reconstruction = masked_projection(basis, standardised, observed) @ basis
        sensor_error = (reconstruction - standardised)[:, observed].pow(2).mean(dim=1).sqrt()
        if self.rank >= self.sensor_count:
            # Every sensor vector fits exactly: what is left is rounding, which no confidence should rank by.
            sensor_error = torch.zeros_like(sensor_error)
        raw = (reconstruction + self.centre()) * self.column_scale + self.column_mean
        return CommandReading(
            commands=self.decode(raw),
            confidence=(1 / (1 + sensor_error)).numpy(),
            reconstruction=raw,
        )

    def decode(self, raw: torch.Tensor) -> np.ndarray:
        """``f x c`` label indices from full vectors in raw units (``f x m``): each command's one-hot block by its
        largest entry (in raw units, where each block estimates the labels' indicators)."""
        commands, start = [], self.sensor_count
        for size in self.command_sizes:
            commands.append(raw[:, start : start + size].argmax(dim=1))
            start += size
        return torch.stack(commands, dim=1).numpy()

    @torch.no_grad()
    def reconstruction_error(self, vectors: torch.Tensor) -> float:
        """Mean squared error per entry of the full vectors' reconstruction, standardised units."""
        standardised = self.standardise(vectors)
        return float((self.reconstruct(standardised) - standardised).pow(2).mean())
