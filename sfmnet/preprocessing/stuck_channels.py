"""A channel holding one value its load does not explain: stuck or disconnected for a run of rows, or clipped at its
range.

With more channels than load axes the readings lie in an ``n``-dimensional affine space, so each channel is a linear
function of the others (where they span the load space): ``z_c ~ beta^T z_(-c) + beta_0``, with a residual of the
noise's size. A channel that holds one value while the others say it should read something else misses that
prediction by far more than its residuals elsewhere. Two kinds of rows are judged, each at least
:data:`MIN_STUCK_ROWS`: each channel's longest run of one value (stuck, disconnected), and the rows reading its largest
or its smallest value (clipped, wherever they lie in the file). They are stuck when their RMS miss of the prediction,
fitted on every other row, is :data:`STUCK_MISS` times the residuals' standard deviation there. A channel that truly
holds still (a hold, a turn about its own sensing axis) with noise under one count is predicted still too, and is
not flagged however long it holds. On hostile testers' quantised sessions (poses, streams, cones about a channel's
axis, 6-10 bits) the clean misses reached 5.2 (a few poses repeat, so the residuals there understate the prediction's
error for a pose left out); stuck and clipped channels missed by 6-1,300, with a median of 60-500.

With as many channels as axes no channel is predicted by the others, and nothing is judged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from sfmnet.preprocessing.chunked_rows import CHUNK_ROWS, Rows, read_rows

MIN_STUCK_ROWS = 10
STUCK_MISS = 10.0


@dataclass(frozen=True)
class StuckReading:
    """One channel holding one value its load does not explain.

    Attributes:
        channel: the channel's index.
        value: the value it holds.
        rows: how many rows hold it.
        first, stop: the rows it spans, ``[first, stop)``; every row between them for a ``run``.
        kind: ``"run"`` (consecutive rows: stuck, disconnected), ``"largest"`` or ``"smallest"`` (its range's end on
            rows anywhere: clipped).
        miss: the RMS of the value less what the other channels predict over those rows, in standard deviations of
            the prediction's residuals over the other rows.
    """

    channel: int
    value: float
    rows: int
    first: int
    stop: int
    kind: str
    miss: float


def stuck_readings(readings: Rows, rank: int, chunk_rows: int = CHUNK_ROWS) -> list[StuckReading]:
    """Each channel's longest run of one value and its range's two ends where the other channels say it is stuck or
    clipped (module docstring); at most one per channel and value, none where ``p <= rank``. Three passes,
    ``chunk_rows`` rows at a time.

    Args:
        readings: ``f x p`` raw readings in row order; rank: ``n``, the load axes.
    """
    f, p = readings.shape
    if p <= rank or f <= p + MIN_STUCK_ROWS:
        return []
    scan = scan_channels(readings, chunk_rows)
    candidates = [
        (channel, "run", float(scan.longest_value[channel]), np.arange(first, stop))
        for channel, (first, stop) in enumerate(scan.longest.tolist())
        if stop - first >= MIN_STUCK_ROWS
    ]
    candidates += range_ends(readings, scan.low, scan.high, chunk_rows)
    found: dict[tuple[int, float], StuckReading] = {}
    for channel, kind, value, rows in candidates:
        if (channel, value) in found:
            continue
        miss = prediction_miss(readings, scan, channel, rows, chunk_rows)
        if miss >= STUCK_MISS:
            found[channel, value] = StuckReading(channel, value, len(rows), int(rows[0]), int(rows[-1]) + 1, kind, miss)
    return list(found.values())


class ChannelScan(NamedTuple):
    """What one pass over the readings gives :func:`stuck_readings`.

    Attributes:
        longest: ``p x 2`` int64, each channel's longest run of one value, ``[first, stop)``; longest_value: ``p``,
            that value.
        low, high: ``p`` each, each channel's smallest and largest reading.
        gram: ``(p + 1) x (p + 1)``, the Gram matrix of the rows less ``origin`` with a 1 appended.
        origin: ``p``, the first row.
    """

    longest: np.ndarray
    longest_value: np.ndarray
    low: np.ndarray
    high: np.ndarray
    gram: np.ndarray
    origin: np.ndarray


def scan_channels(readings: Rows, chunk_rows: int) -> ChannelScan:
    """One pass over the readings, ``chunk_rows`` rows at a time: :class:`ChannelScan`."""
    f, p = readings.shape
    longest = np.tile(np.array([0, min(f, 1)], dtype=np.int64), (p, 1))
    low, high = np.full(p, np.inf), np.full(p, -np.inf)
    gram = np.zeros((p + 1, p + 1))
    origin = np.asarray(readings[0:1], dtype=np.float64)[0]
    longest_value = origin.copy()
    run_first = np.zeros(p, dtype=np.int64)  # where each channel's current run began
    for start in range(0, f, chunk_rows):
        block = np.asarray(readings[start : start + chunk_rows + 1], dtype=np.float64)
        own = block[: chunk_rows] if start + chunk_rows < f else block  # the next block's first row is its own
        low, high = np.minimum(low, own.min(axis=0)), np.maximum(high, own.max(axis=0))
        design = np.concatenate([own - origin, np.ones((len(own), 1))], axis=1)
        gram += design.T @ design
        same = np.diff(block, axis=0) == 0
        last = start + len(block) - 1
        for channel in range(p):
            breaks = start + 1 + np.flatnonzero(~same[:, channel])
            starts = np.concatenate([[run_first[channel]], breaks])
            # The last run goes on into the next block unless the recording ends here.
            ends = np.concatenate([breaks, [last + 1 if last + 1 >= f else last]])
            best = int(np.argmax(ends - starts))
            if ends[best] - starts[best] > longest[channel, 1] - longest[channel, 0]:
                longest[channel] = starts[best], ends[best]
                # A run begun in an earlier block holds the value this one starts with.
                longest_value[channel] = block[max(starts[best] - start, 0), channel]
            run_first[channel] = starts[-1]
    return ChannelScan(longest, longest_value, low, high, gram, origin)


def range_ends(
    readings: Rows, low: np.ndarray, high: np.ndarray, chunk_rows: int
) -> list[tuple[int, str, float, np.ndarray]]:
    """``(channel, "largest" or "smallest", value, rows)`` for each channel's range end read by at least
    :data:`MIN_STUCK_ROWS` rows (``rows``: their indices)."""
    f, p = readings.shape
    ends = {"largest": high, "smallest": low}
    rows: dict[tuple[int, str], list[np.ndarray]] = {(channel, kind): [] for kind in ends for channel in range(p)}
    for start in range(0, f, chunk_rows):
        block = np.asarray(readings[start : start + chunk_rows], dtype=np.float64)
        for kind, end in ends.items():
            at_end = block == end
            for channel in np.flatnonzero(at_end.any(axis=0)):
                rows[channel, kind].append(start + np.flatnonzero(at_end[:, channel]))
    return [
        (channel, kind, float(ends[kind][channel]), np.concatenate(found))
        for (channel, kind), found in rows.items()
        if found and sum(len(part) for part in found) >= MIN_STUCK_ROWS
    ]


def prediction_miss(readings: Rows, scan: ChannelScan, channel: int, rows: np.ndarray, chunk_rows: int) -> float:
    """The RMS of channel ``channel`` less its least-squares prediction from the other channels over ``rows``, the
    prediction fitted on every other row (``scan.gram`` less theirs), in standard deviations of its residuals there;
    0 where the other channels do not predict it."""
    f, p = readings.shape
    values = read_rows(readings, rows, chunk_rows) - scan.origin
    design = np.concatenate([values, np.ones((len(values), 1))], axis=1)
    rest = scan.gram - design.T @ design
    others = np.array([k for k in range(p + 1) if k != channel])
    try:
        beta = np.linalg.solve(rest[np.ix_(others, others)], rest[others, channel])
    except np.linalg.LinAlgError:
        return 0.0
    residual_squares = rest[channel, channel] - rest[others, channel] @ beta
    dof = f - len(rows) - p
    if dof <= 0 or not residual_squares > 0:
        return 0.0
    miss = values[:, channel] - design[:, others] @ beta
    return float(np.sqrt(np.mean(miss**2) / (residual_squares / dof)))

