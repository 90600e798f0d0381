"""A sensorimotor log from a file: sensor columns and command columns, one row per time step."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sfmnet.data.sensorimotor import (
    Command,
    Episode,
    SensorimotorData,
    SensorimotorDataModule,
    label_indices,
)
from sfmnet.readers.table_file import Table, check_finite, read_table, refuse_columns_named_twice
from sfmnet.errors import SfmnetError


class SensorimotorCsvDataModule(SensorimotorDataModule):
    """Time-ordered rows; the last ``test_fraction`` held out (no shuffling: neighbouring rows are near copies).

    Args:
        path: CSV (header row), ``.npz`` or ``.npy`` (with ``columns``).
        sensor_columns: numeric sensor columns.
        command_columns: command columns, numeric or text; each is categorical (one-hot, decoded back to labels).
        columns: names of a ``.npy`` file's columns.
        test_fraction: the last part of the log held out.
        period: seconds per row (for plots).
    """

    def __init__(
        self,
        path: str,
        sensor_columns: list[str],
        command_columns: list[str],
        columns: list[str] | None = None,
        test_fraction: float = 0.3,
        period: float = 1.0,
        batch_size: int | None = None,
    ) -> None:
        super().__init__(batch_size=batch_size)
        self.path = Path(path)
        self.sensor_columns = list(sensor_columns)
        self.command_columns = list(command_columns)
        self.columns = columns
        self.test_fraction = test_fraction
        self.period = period

    def build(self) -> SensorimotorData:
        if not 0 < self.test_fraction < 1:
            raise SfmnetError(f"data.test_fraction must be between 0 and 1, not {self.test_fraction}")
        if not self.sensor_columns or not self.command_columns:
            raise SfmnetError("name the columns: data.sensor_columns=[...] and data.command_columns=[...]")
        refuse_columns_named_twice({"sensor": self.sensor_columns, "command": self.command_columns})
        table = read_table(self.path, self.columns)
        sensors = table.numeric(self.sensor_columns, "sensor")
        check_finite(sensors, self.sensor_columns, table, "sensor")
        raw = [table.categorical(name, "command") for name in self.command_columns]
        for name, values in zip(self.command_columns, raw):
            refuse_empty_commands(values, name, table)
            refuse_continuous_commands(values, name)
        split = round(len(sensors) * (1 - self.test_fraction))
        if split == len(sensors):
            raise SfmnetError(
                f"data.test_fraction={self.test_fraction} holds out none of the {len(sensors)} rows: give at least "
                f"{1 / len(sensors):.2g}"
            )
        commands, indices = [], []
        for name, values in zip(self.command_columns, raw):
            labels = sorted(set(values[:split].tolist()), key=sort_key)
            unseen = sorted(set(values[split:].tolist()) - set(labels), key=sort_key)
            if unseen:
                raise SfmnetError(
                    f"command column '{name}' takes {unseen[0]!r} in the held-out rows but never in training: "
                    "a learner cannot produce it; use a longer log or a smaller data.test_fraction"
                )
            commands.append(Command(name, [plain(label) for label in labels]))
            indices.append(label_indices(values, labels))
        codes = np.stack(indices, axis=1)
        return SensorimotorData(
            train=[Episode(sensors[:split], codes[:split])],
            test=[Episode(sensors[split:], codes[split:])],
            sensors=self.sensor_columns,
            commands=commands,
            period=self.period,
        )


def refuse_empty_commands(values: np.ndarray, name: str, table: Table) -> None:
    """An empty command cell is no command a learner can produce: refuse it rather than make it a class of its own."""
    empty = np.array([value == "" or (isinstance(value, float) and math.isnan(value)) for value in values])
    if empty.any():
        rows = np.nonzero(empty)[0]
        raise SfmnetError(
            f"{table.path} has {len(rows)} empty cells in command column '{name}' (first: {table.row_place(int(rows[0]))}): "
            "fill in every command or drop those rows"
        )


# More distinct values than this (and than a tenth of the rows) make a command a signal, not a choice among labels.
MAX_COMMAND_LABELS = 20


def refuse_continuous_commands(values: np.ndarray, name: str) -> None:
    """A command with a label per few rows (a velocity logged as a number) would be hundreds of one-hot columns, most
    seen only once: refuse it, saying to bin it."""
    labels = len(set(values.tolist()))
    if labels > max(MAX_COMMAND_LABELS, len(values) / 10):
        raise SfmnetError(
            f"command column '{name}' takes {labels} different values in {len(values)} rows: a command is one of a few "
            "labels (one-hot encoded), not a continuous signal; bin it into a few levels (e.g. -1, 0, +1)"
        )


def sort_key(label: object) -> tuple[int, object]:
    return (0, label) if isinstance(label, float) else (1, str(label))


def plain(label: object) -> object:
    """Whole-number floats read from a file as ints (so -1.0/0.0/1.0 read as the MK-V's alphabet)."""
    return int(label) if isinstance(label, float) and label.is_integer() else label
