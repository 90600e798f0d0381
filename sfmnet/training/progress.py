"""The console's view of a fit: a progress bar in a terminal, one logged line per epoch (or item) anywhere else.

A bar redraws itself with carriage returns, which a file or a pipe (a sweep's log, CI) keeps as
one long line per redraw; there each epoch is one line through the ``sfmnet`` logger instead,
so it reaches ``train.log`` too.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterator, Sequence
from typing import Any, TypeVar

import lightning as L
from lightning.pytorch.callbacks import ProgressBar as LightningProgressBar
from lightning.pytorch.callbacks import TQDMProgressBar
from tqdm import tqdm

log = logging.getLogger(__name__)
Item = TypeVar("Item")


def progress_bar() -> LightningProgressBar:
    """A :class:`Bar` when stdout is a terminal, else :class:`EpochLines` (the ``callbacks.progress_bar`` target)."""
    return Bar() if sys.stdout.isatty() else EpochLines()


def shown_metrics(metrics: dict[str, Any]) -> dict[str, Any]:
    """The progress bar's metrics without the logger's version number (it is the method's name, truncated)."""
    return {key: value for key, value in metrics.items() if key != "v_num"}


def epoch_metrics(metrics: dict[str, Any]) -> dict[str, Any]:
    """The metrics of a whole epoch: without the last step's (``loss_step``) where the epoch's is there too."""
    return {key: value for key, value in metrics.items() if not (key.endswith("_step") and key[:-5] + "_epoch" in metrics)}


class Bar(TQDMProgressBar):
    """Lightning's tqdm bar, without the version number."""

    def get_metrics(self, trainer: L.Trainer, pl_module: L.LightningModule) -> dict[str, Any]:
        return shown_metrics(super().get_metrics(trainer, pl_module))


class EpochLines(LightningProgressBar):
    """One line per finished epoch: ``<method> epoch 3/10: loss_epoch 0.0001451, error/matrix_relative 0.02134``.

    Epochs whose figures repeat the last line's (a fit that has converged) are not printed again; the last epoch is,
    saying since when nothing changed: ``epoch 10/10: loss_epoch 0.07733 (unchanged since epoch 1)``.
    """

    def __init__(self) -> None:
        super().__init__()
        self.enabled = True
        self.reported_epoch = -1
        self.shown: tuple[str, int] | None = None

    def disable(self) -> None:
        self.enabled = False

    def enable(self) -> None:
        self.enabled = True

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # A resumed fit reports from the epoch it resumes in.
        self.reported_epoch = trainer.current_epoch - 1
        self.shown = None

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # An epoch's metrics are complete only after every epoch-end hook: report it when the next one starts.
        self.report(trainer, pl_module, trainer.current_epoch - 1)

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.report(trainer, pl_module, trainer.current_epoch - 1, last=True)

    def report(self, trainer: L.Trainer, pl_module: L.LightningModule, epoch: int, last: bool = False) -> None:
        if not self.enabled or epoch <= self.reported_epoch or epoch < 0:
            return
        self.reported_epoch = epoch
        # The run loop names each method's logger version after the method.
        version = trainer.logger.version if trainer.logger is not None else None
        method = f"{version} " if isinstance(version, str) else ""
        total = f"/{trainer.max_epochs}" if trainer.max_epochs and trainer.max_epochs > 0 else ""
        metrics = ", ".join(f"{key} {value:.4g}" if isinstance(value, float) else f"{key} {value}"
                            for key, value in epoch_metrics(shown_metrics(self.get_metrics(trainer, pl_module))).items())
        if not metrics and not last:
            return  # an epoch that logs nothing (a streamed pass summing moments) says nothing
        unchanged = self.shown is not None and self.shown[0] == metrics
        if not unchanged:
            self.shown = (metrics, epoch)
        elif not last:
            return
        since = f" (unchanged since epoch {self.shown[1] + 1})" if unchanged else ""
        log.info(f"{method}epoch {epoch + 1}{total}: {metrics}{since}")


def each_with_progress(items: Sequence[Item], description: str, enabled: bool = True) -> Iterator[Item]:
    """``items`` one by one, with a bar in a terminal, elsewhere a logged line as each is done (``enabled``)."""
    if not enabled:
        yield from items
    elif sys.stdout.isatty():
        yield from tqdm(items, desc=description, file=sys.stdout)
    else:
        for number, item in enumerate(items, 1):
            yield item
            log.info(f"{description}: {number}/{len(items)} done")
