"""What a task is: what the one run loop (:func:`sfmnet.training.run.train`) asks of calibration, learning and PCA.

The loop builds the data, asks the task for its models, fits each through the one trainer
(with the logger and callbacks of :mod:`sfmnet.training.components`), and hands each fit to the
task to evaluate; the task then writes its result files and says what the console shows.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import lightning as L
import torch
from hydra.utils import instantiate
from lightning.pytorch.loggers import Logger
from omegaconf import DictConfig, OmegaConf

from sfmnet.errors import SfmnetError
from sfmnet.models.contracts import Learner


@dataclass
class FittedMethod:
    """One method as the loop hands it to the task after fitting.

    Attributes:
        name: the method's name (the main model's, or its key in ``baselines``).
        model: the fitted model.
        trainer: the Trainer that fitted it (epochs, step, process rank).
        seconds: wall time of the fit.
        logger: its logger (TensorBoard), or None.
        run_dir: the run directory.
        settings: its settings as the logger's hyperparameters (:func:`sfmnet.training.tensorboard_summary.run_settings`).
    """

    name: str
    model: Learner
    trainer: L.Trainer
    seconds: float
    logger: Logger | None
    run_dir: Path
    settings: dict[str, Any] = field(default_factory=dict)


@dataclass
class MethodResult:
    """What one fitted method leaves behind: its flat metrics, warnings, the task's own result object and the model;
    ``series``: figures over items (tag to ``{item number: value}``, e.g. the error per held-out group), logged as
    TensorBoard scalars stepped by item."""

    name: str
    metrics: dict[str, float]
    warnings: list[str] = field(default_factory=list)
    result: Any = None
    model: Learner | None = None
    series: dict[str, dict[int, float]] = field(default_factory=dict)


class Task(ABC):
    """One kind of run. Subclasses set ``kind`` (the name ``task=`` and data modules use) and
    ``ignores``: config keys it cannot honour, refused in one line when set.

    Args:
        cfg: the run's config.
    """

    kind: str
    # Config keys (dotted) this task has no use for, with why; refused when truthy.
    ignores: dict[str, str] = {}

    def __init__(self, cfg: DictConfig) -> None:
        self.cfg = cfg
        for key, why in self.ignores.items():
            if OmegaConf.select(cfg, key):
                raise SfmnetError(f"{key} is set but a {self.kind} run {why}: drop {key}")

    def models(self) -> dict[str, Learner]:
        """The main model (first) and the baselines, by name."""
        main = instantiate(self.cfg.model)
        models = {main.name: main}
        models.update({name: instantiate(model_cfg) for name, model_cfg in self.cfg.get("baselines", {}).items()})
        return models

    def true_matrix(self, data: Any) -> torch.Tensor | None:
        """The simulated calibration matrix the trainer logs its error against, if any."""
        return None

    @abstractmethod
    def evaluate(self, fitted: FittedMethod, data: Any) -> MethodResult:
        """Score one fitted method (on every process) and draw its figures (on the first)."""

    def after_fits(self, data: Any, results: dict[str, MethodResult], run_dir: Path) -> None:
        """Work that needs every method fitted (e.g. leave-one-group-out refits); adds to ``results``."""

    @abstractmethod
    def write(self, results: dict[str, MethodResult], data: Any, run_dir: Path) -> dict[str, float]:
        """Write the task's result files (first process only); return the flat metrics for ``metrics.json``."""

    @abstractmethod
    def summary(self, results: dict[str, MethodResult], data: Any) -> list[str]:
        """The console lines under "run directory: ...", one per method and per warning."""
