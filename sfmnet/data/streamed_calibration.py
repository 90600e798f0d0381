"""A calibration session too long for memory: one mass turned through unknown orientations, streamed from a file."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from sfmnet.data.csv_calibration import calibration_magnitude, mirror_hint_fields
from sfmnet.data.recording import CalibrationData
from sfmnet.data.row_file import RowData, RowFileDataModule, column_index, mapped_rows
from sfmnet.errors import SfmnetError
from sfmnet.linalg.frame import MirrorHint
from sfmnet.linalg.wrench import STANDARD_GRAVITY


@dataclass
class StreamedRecording(RowData):
    """A row file of raw channels and load columns (NaN where the load is unknown), every row the same mass.

    Attributes (beyond :class:`RowData`):
        magnitude: ``F``, the calibration load's magnitude (load units).
        known_load_tolerance: relative disagreement allowed between a known load's magnitude and ``F``.
        mirror_hint: which side of the mirror the row ``hint_reading`` lies on (``sample`` unused), or None.
        hint_reading: ``p`` raw readings of the mirror hint's row.
    """

    magnitude: float = math.nan
    known_load_tolerance: float = 0.02
    mirror_hint: MirrorHint | None = None
    hint_reading: torch.Tensor | None = None

    recording = "streamed_rotation"

    @property
    def rank(self) -> int:
        return len(self.load_columns)


class StreamedCalibrationDataModule(RowFileDataModule):
    """The calibration file of :class:`~sfmnet.data.csv_calibration.CsvCalibrationDataModule`, streamed in blocks.

    Same columns and meaning (load columns empty or NaN except on the few known-load rows), but
    the rows are read block by block through a memory map (a CSV converted once to ``.npy``),
    so the session may be longer than memory and shared between processes. One mass only
    (2-, 3- or n-axis force sensors); six-axis sessions with several mass configurations
    are fitted in memory (``experiment=calibrate_csv``).

    Args:
        path: ``.npy`` or ``.csv`` (header row).
        load_columns: the ``n`` load columns.
        magnitude: the load magnitude (load units); or give ``mass`` (kg).
        channel_columns: raw channels (default: every column but the loads and ``time_column``).
        time_column: a column to ignore.
        columns: names of a ``.npy``'s columns.
        mirror_hint: ``{row: <data row, 0-based>, axis: <load column>, sign: <+1|-1>}``, with ``n - 1`` known loads.
        known_load_tolerance: see :class:`StreamedRecording`.
        load_unit: for reports.
        gravity: m/s^2, for ``mass``.
        block_rows, cache_dir: see :class:`RowFileDataModule`.
    """

    def __init__(
        self,
        path: str,
        load_columns: list[str],
        magnitude: float | None = None,
        mass: float | None = None,
        channel_columns: list[str] | None = None,
        time_column: str | None = None,
        columns: list[str] | None = None,
        mirror_hint: dict | None = None,
        known_load_tolerance: float = 0.02,
        load_unit: str = "N",
        gravity: float = STANDARD_GRAVITY,
        block_rows: int | None = None,
        cache_dir: str | None = None,
    ) -> None:
        super().__init__(path, columns=columns, channel_columns=channel_columns, block_rows=block_rows, cache_dir=cache_dir)
        self.load_columns = list(load_columns)
        self.magnitude = magnitude
        self.mass = mass
        self.time_column = time_column
        self.mirror_hint = mirror_hint
        self.known_load_tolerance = known_load_tolerance
        self.load_unit = load_unit
        self.gravity = gravity

    def build(self) -> CalibrationData:
        magnitude = calibration_magnitude(self.magnitude, self.mass, self.gravity)
        layout, names = self.open_rows()
        load_index = column_index(names, self.load_columns, "load", self.path)
        channels = self.channel_columns or [n for n in names if n not in self.load_columns and n != self.time_column]
        if len(channels) < len(self.load_columns):
            raise SfmnetError(
                f"{len(channels)} channel columns for {len(self.load_columns)} load axes: a calibration needs at "
                "least as many channels as axes; list them with data.channel_columns=[...]"
            )
        recording = self.row_data(
            layout, names, channels, StreamedRecording,
            load_columns=self.load_columns, load_index=load_index, magnitude=magnitude,
            known_load_tolerance=self.known_load_tolerance,
        )
        if self.mirror_hint is not None:
            self.read_mirror_hint(recording)
        return CalibrationData(
            recordings={recording.recording: recording}, channels=channels, axes=self.load_columns, load_unit=self.load_unit
        )

    def read_mirror_hint(self, recording: StreamedRecording) -> None:
        """The hint's row, read from the file alone (one row through the memory map)."""
        row, axis, sign = mirror_hint_fields(self.mirror_hint, self.load_columns)
        values = np.asarray(mapped_rows(recording.layout, row, 1), dtype=np.float64)[0] if 0 <= row < recording.rows else None
        if values is None or np.isfinite(values[recording.load_index]).any():
            raise SfmnetError(f"data.mirror_hint.row {row} must be a data row (0-based) whose load is unknown")
        recording.mirror_hint = MirrorHint(sample=0, axis=axis, sign=sign)
        recording.hint_reading = torch.from_numpy(values[recording.channel_index])

