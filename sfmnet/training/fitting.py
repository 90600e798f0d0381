"""Fitting one model: its closed form, then the optimiser's epochs, through one Lightning Trainer."""

from __future__ import annotations

from pathlib import Path

import lightning as L
from hydra.utils import instantiate
from omegaconf import DictConfig

from sfmnet.errors import SfmnetError
from sfmnet.training.learner_module import Learner, LearnerModule


def fit(
    model: Learner,
    cfg: DictConfig,
    datamodule: L.LightningDataModule,
    ckpt_path: str | None = None,
    **trainer_options,
) -> L.Trainer:
    """Fit ``model`` with the optimiser ``cfg.optimizer`` and a Trainer from ``cfg.trainer`` (plus ``trainer_options``).

    ``ckpt_path``: a checkpoint of an interrupted run of the same config; training resumes
    from it (model, optimiser state and epoch) to the result the uninterrupted run would give.
    """
    if ckpt_path is not None and not Path(ckpt_path).is_file():
        raise SfmnetError(f"ckpt_path {ckpt_path} is not a file: give a run's checkpoints/<method>/last.ckpt")
    module = LearnerModule(model=model, optimizer=instantiate(cfg.optimizer))
    trainer: L.Trainer = instantiate(cfg.trainer, **trainer_options)
    trainer.fit(module, datamodule=datamodule, ckpt_path=ckpt_path)
    return trainer
