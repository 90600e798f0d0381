"""A channel holding one value the load does not explain: stuck or disconnected for a run of rows, or clipped at its
range.

A channel that repeats the row before on a share ``q`` of its steps holds one value for ``L`` rows somewhere among
``f`` by chance about ``f q^(L - 1)`` times. Readings coarser than their noise repeat often, and more often at some
levels than at others (a level in the middle of a count holds longer than one at its edge), so a long run within a hold
is no fault; but one through which the other channels move by a good share of their range spans a change of load the
channel did not read. A run is stuck when both hold: unlikely at the channel's own rate (:data:`STUCK_CHANCE`, at least
:data:`MIN_STUCK_ROWS` rows) and another channel moving over it by :data:`MOVED_SHARE` of its range.

A clipped channel reads its range's end on every row whose load would take it further, wherever those rows lie in the
file: its largest (or smallest) reading on many rows, :data:`CLIP_SPIKE` times as many as read the level next to it
(a channel's readings spread over its levels; a clip piles every row beyond it onto one), again with another channel
moving over those rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sfmnet.preprocessing.chunked_rows import CHUNK_ROWS, Rows

MIN_STUCK_ROWS = 10
STUCK_CHANCE = 1e-3
MOVED_SHARE = 0.1
CLIP_SPIKE = 5.0


@dataclass(frozen=True)
class StuckReading:
    """One channel holding one value the load does not explain.

    Attributes:
        channel: the channel's index.
        value: the value it holds.
        rows: how many rows hold it.
        first, stop: the rows it spans, ``[first, stop)``; every row between them for a ``run``.
        kind: ``"run"`` (consecutive rows: stuck, disconnected), ``"largest"`` or ``"smallest"`` (its range's end on
            rows anywhere: clipped).
        moved_share: the most another channel moved over those rows, a fraction of its range over the recording.
        chance: a ``run``: the channel's share of steps repeating the row before, elsewhere; a clip: the rows at the
            level next to it over ``rows``.
    """

    channel: int
    value: float
    rows: int
    first: int
    stop: int
    kind: str
    moved_share: float
    chance: float


def stuck_readings(readings: Rows, chunk_rows: int = CHUNK_ROWS) -> list[StuckReading]:
    """Each channel's longest run of one value and its range's two ends, where they are stuck or clipped (module
    docstring); at most one per channel and value. A few passes, ``chunk_rows`` rows at a time.

    Args:
        readings: ``f x p`` raw readings in row order.
    """
    f, p = readings.shape
    longest, repeats, low, high = scan_channels(readings, chunk_rows)
    spread = np.where(high > low, high - low, np.inf)
    found = {(clip.channel, clip.value): clip for clip in clipped_levels(readings, low, high, spread, chunk_rows)}
    for channel in range(p):
        first, stop = (int(row) for row in longest[channel])
        inside = stop - first - 1
        rate = (int(repeats[channel]) - inside) / max(f - 1 - inside, 1)
        if stop - first < MIN_STUCK_ROWS or f * rate ** (stop - first - 1) >= STUCK_CHANCE:
            continue
        block = np.asarray(readings[first:stop], dtype=np.float64)
        moved = np.ptp(block, axis=0) / spread
        moved[channel] = 0.0
        value = float(block[0, channel])
        if moved.max() >= MOVED_SHARE and (channel, value) not in found:
            found[channel, value] = StuckReading(channel, value, stop - first, first, stop, "run", float(moved.max()), rate)
    return list(found.values())


def scan_channels(readings: Rows, chunk_rows: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One pass: ``p x 2`` int64, each channel's longest run of one value, ``[first, stop)``; ``p`` int, its rows equal
    to the row before; ``p`` each, its smallest and largest reading."""
    f, p = readings.shape
    longest = np.tile(np.array([0, min(f, 1)], dtype=np.int64), (p, 1))
    repeats = np.zeros(p, dtype=np.int64)
    low, high = np.full(p, np.inf), np.full(p, -np.inf)
    run_first = np.zeros(p, dtype=np.int64)  # where each channel's current run began
    for start in range(0, max(f - 1, 1), chunk_rows):
        block = np.asarray(readings[start : start + chunk_rows + 1], dtype=np.float64)
        low, high = np.minimum(low, block.min(axis=0)), np.maximum(high, block.max(axis=0))
        same = np.diff(block, axis=0) == 0
        repeats += same.sum(axis=0)
        last = start + len(block) - 1  # the block's last row, the next block's first
        for channel in range(p):
            breaks = start + 1 + np.flatnonzero(~same[:, channel])
            starts = np.concatenate([[run_first[channel]], breaks])
            # The last run goes on into the next block unless the recording ends here.
            ends = np.concatenate([breaks, [last + 1 if last + 1 >= f else last]])
            best = int(np.argmax(ends - starts))
            if ends[best] - starts[best] > longest[channel, 1] - longest[channel, 0]:
                longest[channel] = starts[best], ends[best]
            run_first[channel] = starts[-1]
    return longest, repeats, low, high


