"""Static intervals of a continuous recording: the rows where the sensor was held still.

A logger that runs on while a robot or a hand carries the sensor from pose to pose records
inertial loads between the poses (``|F| != m g``). Following IMU calibration tools (IMU-TK,
Tedaldi et al., ICRA 2014), a row is static when the variance of a moving window centred on
it, relative to each channel's noise floor and averaged over the channels, is below a
threshold; runs of static rows shorter than a minimum are dropped, and on request (``trim_ends``) each run's ends
are cut where its readings have drifted from its middle's (a move that starts or ends slowly shifts the mean before
the variance notices). The noise floor comes from
the recording itself (a low quantile of each channel's windowed standard deviation), so no
rest period is needed: only that at least ``noise_quantile`` of the rows are static.

A file of independent poses (one sample per pose, in any order) is no stream: consecutive
rows are as different as any two, and then every row is a static sample and nothing is dropped.

The time column is read as a logger writes it. Its tick is the median of its positive steps (the
period, or the clock's resolution when that is coarser) and the period is the mean step apart from
gaps. A step longer than ``GAP_PERIODS`` ticks is a gap (a logger that drops the rows in motion, or
loses packets): no window reaches across one and no interval spans one, and a hold that fills the
stretch between two gaps (or a gap and the recording's end) is kept if it is one window long (or
the minimum duration, if shorter): the minimum duration guards against a pause inside a move, and a
logger that kept only the holds leaves no move around it. A stamp at most ``JITTER_PERIODS`` ticks behind the row before's is
jitter (a logger stamping on receipt, two packets swapped, a coarse clock repeating a stamp): the
rows are taken in file order; a step further back is refused.

Every pass reads the rows in chunks (an array or anything sliceable by rows, e.g. a memory
map), so memory is ``O(f)`` bytes for the mask whatever the number of channels.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from sfmnet.errors import SfmnetError
from sfmnet.preprocessing.chunked_rows import CHUNK_ROWS, Rows, read_rows
from sfmnet.preprocessing.row_repeats import RowRepeats, row_repeats

NOISE_SAMPLES = 100_000   # windows per channel the noise-floor quantile is taken over, at most
PREVIEW_ROWS = 20_000     # rows kept for plotting the stream, at most
PREVIEW_CHANNELS = 3
# Mean squared step between consecutive rows (rows repeated whole left out) over twice the variance: 1 for
# independent rows, about (noise / spread)^2 for a stream. Above this the rows are taken as independent poses.
INDEPENDENT_RATIO = 0.5
DEFAULT_WINDOW = {True: 0.5, False: 25}   # seconds with time, rows without
DEFAULT_THRESHOLD = 3.0
DRIFT_RATIO = 2.0         # an interval's end drifted where its rows stray this many times as far as its middle's
DRIFT_MIDDLE_ROWS = 20_000  # an interval's central rows its ends are judged against, at most
DEFAULT_NOISE_QUANTILE = 0.1
GAP_PERIODS = 5.0         # a time step over this many ticks splits the stream
JITTER_PERIODS = 2.0      # a time step back by at most this many ticks is jitter, not disorder
MANY_BACK_STEPS = 0.01    # steps back past the jitter in more than this fraction of a chunk's rows: stamps that jitter, not one bad row
MANY_BACK_STEPS_AT_LEAST = 10  # ... and more than this many: a short file's few corrupt stamps are each named
MAX_GAP_FRACTION = 0.1    # more of the steps gaps than this: the time column is not one clock at one rate
# A clock whose tick is over this fraction of the recording's span puts its period (span over rows) that far off: a
# tester's epoch seconds stored as float32 (steps of 128 s) held 2 values over 90 s of rows, a period 1.43x wrong.
MAX_TICK_PER_SPAN = 0.25
COARSE_CLOCK_ADVICE = (
    "(seconds since 1970 stored as float32 keep steps of 128 s); store the time as float64 or as seconds from the start, "
    "or give no time column (rows then go by row order)"
)
FULL_WINDOWS = 100        # the noise floor is taken over whole windows only when at least this many are sampled
FLAT_VARIANCE = 1e-10     # a window is flat where its variance is under this fraction of the channel's span squared
FLAT_LEVELS_SHARE = 0.5   # a channel's flat windows this much at its two commonest levels: clipped or stuck there


def intervals_of(rows: np.ndarray, intervals: np.ndarray) -> np.ndarray:
    """Each of ``rows`` (``r`` int, row indices)'s interval in ``intervals`` (``k x 2``, half-open, in order): ``r``
    int64, -1 outside every interval. ``O(k)`` memory, so a stream's rows can be looked up block by block."""
    slot = np.searchsorted(intervals[:, 0], rows, side="right") - 1
    inside = (slot >= 0) & (rows < intervals[np.maximum(slot, 0), 1]) if len(intervals) else np.zeros(len(rows), bool)
    return np.where(inside, slot, -1).astype(np.int64)


