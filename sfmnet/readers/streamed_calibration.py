"""A calibration session too long for memory: one mass turned through unknown orientations, streamed from a file."""

from __future__ import annotations


import numpy as np
import torch

from sfmnet.readers.csv_calibration import (
    calibration_magnitude, channel_scale_warnings, hint_row_warnings, load_axes, mirror_hint_fields,
    monotonic_channel_warnings, six_axes_need_configurations,
)
from sfmnet.data.recording import CalibrationData, load_unit_for
from sfmnet.readers.clock_times import clock_seconds
from sfmnet.readers.delimited import open_delimited
from sfmnet.readers.row_file import RowFileDataModule, column_index
from sfmnet.readers.table_file import DATES_WITH_A_UNIT
from sfmnet.data.rows import SHIFT_ROWS, MappedColumns, StreamedRecording, mapped_rows
from sfmnet.readers.static_rows import fitted_rows, static_settings
from sfmnet.errors import SfmnetError
from sfmnet.linalg.frame import MirrorHint
from sfmnet.linalg.wrench import STANDARD_GRAVITY
from sfmnet.preprocessing.static_intervals import CHUNK_ROWS, StaticIntervals
from sfmnet.preprocessing.stuck_channels import stuck_readings


class StreamedCalibrationDataModule(RowFileDataModule):
    """The calibration file of :class:`~sfmnet.readers.csv_calibration.CsvCalibrationDataModule`, streamed in blocks.

    Same columns and meaning (load columns empty or NaN except on the few known-load rows), but
    the rows are read block by block through a memory map (a CSV converted once to ``.npy``),
    so the session may be longer than memory and shared between processes. One mass only
    (2-, 3- or n-axis force sensors); six-axis sessions with several mass configurations
    are fitted in memory (``experiment=calibrate_csv``).

    Args:
        path: ``.npy`` or ``.csv`` (header row).
        load_columns: the ``n`` load columns; empty when no load is known (then name the ``axes``).
        axes: the ``n`` load axis names when ``load_columns`` is empty.
        magnitude: the load magnitude (load units); or give ``mass`` (kg).
        channel_columns: raw channels (default: every column but the loads and ``time_column``).
        time_column: the rows' time (not a channel); with it the static intervals are found.
        columns: names of a ``.npy``'s columns.
        mirror_hint: ``{row: <data row, 0-based>, axis: <load column>, sign: <+1|-1>}``, with ``n - 1`` known loads.
        known_load_tolerance: see :class:`StreamedRecording`.
        load_unit: for reports; None: ``N``, or ``N, N m`` for six axes (force, then torque).
        gravity: m/s^2, for ``mass``.
        block_rows, cache_dir: see :class:`RowFileDataModule`.
        static_intervals, time_unit, static: see :class:`~sfmnet.readers.csv_calibration.CsvCalibrationDataModule`;
            detected in chunks through the memory map (memory: a byte per row for the mask).
    """

    task = "calibration"

    def __init__(
        self,
        path: str,
        load_columns: list[str],
        axes: list[str] | None = None,
        magnitude: float | None = None,
        mass: float | None = None,
        channel_columns: list[str] | None = None,
        time_column: str | None = None,
        columns: list[str] | None = None,
        mirror_hint: dict | None = None,
        known_load_tolerance: float = 0.02,
        load_unit: str | None = None,
        gravity: float = STANDARD_GRAVITY,
        block_rows: int | None = None,
        cache_dir: str | None = None,
        static_intervals: bool | None = None,
        time_unit: str = "s",
        static: dict | None = None,
    ) -> None:
        super().__init__(path, columns=columns, channel_columns=channel_columns, block_rows=block_rows, cache_dir=cache_dir)
        self.load_columns = list(load_columns)
        self.axes = load_axes(self.load_columns, axes)
        if len(self.axes) == 6:
            raise six_axes_need_configurations(streamed=True)
        self.magnitude = magnitude
        self.mass = mass
        self.time_column = time_column
        self.mirror_hint = mirror_hint
        self.known_load_tolerance = known_load_tolerance
        self.load_unit = load_unit_for(load_unit, len(self.axes))
        self.gravity = gravity
        self.static = static_settings(static_intervals, time_column, time_unit, static)

    def csv_columns(self) -> list[str] | None:
        """With the channels listed: they, the loads and the time column (other columns may hold text)."""
        if not self.channel_columns:
            return None
        wanted = [*self.channel_columns, *self.load_columns, *([self.time_column] if self.time_column else [])]
        return list(dict.fromkeys(wanted))

    def time_columns(self) -> tuple[str, ...]:
        return (self.time_column,) if self.time_column else ()

    def build(self) -> CalibrationData:
        magnitude = calibration_magnitude(self.magnitude, self.mass, self.gravity)
        layout, names = self.open_rows()
        load_index = column_index(names, self.load_columns, "load", self.path)
        if self.time_column:
            column_index(names, [self.time_column], "time", self.path)
        channels = self.channel_columns or [n for n in names if n not in self.load_columns and n != self.time_column]
        if len(channels) < len(self.axes):
            raise SfmnetError(
                f"{len(channels)} channel columns for {len(self.axes)} load axes: a calibration needs at "
                "least as many channels as axes; list them with data.channel_columns=[...]"
            )
        recording = self.row_data(
            layout, names, channels, StreamedRecording,
            load_columns=self.load_columns, load_index=load_index, magnitude=magnitude, axes=self.axes,
            known_load_tolerance=self.known_load_tolerance,
        )
        if self.time_column and self.static is not None and self.static.time_scale != 1.0:
            self.refuse_dates_with_a_unit()
        recording.refuse_bad_rows()
        recording.refuse_far_cells()
        detection = self.find_static_rows(recording, names) if self.static is not None else None
        if self.mirror_hint is not None:
            self.read_mirror_hint(recording)
        first = min(recording.rows, SHIFT_ROWS)
        sample = np.asarray(mapped_rows(layout, 0, first)[:, recording.channel_index])
        return CalibrationData(
            recordings={recording.recording: recording}, channels=channels, axes=self.axes, load_unit=self.load_unit,
            static_intervals=detection,
            row_repeats=None if detection is None else detection.repeats,
            stuck_readings=[
                stuck for stuck in stuck_readings(MappedColumns(layout, recording.channel_index), recording.rank)
                if recording.keep is None or recording.keep[stuck.first : stuck.stop].any()
            ],
            warnings=[
                *monotonic_channel_warnings(
                    sample, channels, "the file's rows" if first == recording.rows else f"the first {first} rows"
                ),
                *channel_scale_warnings(sample, channels),
                *self.hint_line_warnings(),
            ],
        )

    @property
    def rows(self) -> int:
        """The file's rows, after :meth:`setup`."""
        assert self.data is not None, "setup() runs first"
        return sum(recording.rows for recording in self.data.recordings.values())

    def find_static_rows(self, recording: StreamedRecording, names: list[str]) -> StaticIntervals:
        """Detect the static intervals chunk by chunk and set ``recording.keep`` and ``recording.intervals`` (unless the rows
        are independent poses)."""
        layout = recording.layout
        time = None
        if self.time_column:
            time = MappedColumns(layout, column_index(names, [self.time_column], "time", self.path), self.static.time_scale, vector=True)
        detection = self.static.detect(MappedColumns(layout, recording.channel_index), time, self.row_place)
        known = []
        loads = MappedColumns(layout, recording.load_index)
        for start in range(0, recording.rows if recording.load_index else 0, CHUNK_ROWS):
            known.append(start + np.nonzero(np.isfinite(loads[start : start + CHUNK_ROWS]).all(axis=1))[0])
        keep = fitted_rows(detection, np.concatenate(known) if known else np.zeros(0, dtype=int), recording.rank, self.row_place)
        if not detection.independent:
            recording.keep, recording.intervals = keep, detection.intervals
        return detection

    def refuse_dates_with_a_unit(self) -> None:
        """A CSV's time column of dates or clock times is converted to seconds: a ``data.time_unit`` would scale them
        again (judged by the first row's cell)."""
        if self.path.suffix == ".npy":
            return
        source = open_delimited(self.path)
        header, records = source.header_and_rows()
        first = next(records, None)
        column = header.index(self.time_column) if self.time_column in header else None
        if first is not None and column is not None and column < len(first[1]) and clock_seconds(first[1][column]):
            raise SfmnetError(DATES_WITH_A_UNIT.format(name=self.time_column))

    def hint_line_warnings(self) -> list[str]:
        if self.mirror_hint is None or self.path.suffix == ".npy":
            return []
        row, delimited = int(self.mirror_hint["row"]), open_delimited(self.path)
        return hint_row_warnings(row, delimited.line_of_row(0), delimited.line_of_row(row), self.row_place(row))

    def read_mirror_hint(self, recording: StreamedRecording) -> None:
        """The hint's row, read from the file alone (one row through the memory map)."""
        row, axis, sign = mirror_hint_fields(self.mirror_hint, self.load_columns)
        values = np.asarray(mapped_rows(recording.layout, row, 1), dtype=np.float64)[0] if 0 <= row < recording.rows else None
        if values is None or np.isfinite(values[recording.load_index]).any() or (recording.keep is not None and not recording.keep[row]):
            raise SfmnetError(
                f"data.mirror_hint.row {row} must be a data row (0-based) whose load is unknown, in a static interval"
            )
        recording.mirror_hint = MirrorHint(sample=0, axis=axis, sign=sign, axis_name=self.load_columns[axis])
        recording.hint_reading = torch.from_numpy(values[recording.channel_index])
