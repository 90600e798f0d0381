"""Far cells (an overflow, a dropped packet, a unit slip) found in memory and in one streamed pass alike."""

from __future__ import annotations

import numpy as np
import pytest

from sfmnet.preprocessing.far_cells import far_cell_limits_chunked, far_cells


def corrupted(seed: int, rows: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    values = rng.normal(size=(rows, 3)) * [1.0, 50.0, 1e-3]
    # A pose held for most of the recording: the rest far from the median, but not far from one another.
    values[: rows * 9 // 10, 0] = 0.5
    values[rng.integers(rows, size=5), 1] = 4294967295.0
    values[rng.integers(rows, size=2), 2] = -1e3
    return values


@pytest.mark.parametrize("rows", [500, 20_000])
def test_a_streamed_pass_finds_the_cells_the_in_memory_check_finds(rows: int):
    values = corrupted(0, rows)
    bad = far_cells(values)
    assert bad[:, 1].sum() == 5 and bad[:, 2].sum() == 2 and not bad[:, 0].any()
    # Chunks far smaller than the tail kept and than the file: the running extremes must merge across them.
    above, below = far_cell_limits_chunked(values, chunk_rows=37)
    np.testing.assert_array_equal((values >= above) | (values <= below), bad)


def test_a_clean_column_has_no_far_cells():
    values = corrupted(1, 5_000)
    values[:, 1:] = np.random.default_rng(2).normal(size=(5_000, 2))
    above, below = far_cell_limits_chunked(values, chunk_rows=1_000)
    assert np.isinf(above[1:]).all() and np.isinf(below).all()
    assert not far_cells(values).any()


def test_far_cells_at_both_ends_of_a_column_are_each_found():
    """A hostile tester's +1e9 and -1e9 in one column: each end's gap measured against a rest that held the other end's
    cell was no gap, and the fit blamed the orientations."""
    values = np.random.default_rng(3).normal(size=(5_600, 2))
    values[0, 0], values[-1, 0] = 1e9, -1e9
    bad = far_cells(values)
    assert bad[[0, -1], 0].all() and bad.sum() == 2
    above, below = far_cell_limits_chunked(values, chunk_rows=1_000)
    np.testing.assert_array_equal((values >= above) | (values <= below), bad)


def test_a_channel_that_barely_moves_is_no_corrupt_cell():
    """A hostile tester's quantised channel: 100 on every row but 20 that read 101. The rest's range is 0, which gives
    no scale to call a step of one count far by."""
    values = np.full((5_600, 1), 100.0)
    values[3_000:3_020] = 101.0
    assert not far_cells(values).any()

