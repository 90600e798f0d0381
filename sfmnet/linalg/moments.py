"""Sufficient statistics of a stream of rows: count, sums and cross products about a fixed shift (method §11).

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

    def cross_about(self, point: torch.Tensor) -> torch.Tensor:
        """``sum_j (z_j - a)^T (z_j - a)`` (``p x p``) about any point ``a`` (``p``), e.g. offsets or the origin."""
        d = point.to(self.shift) - self.shift
        return self.cross - torch.outer(d, self.total) - torch.outer(self.total, d) + self.count * torch.outer(d, d)


def principal_subspace(scatter: torch.Tensor, rank: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The leading right singular vectors (``k x p``, orthonormal rows) and singular values (``k``) of
    data whose scatter ``Z*^T Z*`` (``p x p``) is given, e.g. :meth:`Moments.centred_cross` for PCA.

    From paper eqs. 6-8 with ``Z* = U Sigma V^T``: ``Z*^T Z* = V Sigma^2 V^T``.
    """
    eigenvalues, vectors = torch.linalg.eigh(scatter)
    order = torch.argsort(eigenvalues, descending=True)[:rank]
    components = vectors[:, order].T
    # A fixed sign per component (largest entry positive) so runs compare entry by entry.
    signs = torch.sign(components.gather(1, components.abs().argmax(dim=1, keepdim=True)))
    return components * signs, eigenvalues[order].clamp_min(0).sqrt()


def singular_values_from_scatter(scatter: torch.Tensor) -> torch.Tensor:
    """All ``p`` singular values of data with scatter ``Z*^T Z*``, descending."""
    return torch.linalg.eigvalsh(scatter).flip(0).clamp_min(0).sqrt()


def cross_product(rows: torch.Tensor, other: torch.Tensor | None = None) -> torch.Tensor:
    """``rows^T other`` (``p x q``; ``other`` defaults to ``rows``). On the CPU through numpy's BLAS, which
    handles tall, narrow blocks several times faster than torch's matmul (measured: 4 against 18 ms for 524288 x 8)."""
    if rows.device.type == "cpu":
        array = rows.numpy()
        return torch.from_numpy(array.T @ (array if other is None else other.numpy()))
    return rows.T @ (rows if other is None else other)
