"""Readings read a chunk of rows at a time, so a pass over a recording holds ``O(chunk)`` of it in memory."""

from __future__ import annotations

from typing import Protocol

import numpy as np

CHUNK_ROWS = 65_536


class Rows(Protocol):
    """Row-sliceable ``f x p`` (or ``f``) values: a numpy array, a memory map, or an adapter reading a file."""

    shape: tuple[int, ...]

    def __getitem__(self, rows: slice) -> np.ndarray: ...