@dataclass(frozen=True)
class StaticIntervals:
    """Where a recording was static.

    Attributes:
        mask: ``f`` bool, the rows kept (inside a static interval).
        intervals: ``k x 2`` int64, half-open row ranges ``[first, stop)`` in order; one per row
            when ``independent``.
        noise_floor: ``p`` raw units, each channel's noise standard deviation (NaN when ``independent``).
        statistic: ``f`` float32, the windowed variance over the noise floor's square, averaged over
            channels (about 1 at rest; zeros when ``independent``).
        threshold: the statistic below which a row is static.
        window_rows: rows in the centred moving window (odd).
        min_rows: the shortest interval kept, rows (at most a window for one filling its stretch between gaps).
        period: seconds per row (the time column's mean step apart from gaps), or None without time.
        gap_rows: row indices where a gap in the time column (a step over ``GAP_PERIODS``
            ticks) starts a new stretch of the stream; empty without time.
        jitter_rows: rows whose time is not after the row before's, by at most ``JITTER_PERIODS``
            ticks (taken in file order).
        repeats: how often the kept rows repeat the kept row before within their interval (every row's step when
            ``independent``).
        noise_correlation: ``p``, how many times the variance of a mean over ``correlation_rows`` consecutive static
            rows exceeds what independent rows give (:func:`noise_correlation`: 1 for white noise; NaN where no
            interval holds two batches, a channel is constant, or ``independent``).
        correlation_dof: the degrees of freedom of ``noise_correlation``'s batch means (0 where NaN).
        correlation_rows: the batch length of ``noise_correlation`` (:func:`correlation_batch_rows`).
        serial_ratio: mean squared step between consecutive rows over twice the variance,
            averaged over channels (1: independent rows; near 0: a stream).
        independent: the rows are independent poses, not a stream: every row is kept.
        interval_times: ``k x 2`` seconds, the first and last row's time of each interval (None without time).
        preview_rows: ``m`` row indices of a thinned copy of the stream, for plots.
        preview_time: ``m`` seconds at those rows (None without time).
        preview_readings: ``m x c`` the first ``c <= 3`` channels at those rows (raw units).
    """

    mask: np.ndarray
    intervals: np.ndarray
    noise_floor: np.ndarray
    statistic: np.ndarray
    threshold: float
    window_rows: int
    min_rows: int
    period: float | None
    gap_rows: np.ndarray
    jitter_rows: int
    repeats: RowRepeats
    noise_correlation: np.ndarray
    correlation_dof: int
    correlation_rows: int
    serial_ratio: float
    independent: bool
    interval_times: np.ndarray | None
    preview_rows: np.ndarray
    preview_time: np.ndarray | None
    preview_readings: np.ndarray

    @property
    def count(self) -> int:
        """``k``, the number of intervals."""
        return len(self.intervals)

    @property
    def rows_kept(self) -> int:
        return int(self.mask.sum())

    @property
    def most_correlated_channel(self) -> int | None:
        """The channel whose :attr:`noise_correlation` is largest, or None where none was measured."""
        measured = np.where(np.isfinite(self.noise_correlation), self.noise_correlation, -np.inf)
        return int(np.argmax(measured)) if np.isfinite(measured).any() else None

    def correlation_words(self) -> str:
        """The batch of :attr:`noise_correlation` in words: ``51 rows (0.51 s)``, or ``25 rows`` without time."""
        seconds = "" if self.period is None else f" ({self.correlation_rows * self.period:.3g} s)"
        return f"{self.correlation_rows} rows{seconds}"

    def interval_of_rows(self) -> np.ndarray:
        """``f`` int64: each row's interval index, -1 outside every interval."""
        return intervals_of(np.arange(len(self.mask)), self.intervals)

    def still(self, rows: np.ndarray) -> np.ndarray:
        """Bool per row of ``rows``: below the threshold (held still, whether or not in an interval)."""
        return np.ones(len(rows), dtype=bool) if self.independent else self.statistic[rows] < self.threshold

    def still_run(self, row: int) -> tuple[int, int, int] | None:
        """The half-open run ``[first, stop)`` of still rows around ``row`` within its stretch between gaps, and the
        fewest rows such a run needs to be an interval (:func:`shortest_interval`); None if ``row`` is in motion."""
        if self.independent or not self.still(np.array([row]))[0]:
            return None
        starts = stretch_starts(self.gap_rows)
        k = int(np.searchsorted(starts, row, side="right")) - 1
        low, high = int(starts[k]), int(starts[k + 1]) if k + 1 < len(starts) else len(self.mask)
        moving = np.nonzero(self.statistic[low:high] >= self.threshold)[0] + low
        before, after = moving[moving < row], moving[moving > row]
        first, stop = int(before[-1]) + 1 if len(before) else low, int(after[0]) if len(after) else high
        fewest = int(shortest_interval(np.array(first == low and stop == high), self.min_rows, self.window_rows))
        return first, stop, fewest

    def near_interval(self, rows: np.ndarray) -> np.ndarray:
        """Bool per row of ``rows``: within one window of an interval (the detector's resolution at its ends)."""
        if not self.count:
            return np.zeros(len(rows), dtype=bool)
        slack = self.window_rows
        previous = np.searchsorted(self.intervals[:, 0], rows, side="right") - 1
        following = previous + 1
        close_previous = (previous >= 0) & (rows < self.intervals[np.maximum(previous, 0), 1] + slack)
        close_following = (following < self.count) & (rows >= self.intervals[np.minimum(following, self.count - 1), 0] - slack)
        return close_previous | close_following


