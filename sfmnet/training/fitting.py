"""Fitting one model: its closed form, then the optimiser's epochs, through one Lightning Trainer."""

from __future__ import annotations

import lightning as L
from hydra.utils import instantiate
from omegaconf import DictConfig

from sfmnet.training.learner_module import Learner, LearnerModule


def fit(model: Learner, cfg: DictConfig, datamodule: L.LightningDataModule, **trainer_options) -> L.Trainer:
    """Fit ``model`` with the optimiser ``cfg.optimizer`` and a Trainer from ``cfg.trainer`` (plus ``trainer_options``)."""
    module = LearnerModule(model=model, optimizer=instantiate(cfg.optimizer))
    trainer: L.Trainer = instantiate(cfg.trainer, **trainer_options)
    trainer.fit(module, datamodule=datamodule)
    return trainer
