"""Anderson acceleration of a fixed-point iteration ``x <- G(x)`` (the alternation of method §5)."""

from __future__ import annotations

import torch


def anderson_mix(mapped: list[torch.Tensor], residuals: list[torch.Tensor]) -> torch.Tensor:
    """``sum_i a_i G(x_i)`` with ``a = argmin |sum_i a_i r_i|``, ``sum_i a_i = 1`` (``r_i = G(x_i) - x_i``)."""
    if len(mapped) == 1:
        return mapped[0]
    r = torch.stack(residuals, dim=1)
    differences = r[:, 1:] - r[:, :1]
    gamma = torch.linalg.lstsq(differences, -r[:, 0:1]).solution[:, 0]
    weights = torch.cat([1 - gamma.sum(dim=0, keepdim=True), gamma])
    return torch.stack(mapped, dim=1) @ weights


class AndersonAcceleration:
    """Mixes the last ``history`` rounds of a linearly converging map; a round that raises the step restarts it.

    Plain alternation converges linearly and can be slow (offsets with a partial frame from
    ``n - 1`` known loads); Anderson mixing reaches the same fixed point in far fewer rounds.

    Attributes:
        step_norm: ``|G(x) - x|`` of the latest round (inf before the first).
    """

    def __init__(self, history: int = 5) -> None:
        self.history = history
        self.iterates: list[torch.Tensor] = []
        self.residuals: list[torch.Tensor] = []
        self.best = float("inf")
        self.step_norm = float("inf")

    def state_dict(self) -> dict[str, object]:
        """The history, as tensors and numbers (what a checkpoint keeps)."""
        return {"iterates": list(self.iterates), "residuals": list(self.residuals), "best": self.best, "step_norm": self.step_norm}

    def load_state_dict(self, state: dict[str, object]) -> None:
        self.iterates, self.residuals = list(state["iterates"]), list(state["residuals"])
        self.best, self.step_norm = float(state["best"]), float(state["step_norm"])

    def step(self, current: torch.Tensor, mapped: torch.Tensor) -> torch.Tensor:
        """The next iterate (shape of ``current``) from ``x = current`` and ``G(x) = mapped``."""
        residual = (mapped - current).flatten()
        self.step_norm = float(residual.norm())
        if self.step_norm > self.best:
            self.iterates, self.residuals = [], []
            return mapped
        self.best = self.step_norm
        self.iterates = [*self.iterates, mapped.flatten()][-self.history :]
        self.residuals = [*self.residuals, residual][-self.history :]
        return anderson_mix(self.iterates, self.residuals).reshape(current.shape)
