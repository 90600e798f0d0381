"""Sufficient statistics of a stream of rows: count, sums and cross products about a fixed shift (NOTES 11).

The closed forms need only these for ``f >> p``: one pass over the data, memory independent
of ``f``, and statistics of several shards (processes, files) add up exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class Moments:
    """``count``, ``total = sum_j (z_j - c)`` (``p``) and ``cross = sum_j (z_j - c)^T (z_j - c)`` (``p x p``).

    Accumulated in float64 about a fixed shift ``c`` (``p``, e.g. the first rows' mean) so the
    centred cross product does not cancel catastrophically when offsets dwarf the spread.
    """

    shift: torch.Tensor
    count: torch.Tensor
    total: torch.Tensor
    cross: torch.Tensor

    @classmethod
    def empty(cls, shift: torch.Tensor) -> Moments:
        shift = shift.to(torch.float64)
        p = len(shift)
        return cls(shift, torch.zeros((), dtype=torch.float64), torch.zeros(p, dtype=torch.float64), torch.zeros(p, p, dtype=torch.float64))

    def update(self, rows: torch.Tensor) -> None:
        """Add a batch of rows (``b x p``, any float dtype)."""
        self.add_shifted(rows.to(torch.float64) - self.shift.to(rows.device))

    def add_shifted(self, shifted: torch.Tensor) -> None:
        """Add a batch already minus the shift (``b x p`` float64), as a streaming reader can produce it in one pass."""
        self.count += len(shifted)
        self.total += shifted.sum(dim=0).to(self.total.device)
        self.cross += cross_product(shifted).to(self.cross.device)

    def mean(self) -> torch.Tensor:
        """``p``: the column mean."""
        return self.shift + self.total / self.count

    def centred_cross(self) -> torch.Tensor:
        """``sum_j (z_j - mean)^T (z_j - mean)`` (``p x p``) = ``cross - total^T total / count``."""
        return self.cross - torch.outer(self.total, self.total) / self.count


def principal_subspace(moments: Moments, rank: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Affine PCA from the statistics: components (``k x p``, orthonormal rows) and singular values (``k``).

    The singular values of the centred data are the square roots of the eigenvalues of its
    centred cross product (paper eqs. 6-8 with ``Z* = U S V^T``: ``Z*^T Z* = V S^2 V^T``).
    """
    eigenvalues, vectors = torch.linalg.eigh(moments.centred_cross())
    order = torch.argsort(eigenvalues, descending=True)[:rank]
    components = vectors[:, order].T
    # A fixed sign per component (largest entry positive) so runs compare entry by entry.
    signs = torch.sign(components.gather(1, components.abs().argmax(dim=1, keepdim=True)))
    return components * signs, eigenvalues[order].clamp_min(0).sqrt()


def cross_product(rows: torch.Tensor) -> torch.Tensor:
    """``rows^T rows`` (``p x p``). On the CPU through numpy's BLAS, which handles tall, narrow
    blocks several times faster than torch's matmul (measured: 4 against 18 ms for 524288 x 8)."""
    if rows.device.type == "cpu":
        array = rows.numpy()
        return torch.from_numpy(array.T @ array)
    return rows.T @ rows