def data_row(row: int) -> str:
    """A row's place where the file is unknown: ``data row 17 (0-based)``."""
    return f"data row {row} (0-based)"


def find_static_intervals(
    readings: Rows,
    time: Rows | None = None,
    window: float | None = None,
    min_duration: float | None = None,
    threshold: float = DEFAULT_THRESHOLD,
    noise_quantile: float = DEFAULT_NOISE_QUANTILE,
    chunk_rows: int = CHUNK_ROWS,
    where: Callable[[int], str] = data_row,
    trim_ends: bool = False,
) -> StaticIntervals:
    """Find the static intervals of a recording (module docstring).

    Args:
        readings: ``f x p`` raw readings in row (time) order.
        time: ``f`` seconds in row order (jitter and gaps allowed: module docstring); None: rows
            are evenly spaced and durations are in rows.
        window: the centred moving window, seconds (rows without ``time``); None: 0.5 s or 25 rows.
        min_duration: the shortest static interval kept, seconds (rows without ``time``); None: two windows.
        threshold: windowed variance over the noise variance (averaged over channels) below which a
            row is static; pure noise gives about 1.
        noise_quantile: each channel's noise floor is this quantile of its windowed standard
            deviation (corrected to the noise's for Gaussian noise): at least this fraction of
            the rows must be static.
        chunk_rows: rows read at a time.
        where: a row's place in the file for messages, e.g. ``line 17 of session.csv``.
        trim_ends: cut each interval's drifted ends (:func:`trim_drifting_ends`). Off by default: it also cuts the
            start of a hold that rings after a move, the very rows that show the ringing to the goodness of fit,
            while the ringing left in the hold still biases its mean (a hostile tester's: 4.2x its bars, trusted).

    Returns:
        :class:`StaticIntervals`.

    Raises:
        SfmnetError: ``time`` is not finite, steps back by more than ``JITTER_PERIODS`` ticks or
            does not increase or has gaps at over ``MAX_GAP_FRACTION`` of its steps, the window spans under two
            rows or over a quarter of them, or a reading is not finite.
    """
    f, p = readings.shape
    if not (window is None or window > 0) or not (min_duration is None or min_duration > 0):
        raise ValueError("window and min_duration must be positive")
    if not 0 < noise_quantile < 1 or not threshold > 0:
        raise ValueError("noise_quantile must lie in (0, 1) and threshold be positive")
    scan = serial_scan(readings, time, chunk_rows, where)
    period = scan.period
    window = DEFAULT_WINDOW[time is not None] if window is None else window
    # Halves round up, so a window of exactly 12.5 half-rows is 13 however the period's sum rounded.
    half = max(1, math.floor(window / (period or 1.0) / 2 + 0.5 + 1e-9))
    window_rows = 2 * half + 1
    min_rows = max(1, math.ceil(min_duration / (period or 1.0))) if min_duration is not None else 2 * window_rows
    common = dict(
        threshold=threshold, window_rows=window_rows, min_rows=min_rows, period=period, serial_ratio=scan.ratio,
        gap_rows=scan.gap_rows, jitter_rows=scan.jitter_rows,
        preview_rows=scan.preview_rows, preview_time=scan.preview_time, preview_readings=scan.preview_readings,
    )
    if scan.ratio >= INDEPENDENT_RATIO:
        rows = np.arange(f)
        return StaticIntervals(
            mask=np.ones(f, dtype=bool), intervals=np.stack([rows, rows + 1], axis=1), noise_floor=np.full(p, np.nan),
            statistic=np.zeros(f, dtype=np.float32), independent=True, repeats=row_repeats(readings, None, chunk_rows),
            noise_correlation=np.full(p, np.nan), correlation_dof=0, correlation_rows=0,
            interval_times=None if time is None else np.stack([scan.time_at(rows), scan.time_at(rows)], axis=1),
            **common,
        )
    starts = stretch_starts(scan.gap_rows)
    if period is not None and window < 2 * period:
        raise SfmnetError(
            f"the static-interval window of {window:g} s spans under two rows of this recording ({period:.3g} s a row): "
            f"check data.time_unit (a time column in ms read as s?), or set data.static.window to {2 * period:.3g} s or more"
        )
    if period is not None and len(scan.gap_rows) > MAX_GAP_FRACTION * f:
        raise SfmnetError(
            f"{len(scan.gap_rows):,} of the time column's {f - 1:,} steps are gaps (over {GAP_PERIODS:g} ticks of "
            f"{scan.tick:.3g} s): its rate changes within the file or its stamps are not the rows' times; split the file "
            "where the rate changes, or find the intervals in row order (data.static_intervals=true, data.time_column=null "
            "and data.channel_columns naming the channels); a logger that writes a burst of rows at each held pose (a gap "
            "at each move) has no motion to find: fit every row with data.static_intervals=false, and give each row's pose "
            "as data.group_column if the file has one"
        )
    if period is not None and 4 * window_rows > f:
        raise SfmnetError(
            f"the static-interval window of {window:g} s spans {window_rows:,} rows, over a quarter of the recording's "
            f"{f:,} ({period:.3g} s a row): check data.time_unit (a time column in s read as ms, or a spreadsheet's "
            "serial dates, which need data.time_unit=d?), or set data.static.window shorter than a hold"
        )
    floor = noise_floor(readings, half, noise_quantile, scan.step, chunk_rows, starts)
    statistic = np.empty(f, dtype=np.float32)
    used = floor > 0
    for first, variance, _, _ in moving_variances(readings, half, chunk_rows, starts):
        statistic[first : first + len(variance)] = (variance[:, used] / floor[used] ** 2).mean(axis=1)
    intervals = static_runs(statistic < threshold, min_rows, starts, window_rows)
    if trim_ends:
        intervals = trim_drifting_ends(readings, intervals, floor, half)
    mask = np.zeros(f, dtype=bool)
    for first, stop in intervals:
        mask[first:stop] = True
    batch_rows = correlation_batch_rows(intervals, window_rows)
    correlation, correlation_dof = noise_correlation(readings, intervals, batch_rows, chunk_rows)
    times = None
    if time is not None:
        times = np.stack([scan.time_at(intervals[:, 0]), scan.time_at(intervals[:, 1] - 1)], axis=1)
    return StaticIntervals(
        mask=mask, intervals=intervals, noise_floor=floor, statistic=statistic, independent=False,
        repeats=row_repeats(readings, intervals, chunk_rows),
        noise_correlation=correlation, correlation_dof=correlation_dof, correlation_rows=batch_rows,
        interval_times=times, **common,
    )


