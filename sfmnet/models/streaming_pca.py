"""Affine PCA of rows streamed from disk, from their sufficient statistics (method §11)."""

from __future__ import annotations

import torch
from torch import nn

from sfmnet.data.rows import RowBlock, RowData
from sfmnet.errors import SfmnetError
from sfmnet.linalg.moments import Moments, principal_subspace
from sfmnet.models.contracts import FitMode


class StreamingPCA(nn.Module):
    """The factorisation's closed form (centred truncated SVD, paper eqs. 6-8) from one pass of statistics.

    Each training step adds a block to the :class:`Moments` (``Z^T Z`` in float64 about a fixed
    shift); at the end of the pass the statistics are summed over processes by the trainer's
    strategy and the components come from the eigendecomposition of the centred cross
    product. Memory is ``O(p^2)`` whatever the number of rows.

    Args:
        rank: ``k``, the components kept.
    """

    name = "pca"
    recording = "rows"
    dev_run_passes = 1
    converged = True  # one pass is the whole fit

    def __init__(self, rank: int) -> None:
        super().__init__()
        self.rank = rank
        self.moments: Moments | None = None
        # Parameters, not buffers, so a distributed strategy has something to wrap.
        self.components: nn.Parameter | None = None
        self.mean: nn.Parameter | None = None
        self.register_buffer("singular_values", None)

    @property
    def is_initialised(self) -> bool:
        return self.moments is not None

    def fit_mode(self) -> FitMode:
        return FitMode.PASSES

    def prepare_step(self, batch: RowBlock) -> None:
        """Nothing to do before a step."""

    def end_fit(self, data: RowData) -> None:
        """Nothing to do after the last step."""

    def monitor(self) -> dict[str, float]:
        return {}

    def initialise(self, data: RowData) -> None:
        p = len(data.channels)
        if not 1 <= self.rank <= p:
            raise SfmnetError(f"model.rank is {self.rank} but the file has {p} columns: choose 1 to {p}")
        self.data = data
        self.moments = Moments.empty(data.shift)
        self.components = nn.Parameter(torch.zeros(self.rank, p, dtype=torch.float64))
        self.mean = nn.Parameter(torch.zeros(p, dtype=torch.float64))

    def begin_pass(self) -> None:
        self.moments = Moments.empty(self.data.shift)

    def accumulate(self, block: RowBlock) -> None:
        """Add a block of rows, which arrive minus the data's shift."""
        self.moments.add_shifted(block.readings)

    def reduce(self, strategy) -> None:
        """Sum the statistics over processes (each block was read by exactly one)."""
        for name in ("count", "total", "cross"):
            setattr(self.moments, name, strategy.reduce(getattr(self.moments, name), reduce_op="sum"))

    @torch.no_grad()
    def finalise(self) -> None:
        if self.moments.count <= self.rank:
            raise SfmnetError(f"{int(self.moments.count)} rows for {self.rank} components: give more rows or a smaller model.rank")
        self.data.require_plausible(self.moments)
        components, singular = principal_subspace(self.moments.centred_cross(), self.rank)
        self.components.copy_(components)
        self.mean.copy_(self.moments.mean())
        self.singular_values = singular

    @property
    def shape(self) -> torch.Tensor:
        """``Sigma^(1/2) V^T`` (eq. 8), so the trainer logs the same singular values as for every factorisation."""
        if self.singular_values is None:
            return self.components.detach()
        return self.singular_values.sqrt()[:, None] * self.components.detach()

