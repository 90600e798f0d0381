"""The one LightningModule: fits every model, calibrators and sensorimotor learners alike (closed form first, then steps)."""

from __future__ import annotations

from collections.abc import Callable, Iterable

import lightning as L
import torch

from sfmnet.data.recording import CalibrationRecording
from sfmnet.data.sensorimotor import SensorimotorData
from sfmnet.errors import SfmnetError
from sfmnet.models.linear_calibrator import LinearCalibrator
from sfmnet.models.sensorimotor_learner import SensorimotorLearner

OptimizerFactory = Callable[[Iterable[torch.nn.Parameter]], torch.optim.Optimizer]
Learner = LinearCalibrator | SensorimotorLearner


class LearnerModule(L.LightningModule):
    """Thin Lightning glue over a model that owns its math.

    Fitting runs ``model.initialise`` (the closed form) in ``setup``, then for the trainer's
    epochs either gradient steps on ``model.loss``, or for a model that refines itself by
    closed-form rounds (``model.alternating``) its ``alternate`` step, or for a model fitted
    from sufficient statistics (``model.streaming``) one pass of ``accumulate`` per epoch,
    summed over processes by the strategy and solved by ``finalise`` (both with Lightning's
    manual optimisation). Every epoch it logs the loss terms, the singular values of the shape, what
    the model's ``monitor()`` reports (e.g. an autoencoder's angle to the PCA subspace) and,
    for simulated calibration data, the relative error of the calibration matrix.

    Args:
        model: a :class:`LinearCalibrator` or :class:`SensorimotorLearner`.
        optimizer: builds the optimiser from the parameters (a Hydra ``_partial_``).
    """

    def __init__(self, model: Learner, optimizer: OptimizerFactory) -> None:
        super().__init__()
        self.model = model
        self.optimizer_factory = optimizer
        # Statistics models add each batch to sums and solve once the pass is complete.
        self.streaming = getattr(model, "streaming", False)
        self.choose_optimisation()

    @property
    def recording(self) -> CalibrationRecording | SensorimotorData:
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
        self.choose_optimisation()

    def choose_optimisation(self) -> None:
        """The optimiser for models trained on their loss; manual steps for alternating and streaming ones."""
        self.automatic_optimization = not (getattr(self.model, "alternating", False) or self.streaming)

    def configure_optimizers(self) -> torch.optim.Optimizer | None:
        if not self.automatic_optimization:
            return None
        return self.optimizer_factory([p for p in self.parameters() if p.requires_grad])

    def on_train_epoch_start(self) -> None:
        if self.streaming:
            self.model.begin_pass()

    def on_train_batch_start(self, batch: dict[str, tuple[torch.Tensor, ...]], batch_idx: int) -> None:
        # Once per optimiser step (an L-BFGS step calls training_step many times): e.g. the marginal
        # refinement's update of the directions' distribution (ShapeFromMotion.prepare_step).
        prepare = getattr(self.model, "prepare_step", None)
        if prepare is not None:
            prepare(batch[self.model.recording])

    def training_step(self, batch: dict[str, tuple[torch.Tensor, ...]], batch_idx: int) -> torch.Tensor | None:
        rows = batch[self.model.recording]
        if self.streaming:
            self.model.accumulate(rows)
            return None
        if not self.automatic_optimization:
            self.model.alternate(rows)
            with torch.no_grad():
                terms = self.model.loss(rows)
        else:
            terms = self.model.loss(rows)
        size = len(rows[0])
        self.log_dict(
            {f"train/{name}": value.detach() for name, value in terms.items()}, on_step=False, on_epoch=True, batch_size=size
        )
        self.log("loss", terms["loss"].detach(), on_epoch=True, prog_bar=True, logger=False, batch_size=size)
        return terms["loss"] if self.automatic_optimization else None

    def on_train_epoch_end(self) -> None:
        if self.streaming:
            self.model.reduce(self.trainer.strategy)
            self.model.finalise()
            # A model that needs several passes says when it is done (identical on every process).
            self.trainer.should_stop = getattr(self.model, "converged", False)
        singular = torch.linalg.svdvals(self.model.shape.detach())
        self.log_dict({f"shape/singular_value_{i}": value for i, value in enumerate(singular)})
        self.log_dict(getattr(self.model, "monitor", dict)(), prog_bar=True)
        truth = getattr(self.trainer.datamodule.data, "truth", None)
        if truth is not None:
            self.log("error/matrix_relative", matrix_error(self.model.calibration_matrix(), truth.matrix), prog_bar=True)


def matrix_error(matrix: torch.Tensor, true_matrix: torch.Tensor) -> torch.Tensor:
    """``|C - C_true|_F / |C_true|_F``."""
    return (matrix - true_matrix).norm() / true_matrix.norm()