@dataclass(frozen=True)
class SerialScan:
    """One pass's summary: the serial ratio, the time step, gaps and jitter, each channel's smallest step, a preview."""

    ratio: float
    period: float | None
    tick: float | None
    gap_rows: np.ndarray
    jitter_rows: int
    step: np.ndarray
    preview_rows: np.ndarray
    preview_time: np.ndarray | None
    preview_readings: np.ndarray
    time: Rows | None

    def time_at(self, rows: np.ndarray, chunk_rows: int = CHUNK_ROWS) -> np.ndarray:
        """Seconds at ``rows`` (int), reading only the chunks that hold them."""
        return read_rows(self.time, rows, chunk_rows)


def serial_scan(readings: Rows, time: Rows | None, chunk_rows: int, where: Callable[[int], str]) -> SerialScan:
    """The serial ratio (consecutive steps, rows repeated whole left out, against the spread), the period (the mean
    time step apart from gaps), the gaps and jittered stamps (judged against the first chunk's tick), the smallest
    nonzero step of each channel (its quantisation) and a thinned preview, in one pass."""
    f, p = readings.shape
    shift = np.asarray(readings[0:1], dtype=np.float64)[0]
    total, squares, steps = np.zeros(p), np.zeros(p), np.zeros(p)
    repeated = 0  # steps of zero on every channel
    smallest = np.full(p, np.inf)
    tick, gaps, jitter, previous, previous_time = None, [], 0, None, None
    step_sum, step_count = 0.0, 0  # of the steps apart from gaps: the period, a coarse clock's repeats included
    thin = max(1, math.ceil(f / PREVIEW_ROWS))
    preview_rows = np.arange(0, f, thin)
    preview, preview_time = [], []
    for first in range(0, f, chunk_rows):
        block = np.asarray(readings[first : first + chunk_rows], dtype=np.float64) - shift
        bad = ~np.isfinite(block).all(axis=1)
        if bad.any():
            raise SfmnetError(f"{where(first + int(np.argmax(bad)))} has a NaN or infinite reading: repair or drop that row")
        joined = block if previous is None else np.concatenate([previous, block])
        difference = np.abs(np.diff(joined, axis=0))
        steps += (difference**2).sum(axis=0)
        repeated += int((difference == 0).all(axis=1).sum())
        nonzero = np.where(difference > 0, difference, np.inf)
        smallest = np.minimum(smallest, nonzero.min(axis=0, initial=np.inf))
        total += block.sum(axis=0)
        squares += (block**2).sum(axis=0)
        local = preview_rows[(preview_rows >= first) & (preview_rows < first + len(block))] - first
        preview.append(block[local, :PREVIEW_CHANNELS] + shift[:PREVIEW_CHANNELS])
        if time is not None:
            stamps = np.asarray(time[first : first + chunk_rows], dtype=np.float64)
            joined_time = stamps if previous_time is None else np.concatenate([previous_time, stamps])
            increments = np.diff(joined_time)
            base = first - (previous_time is not None)  # the row of joined_time[0]
            bad = ~np.isfinite(joined_time)
            if bad.any():
                raise SfmnetError(
                    f"the time on {where(base + int(np.argmax(bad)))} is empty or not a number: rows must be in time order; "
                    "repair or drop that row (or fit without static intervals: data.static_intervals=false)"
                )
            if tick is None and len(increments):
                tick = time_tick(joined_time)
            if len(increments):
                back = increments < -JITTER_PERIODS * tick
                if back.any():
                    i = int(np.argmax(back))
                    many = int(back.sum())
                    if many > max(MANY_BACK_STEPS_AT_LEAST, MANY_BACK_STEPS * len(increments)):
                        raise SfmnetError(
                            f"{many} of {len(increments):,} steps of the time column (from {where(base)}) go back by more "
                            f"than {JITTER_PERIODS:g} ticks (of {tick:.3g} s, read from these stamps), the first on "
                            f"{where(base + i + 1)}: the stamps jitter by more than the rows' spacing (taken on a host as "
                            "packets arrive?); sort the rows by time, which moves a reading by a row or two, or fit "
                            "without static intervals (data.static_intervals=false)"
                        )
                    jumped = i > 0 and increments[i - 1] > GAP_PERIODS * tick
                    if jumped and joined_time[i - 1] <= joined_time[i + 1] + JITTER_PERIODS * tick:
                        # The row before jumped ahead of both its neighbours: a spike, not a step back.
                        raise SfmnetError(
                            f"the time on {where(base + i)} is {joined_time[i] - joined_time[i + 1]:.3g} s after the next "
                            "row's and the row before's: a corrupt stamp; repair or drop that row (or fit without static "
                            "intervals: data.static_intervals=false)"
                        )
                    row = base + i + 1
                    if -increments[i] > GAP_PERIODS * tick:
                        raise SfmnetError(
                            f"the time on {where(row)} is {-increments[i]:.3g} s before the row before's: the clock "
                            "restarted there, or two logs were joined, or the rows were written out of order; split the "
                            "file where the clock restarts and calibrate each part, or sort the rows by time"
                        )
                    raise SfmnetError(
                        f"the time on {where(row)} is {-increments[i]:.3g} s before the row before's, "
                        f"more than {JITTER_PERIODS:g} ticks of {tick:.3g} s (jitter): rows must be in time order; repair "
                        "or drop that row (or fit without static intervals: data.static_intervals=false)"
                    )
                jitter += int((increments <= 0).sum())
                gap = increments > GAP_PERIODS * tick
                gaps.append(base + 1 + np.nonzero(gap)[0])
                step_sum += float(increments[~gap].sum())
                step_count += int((~gap).sum())
            preview_time.append(stamps[local])
            previous_time = stamps[-1:]
        previous = block[-1:]
    if time is not None and tick is not None:
        span = float(np.asarray(time[f - 1 : f], dtype=np.float64)[0] - np.asarray(time[0:1], dtype=np.float64)[0])
        if tick > MAX_TICK_PER_SPAN * span:
            raise SfmnetError(
                f"the time column steps by {tick:.3g} s, {tick / span:.0%} of the {span:.3g} s it spans over {f:,} rows: "
                f"too coarse to time the rows {COARSE_CLOCK_ADVICE}"
            )
    variance = squares / f - (total / f) ** 2
    spread = variance > 0
    # A row repeated whole is the logger polling faster than the sensor updates, not a step of the stream: counted,
    # independent poses logged five times each would read as a stream five times slower.
    moves = max(f - 1 - repeated, 1)
    ratio = float(np.mean(steps[spread] / moves / (2 * variance[spread]))) if spread.any() else 0.0
    period = None if time is None else (step_sum / step_count if step_count else 1.0)
    if period is not None and not period > 0:
        raise not_increasing(period, "mean step apart from gaps")
    return SerialScan(
        ratio=ratio,
        period=period,
        tick=tick,
        gap_rows=np.concatenate(gaps).astype(np.int64) if gaps else np.zeros(0, dtype=np.int64),
        jitter_rows=jitter,
        step=np.where(np.isfinite(smallest), smallest, 0.0),
        preview_rows=preview_rows,
        preview_time=np.concatenate(preview_time) if time is not None else None,
        preview_readings=np.concatenate(preview),
        time=time,
    )


