"""Times as loggers write them, read as seconds: ISO 8601 dates and times (``2026-12-07T13:52:41.250``, with a
space for the ``T``, ``Z`` or an offset from UTC) and clock times alone (``13:52:41.250``, or ``1:52:41.250 PM``)."""

from __future__ import annotations

import datetime
import re
from collections.abc import Callable, Iterable

import numpy as np

from sfmnet.errors import SfmnetError

CLOCK_TIME = re.compile(
    r"(?:(?P<date>\d{4}-\d{2}-\d{2})(?:[T ]|$))?"
    r"(?:(?P<hours>\d{1,2}):(?P<minutes>\d{2})(?::(?P<seconds>\d{2}(?:[.,]\d+)?))?)?"
    r"(?:\s*(?P<half>[AaPp][Mm]))?"
    r"\s*(?P<zone>Z|[+-]\d{2}(?::?\d{2})?)?"
)
DAY = 86_400.0
EPOCH = datetime.date(1970, 1, 1)


def clock_seconds(cell: str) -> tuple[int, float, bool] | None:
    """``cell``'s time as a day (since 1970-01-01; 0 without a date) and seconds into it (UTC where the cell gives an
    offset, so possibly outside ``[0, 86400)``; else in the cell's own zone), and whether it gives a date; None where it
    is not a date or clock time. Apart, not summed: Unix time in one float64 keeps only 0.2 microseconds."""
    match = CLOCK_TIME.fullmatch(cell.strip())
    if match is None or not (match["date"] or match["hours"]):
        return None
    try:
        day = (datetime.date.fromisoformat(match["date"]) - EPOCH).days if match["date"] else 0
    except ValueError:  # 2026-13-40
        return None
    seconds = float((match["seconds"] or "0").replace(",", "."))
    hours = int(match["hours"] or 0)
    if match["half"]:
        # A 12-hour clock: 12:30 AM is 00:30, 12:30 PM is 12:30, 1:30 PM is 13:30.
        if not match["hours"] or not 1 <= hours <= 12:
            return None
        hours = hours % 12 + (12 if match["half"].lower() == "pm" else 0)
    clock = hours * 3600 + int(match["minutes"] or 0) * 60 + seconds
    zone = match["zone"] or "Z"
    # +01, +0130 or +01:30 (hours, then minutes where given).
    offset = 0 if zone == "Z" else (1 if zone[0] == "+" else -1) * (int(zone[1:3]) * 3600 + int(zone[3:].lstrip(":") or 0) * 60)
    return day, clock - offset, bool(match["date"])


def clock_time_hint(cells: Iterable[str]) -> str:
    """What to do when refused ``cells`` are dates or clock times (a number is needed there)."""
    if any(clock_seconds(cell) is not None for cell in cells):
        return " (dates or clock times: a time column may hold them, named by data.time_column; elsewhere give numbers)"
    return ""


def all_clock_times(cells: Iterable[str]) -> bool:
    """Whether every cell is a date or a clock time (a time column)."""
    return all(clock_seconds(cell) is not None for cell in cells)


class ClockTimes:
    """A column's dates or clock times read one by one in row order, as seconds from the first one read
    (:func:`clock_seconds`). Clock times without a date are put on the day nearest the row before's: one that steps
    back by over half a day has passed midnight, and a day is added from there on."""

    def __init__(self) -> None:
        self.first: tuple[int, float] | None = None
        self.previous: float | None = None
        self.days = 0

    def __call__(self, cell: str) -> tuple[float, bool] | None:
        """Seconds from the first time read, and whether ``cell`` gives a date; None where it is no time."""
        read = clock_seconds(cell)
        if read is None:
            return None
        day, seconds, dated = read
        self.first = self.first or (day, seconds)
        elapsed = (day - self.first[0] + self.days) * DAY + (seconds - self.first[1])
        if not dated and self.previous is not None:
            # The day that puts it nearest the row before: a step back of half a day has passed midnight, and a step
            # forward of half a day after that is a row logged just before midnight, out of order.
            shift = round((self.previous - elapsed) / DAY)
            self.days += shift
            elapsed += shift * DAY
        self.previous = elapsed
        return elapsed, dated


def clock_time_column(cells: list[str], where: Callable[[int], str]) -> np.ndarray | None:
    """``f`` seconds from the first row of a column of dates or clock times (:class:`ClockTimes`; ``where`` names a row
    for messages); None where at most half the cells are (a column of numbers with a stray cell, or of other text)."""
    clock = ClockTimes()
    read = [clock(cell) for cell in cells]
    if sum(value is not None for value in read) <= len(read) / 2:
        return None
    for row, (cell, value) in enumerate(zip(cells, read)):
        if value is None:
            raise SfmnetError(
                f"{where(row)} has time '{cell}' among dates or clock times: give every row a time as "
                "2026-12-07T13:52:41.250 or 13:52:41.250, or numbers of seconds"
            )
    if len({dated for _, dated in read}) > 1:
        raise SfmnetError(
            f"the time column gives dates on some rows and clock times alone on others (first row: '{cells[0]}'): "
            "give every row the same form"
        )
    return np.array([value for value, _ in read])
