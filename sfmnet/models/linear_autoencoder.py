"""A linear autoencoder on the same vectors, for comparison with the eigenspace learner (method §10)."""

from __future__ import annotations

import torch
from torch import nn

from sfmnet.linalg.factorisation import truncated_svd_factors
from sfmnet.linalg.subspace import principal_angles_deg
from sfmnet.models.sensorimotor_learner import SensorimotorLearner


class LinearAutoencoder(SensorimotorLearner):
    """``x^ = W_d W_e x`` on centred standardised vectors, trained by the trainer's optimiser.

    Loss: ``mean_j |x_j - x^_j|^2 + weight_decay (|W_e|^2 + |W_d|^2)``. Squared error alone
    spans the principal subspace but not its directions (Baldi and Hornik 1989); the L2 term
    makes ``W_e = W_d^T`` at the optimum, so the principal directions are the left singular
    vectors of ``W_d`` (Kunin et al. 2019). At run time the decoder's columns are the basis
    of the same masked projection the eigenspace learner uses.

    Args:
        weight_decay: the L2 weight (must stay below the smallest kept eigenvalue of the
            covariance, about 0.1 for standardised data, or components are switched off).
        init_scale: std of the random initial weights.
        Others as :class:`SensorimotorLearner` (the rank is chosen by the same rule).
    """

    name = "linear_autoencoder"

    def __init__(
        self,
        rank: int | None = None,
        rank_rule: str = "parallel_analysis",
        weight_decay: float = 1e-3,
        init_scale: float = 0.1,
        seed: int = 0,
    ) -> None:
        super().__init__(rank=rank, rank_rule=rank_rule, seed=seed)
        self.weight_decay = weight_decay
        self.init_scale = init_scale
        self.encoder: nn.Linear | None = None
        self.decoder: nn.Linear | None = None
        self.register_buffer("reference_basis", None)

    def start(self, standardised: torch.Tensor) -> None:
        m = standardised.shape[1]
        generator = torch.Generator().manual_seed(self.seed)
        self.encoder = nn.Linear(m, self.rank, bias=False, dtype=standardised.dtype)
        self.decoder = nn.Linear(self.rank, m, bias=False, dtype=standardised.dtype)
        with torch.no_grad():
            for layer in (self.encoder, self.decoder):
                layer.weight.copy_(torch.randn(layer.weight.shape, generator=generator, dtype=standardised.dtype) * self.init_scale)
        # Only to monitor the angle to the principal subspace while training.
        self.reference_basis = truncated_svd_factors(standardised, self.rank, centre=True).shape

    def loss(self, batch: tuple[torch.Tensor, torch.Tensor]) -> dict[str, torch.Tensor]:
        _, vectors = batch
        standardised = self.standardise(vectors)
        reconstruction = self.decoder(self.encoder(standardised))
        terms = {
            "reconstruction": (reconstruction - standardised).pow(2).sum(dim=1).mean(),
            "weight_decay": self.encoder.weight.pow(2).sum() + self.decoder.weight.pow(2).sum(),
        }
        terms["loss"] = terms["reconstruction"] + self.weight_decay * terms["weight_decay"]
        return terms

    def basis(self) -> torch.Tensor:
        return self.decoder.weight.detach().T

    def centre(self) -> torch.Tensor:
        # Standardised vectors are centred on the training set.
        return torch.zeros_like(self.column_mean)

    def reconstruct(self, standardised: torch.Tensor) -> torch.Tensor:
        return self.decoder(self.encoder(standardised))

    def monitor(self) -> dict[str, float]:
        """Largest principal angle to the PCA subspace, degrees (logged every epoch)."""
        return {"subspace_angle_deg": float(principal_angles_deg(self.basis(), self.reference_basis).max())}