def time_tick(stamps: np.ndarray) -> float:
    """The clock's tick, seconds: the median positive step of ``stamps`` (the first chunk's times).

    Raises:
        SfmnetError: no step increases the time.
    """
    increments = np.diff(stamps)
    positive = increments[increments > 0]
    if not len(positive):
        if (increments == 0).all():
            raise SfmnetError(
                f"the time column holds one value, {stamps[0]:.3g}, on its first {len(stamps):,} rows: it does not time them "
                f"{COARSE_CLOCK_ADVICE}"
            )
        raise not_increasing(float(np.median(increments)), "median step")
    return float(np.median(positive))


def not_increasing(step: float, what: str) -> SfmnetError:
    return SfmnetError(
        f"the time column does not increase (its {what} is {step:g} s): rows must be in time order; "
        "sort the file by time, or fit without static intervals: data.static_intervals=false"
    )


def moving_variances(
    readings: Rows, half: int, chunk_rows: int, starts: np.ndarray
) -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """``(first row, b x p variances, b x p means, b counts)`` blocks: each row's variance and mean over rows
    ``[i - half, i + half]``, cut at the ends of its stretch (``starts``: sorted first rows of the stretches between
    gaps, from 0).

    Each chunk is read with ``half`` rows either side and shifted by its first row, so the
    cumulative sums stay small, and the same rows give the same numbers however they are read.
    """
    f = readings.shape[0]
    for first in range(0, f, chunk_rows):
        stop = min(f, first + chunk_rows)
        start, end = max(0, first - half), min(f, stop + half)
        block = np.asarray(readings[start:end], dtype=np.float64)
        shift = block[0].copy()
        block = block - shift
        sums = np.concatenate([np.zeros((1, block.shape[1])), np.cumsum(block, axis=0)])
        squares = np.concatenate([np.zeros((1, block.shape[1])), np.cumsum(block**2, axis=0)])
        rows = np.arange(first, stop)
        stretch = np.searchsorted(starts, rows, side="right") - 1
        stretch_stop = np.append(starts, f)[stretch + 1]
        low = np.maximum(rows - half, starts[stretch]) - start
        high = np.minimum(rows + half + 1, stretch_stop) - start
        count = (high - low)[:, None]
        mean = (sums[high] - sums[low]) / count
        yield first, np.maximum((squares[high] - squares[low]) / count - mean**2, 0.0), mean + shift, count[:, 0]


