"""The eigenspace learner: the factorisation with no metric constraint on sensorimotor vectors (paper section 6)."""

from __future__ import annotations

import torch

from sfmnet.data.recording import CalibrationRecording
from sfmnet.linalg.subspace import masked_projection
from sfmnet.models.contracts import FitMode
from sfmnet.models.sensorimotor_learner import SensorimotorLearner
from sfmnet.models.shape_from_motion import ShapeFromMotion


class EigenspaceLearner(SensorimotorLearner):
    """Affine PCA of standardised ``[sensors; commands]``: :class:`ShapeFromMotion` with ``metric_weight = 0``.

    The factorisation's closed form (centred truncated SVD, eqs. 6-8) is the principal
    subspace; the trainer's steps are its alternation (alternating least squares, which
    keeps the subspace: it is the fixed point). Args as :class:`SensorimotorLearner`.
    """

    name = "eigenspace"

    def __init__(self, rank: int | None = None, rank_rule: str = "parallel_analysis", seed: int = 0) -> None:
        super().__init__(rank=rank, rank_rule=rank_rule, seed=seed)
        self.factorisation: ShapeFromMotion | None = None

    def fit_mode(self) -> FitMode:
        return FitMode.ALTERNATION

    def start(self, standardised: torch.Tensor) -> None:
        # One alternation round per epoch: the closed form is already its fixed point.
        self.factorisation = ShapeFromMotion(rank=self.rank, metric_weight=0.0, estimate_offset=True, alternation_steps=1)
        self.factorisation.initialise(CalibrationRecording(standardised, self.unknown_coefficients(standardised)))

    def unknown_coefficients(self, rows: torch.Tensor) -> torch.Tensor:
        """NaN ``b x k``: every row's coefficients (its "load") are unknown, the unconstrained factorisation."""
        return torch.full((len(rows), self.rank), float("nan"), dtype=rows.dtype)

    def factorisation_batch(self, batch: tuple[torch.Tensor, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        index, vectors = batch
        return index, self.standardise(vectors), self.unknown_coefficients(vectors)

    def alternate(self, batch: tuple[torch.Tensor, torch.Tensor]) -> dict[str, torch.Tensor]:
        terms = self.factorisation.alternate(self.factorisation_batch(batch))
        return {"reconstruction": terms["reconstruction"], "loss": terms["loss"]}

    def loss(self, batch: tuple[torch.Tensor, torch.Tensor]) -> dict[str, torch.Tensor]:
        terms = self.factorisation.loss(self.factorisation_batch(batch))
        return {"reconstruction": terms["reconstruction"], "loss": terms["loss"]}

    def basis(self) -> torch.Tensor:
        return self.factorisation.physical_shape()

    def centre(self) -> torch.Tensor:
        return self.factorisation.physical_offset()

    def reconstruct(self, standardised: torch.Tensor) -> torch.Tensor:
        basis = self.basis()
        every_column = torch.ones(basis.shape[1], dtype=torch.bool)
        return masked_projection(basis, standardised - self.centre(), every_column) @ basis + self.centre()
