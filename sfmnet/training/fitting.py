"""Fitting one model: its closed form, then the optimiser's epochs, through one Lightning Trainer."""

from __future__ import annotations

import lightning as L
from hydra.utils import instantiate
from omegaconf import DictConfig

from sfmnet.data.calibration_datamodule import CalibrationDataModule
from sfmnet.models.linear_calibrator import LinearCalibrator
from sfmnet.training.learner_module import LearnerModule


def fit(model: LinearCalibrator, cfg: DictConfig, datamodule: CalibrationDataModule, **trainer_options) -> L.Trainer:
    """Fit ``model`` with the optimiser ``cfg.optimizer`` and a Trainer from ``cfg.trainer`` (plus ``trainer_options``)."""
    module = LearnerModule(model=model, optimizer=instantiate(cfg.optimizer))
    trainer: L.Trainer = instantiate(cfg.trainer, **trainer_options)
    trainer.fit(module, datamodule=datamodule)
    return trainer