def noise_floor(readings: Rows, half: int, quantile: float, step: np.ndarray, chunk_rows: int, starts: np.ndarray) -> np.ndarray:
    """``p``: each channel's noise standard deviation, from the ``quantile`` of its windowed standard deviations.

    A window of ``L = 2 half + 1`` rows of Gaussian noise has ``L v / sigma^2 ~ chi2(L - 1)``, so
    the quantile of ``v`` is divided by the chi-square quantile over ``L``; the floor is at
    least the channel's quantisation (its smallest step over sqrt(12)). A channel flat in more than
    ``quantile`` of the windows at one or two levels (clipped, stuck: :data:`FLAT_LEVELS_SHARE`) takes the quantile of
    the windows where it moves; flat at many levels, it is held poses with noise below its step, and its floor is the
    quantisation's. Windows cut short by a gap or an end have fewer degrees of freedom, so a lower quantile: they are
    left out when ``FULL_WINDOWS`` whole ones are sampled.
    """
    f = readings.shape[0]
    stride = max(1, math.ceil(f / NOISE_SAMPLES))
    sampled, levels, counts = [], [], []
    for first, variance, mean, count in moving_variances(readings, half, chunk_rows, starts):
        sampled.append(variance[(-first) % stride :: stride])
        levels.append(mean[(-first) % stride :: stride])
        counts.append(count[(-first) % stride :: stride])
    sampled, levels, counts = np.concatenate(sampled), np.concatenate(levels), np.concatenate(counts)
    whole = counts == 2 * half + 1
    if whole.sum() >= FULL_WINDOWS:
        sampled, levels = sampled[whole], levels[whole]
    dof = 2 * half
    z = NormalDist().inv_cdf(quantile)
    chi2_quantile = dof * max(1 - 2 / (9 * dof) + z * math.sqrt(2 / (9 * dof)), 0.05) ** 3  # Wilson-Hilferty
    # A flat window's variance is 0 to the rounding of the running sums (1e-14 in volts), not exactly 0. Rounding on the
    # scale of the levels' spread, taken between the 2nd and 98th percentiles: a corrupt cell 5000 times the channel's
    # range had made every window of it "flat" and its floor the rounding (a hostile tester's: no interval found).
    spread = np.subtract(*np.quantile(levels, [0.98, 0.02], axis=0))
    spread = np.where(spread > 0, spread, np.ptp(levels, axis=0))
    flat_windows = sampled <= FLAT_VARIANCE * spread**2
    low = np.quantile(np.where(flat_windows, 0.0, sampled), quantile, axis=0)
    # A channel flat for over ``quantile`` of the windows at one or two levels (clipped at its range, stuck, dropped out)
    # has no noise there: its floor is the quantile of the windows where it moves, or every other row of it would read
    # as motion. Flat at many levels, it is poses held with noise under one count, and the windows where it moves are
    # the motion: there the quantisation is the floor.
    for channel in np.nonzero(low == 0)[0]:
        flat = flat_windows[:, channel]
        # float32: a flat window's mean is its level to rounding, which differs by where the chunk was shifted.
        _, repeats = np.unique(levels[flat, channel].astype(np.float32), return_counts=True)
        if np.sort(repeats)[-2:].sum() >= FLAT_LEVELS_SHARE * flat.sum():
            moving = sampled[~flat, channel]
            low[channel] = np.quantile(moving, quantile) if len(moving) else 0.0
    floor = np.sqrt(low * (dof + 1) / chi2_quantile)
    return np.maximum(floor, step / math.sqrt(12))


