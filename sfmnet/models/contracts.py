"""What the trainer asks of a model: the three ways a model is fitted, as explicit contracts.

:class:`sfmnet.training.learner_module.LearnerModule` dispatches on :meth:`Learner.fit_mode`
alone; each mode's methods are the Protocol below it. Every model in :mod:`sfmnet.models`
says which it is:

==============  =========================================  ====================================
mode            models                                      each training step
==============  =========================================  ====================================
``STEPS``       penalised and marginal shape from motion,   the optimiser on ``loss(batch)``
                least squares, the linear autoencoder
``ALTERNATION`` shape from motion's alternation, the        ``alternate(batch)``: closed-form
                eigenspace learner                          rounds (``loss`` only logged)
``PASSES``      streamed PCA and shape from motion          ``accumulate(block)``; a pass ends in
                                                            ``reduce`` then ``finalise``
==============  =========================================  ====================================
"""

from __future__ import annotations

from enum import Enum
from typing import Any, Protocol, runtime_checkable

import torch


class FitMode(Enum):
    """How the trainer's steps fit a model (see the module's table)."""

    STEPS = "steps"
    ALTERNATION = "alternation"
    PASSES = "passes"


@runtime_checkable
class Learner(Protocol):
    """Any model the trainer fits: built by its closed form from a recording, then refined in steps.

    Attributes:
        name: the method's name in results and file names.
        recording: which of the data's recordings it learns from (e.g. ``"rotation"``).
    """

    name: str
    recording: str

    @property
    def is_initialised(self) -> bool: ...

    def initialise(self, recording: Any) -> None:
        """The closed form: create the parameters from the recording (the first step of fitting)."""

    def fit_mode(self) -> FitMode:
        """How the trainer's steps refine it (may depend on the data: read after :meth:`initialise`)."""

    def prepare_step(self, batch: Any) -> None:
        """Before each optimiser step on ``batch`` (e.g. the marginal refinement's distribution of directions)."""

    def end_fit(self, recording: Any) -> None:
        """After the last step, on the whole recording (e.g. the marginal refinement's frame turned to its known loads)."""

    def monitor(self) -> dict[str, float]:
        """Figures logged every epoch beside the loss (e.g. an autoencoder's angle to the PCA subspace)."""

    @property
    def shape(self) -> torch.Tensor:
        """The factorisation's shape (rows span the learnt subspace); its singular values are logged."""


@runtime_checkable
class StepFitted(Learner, Protocol):
    """``FitMode.STEPS``: the trainer's optimiser minimises ``loss(batch)["loss"]`` over the parameters."""

    def loss(self, batch: Any) -> dict[str, torch.Tensor]:
        """Loss terms of one batch (logged as ``train/<term>``); key ``"loss"`` is minimised."""


@runtime_checkable
class Alternating(StepFitted, Protocol):
    """``FitMode.ALTERNATION``: each step is the model's own closed-form rounds; the loss is only logged."""

    def alternate(self, batch: Any) -> dict[str, torch.Tensor]:
        """Refine the parameters in place from one (full) batch; return the loss terms there (as :meth:`loss`'s)."""


@runtime_checkable
class PassFitted(Learner, Protocol):
    """``FitMode.PASSES``: fitted from sums over every row, one pass (epoch) at a time, on any number of processes.

    Attributes:
        converged: set by :meth:`finalise` when no further pass would change the result.
        dev_run_passes: the passes a fast dev run needs to reach a result.
    """

    converged: bool
    dev_run_passes: int

    def begin_pass(self) -> None:
        """Reset the sums at the start of a pass."""

    def accumulate(self, block: Any) -> None:
        """Add one block of rows to the sums."""

    def reduce(self, strategy: Any) -> None:
        """Sum the sums over processes with the trainer's strategy (each block was read by one process)."""

    def finalise(self) -> None:
        """Solve from the complete sums."""
