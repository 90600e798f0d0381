"""The one LightningModule: fits every model, calibrators and sensorimotor learners alike (closed form first, then steps)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import lightning as L
import torch

from sfmnet.errors import SfmnetError
from sfmnet.models.contracts import FitMode, Learner

# Where a checkpoint keeps the settings its fit depends on.
FIT_SETTINGS_KEY = "sfmnet_fit_settings"
UNSET = "<unset>"

OptimizerFactory = Callable[[Iterable[torch.nn.Parameter]], torch.optim.Optimizer]


class LearnerModule(L.LightningModule):
    """Thin Lightning glue over a model that owns its math, dispatched on its :class:`FitMode`.

    Fitting runs ``model.initialise`` (the closed form) in ``setup``; then each of the trainer's
    steps is, by ``model.fit_mode()`` (:mod:`sfmnet.models.contracts`): the optimiser on
    ``model.loss`` (``STEPS``); the model's own ``alternate`` rounds (``ALTERNATION``); or one block
    of ``accumulate`` per step, a pass per epoch, summed over processes by the strategy and solved
    by ``finalise`` (``PASSES``; both with Lightning's manual optimisation). Every epoch it logs the
    loss terms, the singular values of the shape, the model's ``monitor()`` and, given
    ``true_matrix`` (simulated calibration data), the relative error of the calibration matrix.

    Args:
        model: any :class:`Learner`.
        optimizer: builds the optimiser from the parameters (a Hydra ``_partial_``).
        true_matrix: ``n x p``, the simulated truth to log the matrix error against, or None.
    """

    def __init__(
        self, model: Learner, optimizer: OptimizerFactory, true_matrix: torch.Tensor | None = None,
        fit_settings: dict[str, Any] | None = None,
    ) -> None:
        super().__init__()
        self.model = model
        self.optimizer_factory = optimizer
        self.true_matrix = true_matrix
        self.fit_settings = fit_settings
        self.read_mode()

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        # The settings the fit depends on, so that a resume under other settings is refused (on_load_checkpoint).
        if self.fit_settings is not None:
            checkpoint[FIT_SETTINGS_KEY] = self.fit_settings

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """Refuse to resume under other settings (a hostile tester's resume with another ``data.test_fraction``, whose
        shapes matched, mixed the old split's standardisation with the new one's, exit 0); Lightning calls this before
        it loads the weights. A checkpoint written before checkpoints kept their settings is taken as it is."""
        saved = checkpoint.get(FIT_SETTINGS_KEY)
        if saved is None or self.fit_settings is None:
            return
        keys = dict.fromkeys([*saved, *self.fit_settings])
        differing = [key for key in keys if saved.get(key, UNSET) != self.fit_settings.get(key, UNSET)]
        if differing:
            key = differing[0]
            more = f" and {len(differing) - 1} more" if len(differing) > 1 else ""
            raise SfmnetError(
                f"ckpt_path {self.trainer.ckpt_path} was written with {key}={saved.get(key, UNSET)!r}, this run has "
                f"{self.fit_settings.get(key, UNSET)!r}{more}: resume with the interrupted run's settings (its "
                ".hydra/config.yaml), or start afresh without ckpt_path"
            )

    @property
    def recording(self) -> Any:
        data = self.trainer.datamodule.data
        if self.model.recording not in data.recordings:
            raise SfmnetError(
                f"{type(self.model).__name__} learns from a '{self.model.recording}' recording, which this data "
                f"does not have (it has {', '.join(data.recordings)}): pick a model that fits the data"
            )
        return data.recordings[self.model.recording]

    def setup(self, stage: str) -> None:
        if not self.model.is_initialised:
            self.model.initialise(self.recording)
        # A model may choose its refinement from the data ("auto"): read it again once initialised.
        self.read_mode()

    def read_mode(self) -> None:
        """The model's fit mode; the optimiser for models fitted by steps, manual steps for the others."""
        self.mode = self.model.fit_mode()
        self.automatic_optimization = self.mode is FitMode.STEPS

    def configure_optimizers(self) -> torch.optim.Optimizer | None:
        if not self.automatic_optimization:
            return None
        return self.optimizer_factory([p for p in self.parameters() if p.requires_grad])

    def on_train_epoch_start(self) -> None:
        if self.mode is FitMode.PASSES:
            self.model.begin_pass()

    def on_train_batch_start(self, batch: dict[str, tuple[torch.Tensor, ...]], batch_idx: int) -> None:
        # Once per optimiser step (an L-BFGS step calls training_step many times).
        self.model.prepare_step(batch[self.model.recording])

    def training_step(self, batch: dict[str, tuple[torch.Tensor, ...]], batch_idx: int) -> torch.Tensor | None:
        rows = batch[self.model.recording]
        if self.mode is FitMode.PASSES:
            self.model.accumulate(rows)
            return None
        if self.mode is FitMode.ALTERNATION:
            terms = self.model.alternate(rows)
        else:
            terms = self.model.loss(rows)
        size = len(rows[0])
        self.log_dict(
            {f"train/{name}": value.detach() for name, value in terms.items()}, on_step=False, on_epoch=True, batch_size=size
        )
        self.log("loss", terms["loss"].detach(), on_epoch=True, prog_bar=True, logger=False, batch_size=size)
        return terms["loss"] if self.automatic_optimization else None

    def on_train_end(self) -> None:
        # Also where a resumed fit had no epochs left: the model's last touches are idempotent.
        self.model.end_fit(self.recording)

    def on_train_epoch_end(self) -> None:
        if self.mode is FitMode.PASSES:
            self.model.reduce(self.trainer.strategy)
            self.model.finalise()
            # A model that needs several passes says when it is done (identical on every process).
            self.trainer.should_stop = self.model.converged
        singular = torch.linalg.svdvals(self.model.shape.detach())
        self.log_dict({f"shape/singular_value_{i}": value for i, value in enumerate(singular)})
        self.log_dict(self.model.monitor(), prog_bar=True)
        if self.true_matrix is not None:
            self.log("error/matrix_relative", matrix_error(self.model.calibration_matrix(), self.true_matrix), prog_bar=True)


def matrix_error(matrix: torch.Tensor, true_matrix: torch.Tensor) -> torch.Tensor:
    """``|C - C_true|_F / |C_true|_F``."""
    return (matrix - true_matrix).norm() / true_matrix.norm()