def stretch_starts(gap_rows: np.ndarray) -> np.ndarray:
    """The first row of each stretch of the stream between gaps: 0, then ``gap_rows`` (int64)."""
    return np.concatenate([[0], gap_rows]).astype(np.int64)


def correlation_batch_rows(intervals: np.ndarray, window_rows: int) -> int:
    """The batch length :func:`noise_correlation` is measured over: the detector's window, or half the median interval
    where that is shorter (a minimum duration under two windows), so that most intervals hold two batches; at least 2."""
    if not len(intervals):
        return max(2, window_rows)
    median = int(np.median(intervals[:, 1] - intervals[:, 0]))
    return max(2, min(window_rows, median // 2))


def noise_correlation(readings: Rows, intervals: np.ndarray, batch_rows: int, chunk_rows: int) -> tuple[np.ndarray, int]:
    """Per channel, ``b var(batch means) / var(rows)`` within the intervals: how many times the variance of a mean over
    ``b = batch_rows`` consecutive rows exceeds ``var / b``, what independent rows give (batch means, as in Markov chain
    error analysis). 1 for white noise; ``(1 + r) / (1 - r)`` less ``O(1 / b)`` for AR(1) noise of lag-one correlation
    ``r``; it grows with ``b`` for drift within a hold. Each interval's full batches are taken about that interval's
    own mean (its pose), the deviations pooled over intervals with their degrees of freedom.

    Args:
        readings: ``f x p`` in row order; intervals: ``k x 2`` half-open; batch_rows: ``b`` (at least 2).

    Returns:
        ``p`` ratios (NaN for a constant channel, or where no interval holds two batches) and the batch means'
        degrees of freedom (each interval's batches less one), summed over the intervals.
    """
    p = readings.shape[1]
    step = max(batch_rows, chunk_rows // batch_rows * batch_rows)
    row_squares, batch_squares = np.zeros(p), np.zeros(p)
    row_dof = batch_dof = 0
    for first, stop in intervals.tolist():
        batches = (stop - first) // batch_rows
        if batches < 2:
            continue
        end = first + batches * batch_rows
        # About the interval's first row: sums of squares of raw counts would lose the noise to rounding.
        origin = np.asarray(readings[first : first + 1], dtype=np.float64)[0]
        sums, squares, mean_squares = np.zeros(p), np.zeros(p), np.zeros(p)
        for start in range(first, end, step):
            block = np.asarray(readings[start : min(end, start + step)], dtype=np.float64) - origin
            sums += block.sum(axis=0)
            squares += (block**2).sum(axis=0)
            mean_squares += (block.reshape(-1, batch_rows, p).mean(axis=1) ** 2).sum(axis=0)
        rows = batches * batch_rows
        mean = sums / rows
        row_squares += squares - rows * mean**2
        batch_squares += mean_squares - batches * mean**2
        row_dof += rows - 1
        batch_dof += batches - 1
    if batch_dof == 0:
        return np.full(p, np.nan), 0
    row_variance = row_squares / row_dof
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(row_variance > 0, batch_rows * (batch_squares / batch_dof) / row_variance, np.nan)
    return ratio, batch_dof


def trim_drifting_ends(readings: Rows, intervals: np.ndarray, floor: np.ndarray, half: int) -> np.ndarray:
    """``intervals`` (``k x 2`` half-open) less the rows at either end that have drifted from the interval's middle.

    A move that starts or ends slowly (a minimum-jerk move's acceleration grows from zero) shifts the readings' mean
    before their windowed variance notices: at an SNR of 100 a simulated stream's intervals ran up to 62 rows into
    its moves, and the goodness of fit disowned the bars. Each row near an end is scored by its squared deviation from
    the middle's mean, over the noise floor and averaged over channels, smoothed over ``half / 2`` rows; ends are cut
    while that score exceeds :data:`DRIFT_RATIO` times the middle rows' own (which carries any slow noise, tremor, of
    the hold itself), by at most a quarter of the interval and one window at each end. An interval longer than
    :data:`DRIFT_MIDDLE_ROWS` is judged against its central rows alone, so memory stays bounded in a streamed session.

    Args:
        readings: ``f x p``; floor: ``p`` noise floors (0: a channel left out); half: the window's half-width, rows.
    """
    used = floor > 0
    if not used.any():
        return intervals
    smooth = max(1, half // 2)
    trimmed = []
    for first, stop in intervals.tolist():
        length = stop - first
        reach = min(2 * half, length // 4)
        if reach < smooth or length < 4 * smooth:
            trimmed.append((first, stop))
            continue
        if length <= DRIFT_MIDDLE_ROWS + 2 * reach:
            parts = [(first, stop)]
        else:
            centre = (first + stop) // 2
            ends = reach + smooth
            parts = [(first, first + ends), (centre - DRIFT_MIDDLE_ROWS // 2, centre + DRIFT_MIDDLE_ROWS // 2), (stop - ends, stop)]
        blocks = [np.asarray(readings[a:b], dtype=np.float64)[:, used] / floor[used] for a, b in parts]
        whole = blocks[0] if len(blocks) == 1 else None
        middle = whole[reach : length - reach] if whole is not None else blocks[1]
        mean = middle.mean(axis=0)
        smoothed = [moving_mean(((block - mean) ** 2).mean(axis=1), smooth) for block in blocks]
        level = DRIFT_RATIO * float(np.median(smoothed[0][reach : length - reach] if whole is not None else smoothed[1]))
        head_scores, tail_scores = smoothed[0], smoothed[-1]
        head = next((r for r in range(reach) if head_scores[r] <= level), reach)
        tail = next((r for r in range(reach) if tail_scores[len(tail_scores) - 1 - r] <= level), reach)
        trimmed.append((first + head, stop - tail))
    return np.array(trimmed, dtype=np.int64).reshape(-1, 2)


def moving_mean(values: np.ndarray, width: int) -> np.ndarray:
    """Centred moving mean over ``width`` rows, of the rows there are at the ends (zeros beyond them would hide a
    drifted end)."""
    kernel = np.ones(width)
    return np.convolve(values, kernel, mode="same") / np.convolve(np.ones(len(values)), kernel, mode="same")


def static_runs(quiet: np.ndarray, min_rows: int, starts: np.ndarray, window_rows: int) -> np.ndarray:
    """``k x 2`` half-open ``[first, stop)`` runs of True in ``quiet`` (``f`` bool), none across a stretch's
    start (``starts``: sorted, from 0), as long as :func:`shortest_interval` asks (``min_rows``, or at most one
    window where the run fills its stretch, from a gap or the first row to the next gap or the last row)."""
    f = len(quiet)
    begins = np.zeros(f, dtype=bool)
    begins[starts[starts < f]] = True
    previous = np.concatenate([[False], quiet[:-1]])
    first = np.nonzero(quiet & (~previous | begins))[0]
    following = np.concatenate([quiet[1:], [False]]) & ~np.concatenate([begins[1:], [True]])
    stop = np.nonzero(quiet & ~following)[0] + 1
    runs = np.stack([first, stop], axis=1).astype(np.int64)
    whole = begins[runs[:, 0]] & np.append(begins, True)[runs[:, 1]]
    return runs[runs[:, 1] - runs[:, 0] >= shortest_interval(whole, min_rows, window_rows)].reshape(-1, 2)


def shortest_interval(whole: np.ndarray, min_rows: int, window_rows: int) -> np.ndarray:
    """The fewest rows a run of still rows needs to be an interval: ``min_rows``, or no more than one window where
    the run fills its stretch between gaps (``whole``, bool array)."""
    return np.where(whole, min(window_rows, min_rows), min_rows)