def clipped_levels(
    readings: Rows, low: np.ndarray, high: np.ndarray, spread: np.ndarray, chunk_rows: int
) -> list[StuckReading]:
    """The range ends (``low``, ``high``: ``p`` each) that are clips (module docstring): read by at least
    :data:`MIN_STUCK_ROWS` rows, :data:`CLIP_SPIKE` times as many as read the next level in, while another channel
    moves over those rows by :data:`MOVED_SHARE` of its range (``spread``, ``p``). Two passes."""
    f, p = readings.shape
    ends = {"largest": (high, 1.0), "smallest": (low, -1.0)}  # the sign turns each into a largest
    count = {kind: np.zeros(p, dtype=np.int64) for kind in ends}
    inner = {kind: np.full(p, -np.inf) for kind in ends}  # the next level in, signed
    for start in range(0, f, chunk_rows):
        block = np.asarray(readings[start : start + chunk_rows], dtype=np.float64)
        for kind, (end, sign) in ends.items():
            at_end = block == end
            count[kind] += at_end.sum(axis=0)
            inner[kind] = np.maximum(inner[kind], np.where(at_end, -np.inf, sign * block).max(axis=0))
    candidates = [(channel, kind) for kind in ends for channel in range(p) if count[kind][channel] >= MIN_STUCK_ROWS]
    if not candidates:
        return []
    inner_count = {kind: np.zeros(p, dtype=np.int64) for kind in ends}
    lows = {key: np.full(p, np.inf) for key in candidates}
    highs = {key: np.full(p, -np.inf) for key in candidates}
    spans = {key: [f, 0] for key in candidates}
    for start in range(0, f, chunk_rows):
        block = np.asarray(readings[start : start + chunk_rows], dtype=np.float64)
        for kind, (_, sign) in ends.items():
            inner_count[kind] += (sign * block == inner[kind]).sum(axis=0)
        for channel, kind in candidates:
            at = np.flatnonzero(block[:, channel] == ends[kind][0][channel])
            if len(at):
                key = (channel, kind)
                lows[key] = np.minimum(lows[key], block[at].min(axis=0))
                highs[key] = np.maximum(highs[key], block[at].max(axis=0))
                spans[key] = [min(spans[key][0], start + int(at[0])), max(spans[key][1], start + int(at[-1]) + 1)]
    clips = []
    for key in candidates:
        channel, kind = key
        rows, next_rows = int(count[kind][channel]), int(inner_count[kind][channel])
        moved = (highs[key] - lows[key]) / spread
        moved[channel] = 0.0
        if rows >= CLIP_SPIKE * next_rows and moved.max() >= MOVED_SHARE:
            clips.append(StuckReading(
                channel, float(ends[kind][0][channel]), rows, *spans[key], kind, float(moved.max()), next_rows / rows,
            ))
    return clips
