"""A callback for resume tests: the run sends itself a signal at the end of one epoch, before that epoch's checkpoint.

Used from the command line as ``+callbacks.signal._target_=tests.signal_at_epoch.SignalAtEpoch
+callbacks.signal.epoch=5 +callbacks.signal.signal=SIGKILL`` (Lightning runs checkpoint callbacks
after the others, so the newest checkpoint on disk is the previous epoch's).
"""

from __future__ import annotations

import os
import signal as signals

import lightning as L
from lightning.pytorch.callbacks import Callback


class SignalAtEpoch(Callback):
    def __init__(self, epoch: int, signal: str = "SIGKILL", model: str | None = None) -> None:
        self.epoch = epoch
        self.signal = getattr(signals, signal)
        self.model = model  # only in the fit of this model class (e.g. a baseline's), else in the first to get there

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self.model is not None and type(pl_module.model).__name__ != self.model:
            return
        if trainer.current_epoch == self.epoch:
            if self.signal == signals.SIGINT:
                # As in a terminal: a test run in the background inherits SIGINT ignored.
                signals.signal(signals.SIGINT, signals.default_int_handler)
            os.kill(os.getpid(), self.signal)
