"""Readings read a chunk of rows at a time, so a pass over a recording holds ``O(chunk)`` of it in memory."""

from __future__ import annotations

from typing import Protocol

import numpy as np

CHUNK_ROWS = 65_536


class Rows(Protocol):
    """Row-sliceable ``f x p`` (or ``f``) values: a numpy array, a memory map, or an adapter reading a file."""

    shape: tuple[int, ...]

    def __getitem__(self, rows: slice) -> np.ndarray: ...


def read_rows(values: Rows, rows: np.ndarray, chunk_rows: int = CHUNK_ROWS) -> np.ndarray:
    """``values`` (``f`` or ``f x p``) at ``rows`` (int, in any order), float64, reading only the chunks that hold them."""
    out = np.empty((len(rows), *values.shape[1:]), dtype=np.float64)
    for chunk in np.unique(rows // chunk_rows):
        first = int(chunk) * chunk_rows
        inside = rows // chunk_rows == chunk
        out[inside] = np.asarray(values[first : first + chunk_rows], dtype=np.float64)[rows[inside] - first]
    return out
