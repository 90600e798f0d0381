"""Rows that repeat the row before: a logger polling faster than its sensor updates, or readings coarser than their noise.

Repeated readings are not new measurements, so error bars that count every row as one are too small
(:func:`~sfmnet.eval.goodness_of_fit.repeated_rows_warning` judges the counts), and a file of independent poses each
logged several times would look like a slow stream if its zero steps were counted
(:func:`~sfmnet.preprocessing.static_intervals.serial_scan` leaves them out).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sfmnet.preprocessing.chunked_rows import CHUNK_ROWS, Rows


@dataclass(frozen=True)
class RowRepeats:
    """How often rows repeat the row before, over the rows judged (the static intervals, or every row).

    Attributes:
        whole: rows equal to the row before on every channel.
        per_channel: ``p`` int, rows equal to the row before on each channel alone.
        steps: the row-to-row steps counted (rows judged less one per interval).
    """

    whole: int
    per_channel: np.ndarray
    steps: int


def row_repeats(readings: Rows, intervals: np.ndarray | None = None, chunk_rows: int = CHUNK_ROWS) -> RowRepeats:
    """Count the rows equal to the row before within each of ``intervals`` (``k x 2`` half-open row ranges), or over
    every row (None), reading ``chunk_rows`` rows at a time."""
    f, p = readings.shape
    spans = np.array([[0, f]]) if intervals is None else intervals
    whole, per_channel, steps = 0, np.zeros(p, dtype=np.int64), 0
    for first, stop in spans.tolist():
        steps += max(stop - first - 1, 0)
        for start in range(first, stop - 1, chunk_rows):
            block = np.asarray(readings[start : min(stop, start + chunk_rows + 1)])
            same = np.diff(block, axis=0) == 0
            whole += int(same.all(axis=1).sum())
            per_channel += same.sum(axis=0)
    return RowRepeats(whole=whole, per_channel=per_channel, steps=steps)
