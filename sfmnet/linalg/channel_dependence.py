"""Channels that are linear functions of one another: a copied column, a channel computed from others."""

from __future__ import annotations

import torch

# The smallest eigenvalue of the channels' correlation matrix below which they count as dependent. Rounding leaves
# about 1e-16 on a copied column; two real channels of a sensor, however alike, differ by their own noise (even 1e-5
# of the signal's spread gives 1e-10 here, twice this).
DEPENDENT_EIGENVALUE = 5e-11


def dependent_channels(scatter: torch.Tensor, rows: int, axes: int) -> list[int]:
    """The channels of an exact linear dependence among the readings, or none: ``scatter`` (``p x p``) is the
    ``rows`` readings' scatter about their mean, ``sum_j (z_j - zbar)(z_j - zbar)^T``, of a sensor of ``axes`` load
    axes.

    In the correlation matrix ``R = D^-1/2 scatter D^-1/2`` (``D`` its diagonal, so channels of any units compare), an
    eigenvalue under :data:`DEPENDENT_EIGENVALUE` is a combination of channels that never varies: one is a copy, a
    multiple or an affine function of the others. Its eigenvector names them (components over a tenth of its largest).
    The calibration's noise model (each channel's own noise) has no such channel. Readings that span fewer dimensions
    than ``axes`` are left to the fit, which says why (loads collinear or coplanar), and so are ``p`` rows or fewer,
    which span fewer than ``p`` dimensions about their mean whatever the channels (the fit counts its unknowns).
    """
    if rows <= len(scatter):
        return []
    spread = scatter.diagonal().clamp_min(torch.finfo(scatter.dtype).tiny).sqrt()
    correlation = scatter / spread[:, None] / spread[None, :]
    values, vectors = torch.linalg.eigh(correlation)
    null = values < DEPENDENT_EIGENVALUE * values[-1]
    if not bool(null.any()) or len(values) - int(null.sum()) < axes:
        return []
    weights = vectors[:, 0].abs()
    return [int(k) for k in torch.nonzero(weights > 0.1 * weights.max())[:, 0]]


def dependent_channels_message(names: list[str], source: str) -> str:
    """The one line refusing readings whose channels ``names`` are linearly dependent."""
    return (
        f"channels {', '.join(names)}{source} are linear functions of one another (a column copied, scaled or computed "
        "from others; or simulated readings without noise): the noise model needs each channel's own noise; leave "
        "out one of them with data.channel_columns=[...], and more until none is a function of the others (or add "
        "noise to a simulation)"
    )
