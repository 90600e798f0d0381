"""Corrupt cells that stand far apart from the rest of their column (an overflow, a dropped packet, a unit slip).

A gap, not a distance from the median: a pose held for most of a recording leaves the other poses' readings far from
the median but near one another. A cell that far out takes the closed form's subspace over, and the fit then blames
the orientations (a hostile tester's 0xFFFFFFFF in counts: "the loads are collinear or coplanar").
"""

from __future__ import annotations

import numpy as np

from sfmnet.preprocessing.chunked_rows import CHUNK_ROWS, Rows

# A cell this many times the range of the rest of its column away from them is corrupt: no sensor reads one pose that
# far from all its others (the hostile tester's 1e4 in a column of range 5, 2e3 times, is left to the fit, which
# names the row as an outlier).
FAR_CELL_SPREADS = 1e4
# The most cells at either end of a column that one gap may set apart: 1 % of the rows, and at most this many, so that a
# streamed pass keeps ``O(MAX_FAR_CELLS * p)`` of a recording of any length.
MAX_FAR_CELLS = 100_000


FAR_CELLS_REMEDY = "corrupt cells (an overflow, a dropped packet, a unit slip): repair or remove those rows"


def far_cells_what(role: str, count: int) -> str:
    """How a refusal names ``count`` far cells of ``role`` columns ("reading")."""
    return f"{role} value{'' if count == 1 else 's'} over {FAR_CELL_SPREADS:.0e} times the spread of the rest of their column away from it"


def far_cell_tail(rows: int) -> int:
    """How many cells at either end of a column of ``rows`` cells the check looks at."""
    return min(max(1, rows // 100), MAX_FAR_CELLS)


def far_cell_limits(lowest: np.ndarray, highest: np.ndarray, rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Per column, the cells at or above ``above`` and at or below ``below`` are far cells (``inf``, ``-inf``: none).

    Args:
        lowest: ``(t + 1) x p``, each column's ``t + 1`` smallest cells, ascending (``t`` = :func:`far_cell_tail`).
        highest: ``(t + 1) x p``, its ``t + 1`` largest cells, ascending (the last row the column's maximum).
        rows: the column's length, more than ``2 t + 1``.

    Returns:
        ``above``, ``below`` (``p`` each): the top (bottom) ``k <= t`` cells are far where the gap between them and the
        rest (less the other end's ``t`` cells) is over :data:`FAR_CELL_SPREADS` times the rest's range, and that range
        is not 0; the largest such ``k`` is taken.
    """
    tail = len(lowest) - 1
    assert rows > 2 * tail + 1, "the two ends must not overlap"
    k = np.arange(1, tail + 1)
    columns = np.arange(lowest.shape[1])
    # Row k - 1 of each: the top (bottom) k cells against the rest, the gap between over the rest's range. The rest
    # leaves out the other end's t cells, which may be far cells too (an overflow at one end, its negative at the
    # other); a rest of one value (a channel that barely moves, quantised) gives no scale to judge a gap by.
    high_k, high_rest = highest[tail + 1 - k], highest[tail - k]
    high_range = high_rest - lowest[tail]
    high = (high_k - high_rest > FAR_CELL_SPREADS * high_range) & (high_range > 0)
    low_k, low_rest = lowest[k - 1], lowest[k]
    low_range = highest[0] - low_rest
    low = (low_rest - low_k > FAR_CELL_SPREADS * low_range) & (low_range > 0)
    # The most cells such a gap sets apart, at each end of each column (0: none).
    top = np.where(high.any(axis=0), tail - np.argmax(high[::-1], axis=0), 0)
    bottom = np.where(low.any(axis=0), tail - np.argmax(low[::-1], axis=0), 0)
    above = np.where(top > 0, highest[tail + 1 - np.maximum(top, 1), columns], np.inf)
    below = np.where(bottom > 0, lowest[np.maximum(bottom, 1) - 1, columns], -np.inf)
    return above, below


def far_cells(values: np.ndarray) -> np.ndarray:
    """``f x p`` bool: the far cells of ``values`` (``f x p``, finite, in memory), by :func:`far_cell_limits`."""
    above, below = far_cell_limits_chunked(values, chunk_rows=max(1, len(values)))
    return (values >= above) | (values <= below)


def far_cell_limits_chunked(values: Rows, chunk_rows: int = CHUNK_ROWS) -> tuple[np.ndarray, np.ndarray]:
    """:func:`far_cell_limits` of ``values`` (``f x p``, finite, row-sliceable: a memory map) in one pass of chunks,
    holding each column's ``t + 1`` smallest and largest cells so far (``O((t + chunk) p)`` memory)."""
    rows, p = values.shape
    tail = far_cell_tail(rows)
    if rows <= 2 * tail + 1:
        return np.full(p, np.inf), np.full(p, -np.inf)
    lowest = np.empty((0, p))
    highest = np.empty((0, p))
    for start in range(0, rows, chunk_rows):
        chunk = np.asarray(values[start : start + chunk_rows], dtype=np.float64)
        lowest = smallest(np.concatenate([lowest, chunk]), tail + 1)
        highest = -smallest(-np.concatenate([highest, chunk]), tail + 1)[::-1]
    return far_cell_limits(lowest, highest, rows)


def smallest(values: np.ndarray, count: int) -> np.ndarray:
    """Each column's ``count`` smallest cells of ``values`` (``m x p``), ascending (all of them when ``m <= count``)."""
    if len(values) > count:
        values = np.partition(values, count - 1, axis=0)[:count]
    return np.sort(values, axis=0)
