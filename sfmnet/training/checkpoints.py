"""Checkpoints at the end of every epoch, whatever the fit's steps are."""

from __future__ import annotations

from typing import Any

import lightning as L
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.trainer.states import TrainerFn


class EpochCheckpoint(ModelCheckpoint):
    """Lightning's ``ModelCheckpoint``, told apart by epoch instead of optimiser step.

    An alternation round (calibration, the eigenspace learner) is an epoch but no optimiser
    step, so ``trainer.global_step`` stays 0 and the stock callback, which skips a save at a
    step it has saved at, would write only the first epoch. Each file is written atomically
    (Lightning saves through a transaction), so a kill leaves whole checkpoints only.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.epoch_saved = -1

    def _should_skip_saving_checkpoint(self, trainer: L.Trainer) -> bool:
        return (
            bool(trainer.fast_dev_run)
            or trainer.state.fn != TrainerFn.FITTING
            or trainer.sanity_checking
            or self.epoch_saved == trainer.current_epoch
        )

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        super().on_train_epoch_end(trainer, pl_module)
        self.epoch_saved = trainer.current_epoch
