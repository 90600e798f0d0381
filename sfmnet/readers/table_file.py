"""Reading a table of named numeric columns from CSV, ``.npy`` or ``.npz``, with errors a user can act on."""

from __future__ import annotations

import difflib
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from sfmnet.data.rows import IMPLAUSIBLE
from sfmnet.errors import SfmnetError
from sfmnet.readers.clock_times import clock_time_column, clock_time_hint
from sfmnet.preprocessing.far_cells import FAR_CELLS_REMEDY, far_cells, far_cells_what
from sfmnet.readers.delimited import decimal_comma_hint, open_delimited
from sfmnet.readers.input_file import check_input_file


def plain_name(name: str) -> str:
    """A column name's letters and digits, in lower case."""
    return "".join(character for character in name.casefold() if character.isalnum())


def missing_column(name: str, role: str, path: Path, names: list[str]) -> SfmnetError:
    """The error for a ``role`` column ``name`` that the file lacks, with its closest match (any case first)."""
    same_but_case = [other for other in names if other.casefold() == name.casefold()]
    # Then the same letters and digits: "Wheel L" for wheel_l.
    same_but_spelling = [other for other in names if plain_name(other) == plain_name(name)]
    close = same_but_case or same_but_spelling or difflib.get_close_matches(name, names, n=1)
    hint = f" (did you mean '{close[0]}'?)" if close else ""
    return SfmnetError(f"{role} column '{name}' is not in {path}{hint}; its columns are: {', '.join(names)}")


DATES_WITH_A_UNIT = (
    "time column '{name}' holds dates or clock times, which are read as seconds: data.time_unit is for a time column "
    "of numbers; leave it out"
)


@dataclass(frozen=True)
class Table:
    """Columns by name, each a float64 array of the same length; NaN where a cell was empty.

    Attributes:
        path: where it was read from (for messages).
        columns: name -> values, in file order.
        text: name -> the first offending cells, for columns that are not all numeric (e.g. labels).
        corrupt: the text columns that are mostly numbers: numeric columns with bad cells.
        cells: every cell of each text column (category labels).
        hints: what to do about a text column's refused cells (decimal commas), by column.
        lines: the file line each row was read from (1-based; blank lines, comments and quoted cells
            over several lines make it differ from the row's index), None for arrays (``.npy``, ``.npz``).
    """

    path: Path
    columns: dict[str, np.ndarray]
    text: dict[str, list[str]]
    corrupt: frozenset[str] = frozenset()
    cells: dict[str, list[str]] = field(default_factory=dict)
    lines: np.ndarray | None = None
    hints: dict[str, str] = field(default_factory=dict)

    def row_place(self, row: int) -> str:
        """Where data row ``row`` (0-based) is, in the words a user finds it by: ``line 17``, or ``data row 15 (0-based)``."""
        return f"line {int(self.lines[row])}" if self.lines is not None else f"data row {row} (0-based)"

    def where(self, row: int) -> str:
        """:meth:`row_place` and the file: ``line 17 of session.csv``."""
        return f"{self.row_place(row)} of {self.path}"

    def require(self, names: list[str], role: str) -> None:
        """Raise a clear error naming each missing column and its closest match."""
        for name in names:
            if name not in self.columns and name not in self.text:
                raise missing_column(name, role, self.path, [*self.columns, *self.text])
            if name in self.text:
                raise SfmnetError(f"{role} column '{name}' of {self.path} is not numeric: {self.text[name]}{self.hints.get(name, '')}")

    def categorical(self, name: str, role: str) -> np.ndarray:
        """One column's values as categories: the text labels, or the numbers of a numeric column."""
        if name not in self.columns and name not in self.cells:
            self.require([name], role)
        return np.array(self.cells[name] if name in self.cells else self.columns[name], dtype=object)

    def times(self, name: str, scale: float) -> np.ndarray:
        """Time column ``name`` in seconds: its numbers times ``scale`` (``data.time_unit``), or its dates or clock times
        (:mod:`sfmnet.readers.clock_times`) from the first row's, whatever the unit."""
        if name in self.cells:
            seconds = clock_time_column(self.cells[name], self.where)
            if seconds is not None:
                if scale != 1.0:
                    raise SfmnetError(DATES_WITH_A_UNIT.format(name=name))
                return seconds
        return self.numeric([name], "time")[:, 0] * scale

    def numeric(self, names: list[str], role: str) -> np.ndarray:
        """``rows x len(names)`` float64, after :meth:`require`."""
        self.require(names, role)
        return np.stack([self.columns[name] for name in names], axis=1)


def read_table(path: Path, columns: list[str] | None = None, option: str = "data.path") -> Table:
    """Read a CSV or ``.tsv`` (header row, one sample per row; see :mod:`sfmnet.readers.delimited`), ``.npy``
    (needs ``columns``), ``.npz`` (one array per column), or a whitespace-separated text table (``.txt``,
    ``.dat``: numbers only, a header row unless ``columns`` names the columns, as loggers and MATLAB's
    ``save -ascii`` write). ``option`` is what the user set the path with (for messages).

    Empty cells become NaN. A column with any non-numeric, non-empty cell is kept as text and
    refused where a number is needed.
    """
    path = check_input_file(path, option, "a file (.csv, .npy or .npz)")
    try:
        if path.suffix == ".npy":
            return _from_array(path, real_values(path, np.load(path, allow_pickle=False), "its array"), columns)
        if path.suffix == ".npz":
            return _from_archive(path)
        if path.suffix in WHITESPACE_SUFFIXES:
            return _read_whitespace(path, columns)
        return _read_csv(path)
    except PermissionError:
        raise SfmnetError(f"{path} cannot be read (permission denied): check the file's permissions") from None
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as error:
        if isinstance(error, SfmnetError):
            raise
        kind = path.suffix or "CSV"
        raise SfmnetError(f"{path} cannot be read as {kind} ({error}): it is truncated or not a {kind} file; check data.path") from None


def _from_array(path: Path, array: np.ndarray, columns: list[str] | None) -> Table:
    if array.ndim != 2:
        raise SfmnetError(f"{path} holds a {array.ndim}-D array: give a 2-D array, one row per sample")
    if not columns or len(columns) != array.shape[1]:
        raise SfmnetError(
            f"{path} has {array.shape[1]} columns: name them all with data.columns=[...] ({len(columns or [])} given)"
        )
    return Table(path, {name: array[:, i].astype(np.float64) for i, name in enumerate(columns)}, {})


def _from_archive(path: Path) -> Table:
    """An ``.npz`` of one array per column (a 2-D one is flattened), every column as long as the others."""
    with np.load(path, allow_pickle=False) as archive:
        arrays = {name: real_values(path, archive[name], f"column '{name}'").ravel() for name in archive.files}
    if not arrays:
        raise SfmnetError(f"{path} holds no arrays: save one array per column, e.g. np.savez(path, s0=..., fx=...)")
    lengths = {name: len(values) for name, values in arrays.items()}
    if len(set(lengths.values())) > 1:
        shown = ", ".join(f"{name} {length}" for name, length in lengths.items())
        raise SfmnetError(f"{path} holds columns of different lengths ({shown}): every column needs one value per row")
    return Table(path, {name: values.astype(np.float64) for name, values in arrays.items()}, {})


def real_values(path: Path, array: np.ndarray, what: str) -> np.ndarray:
    """``array`` if it holds at least one real number (or bool); else one line naming ``what`` of ``path``."""
    if np.iscomplexobj(array):
        raise SfmnetError(f"{path}: {what} holds complex numbers: save real values (e.g. the real part or the magnitude)")
    if not (np.issubdtype(array.dtype, np.number) or array.dtype == np.bool_):
        raise SfmnetError(f"{path}: {what} holds {array.dtype} values, not numbers: save numeric columns")
    if array.size == 0:
        raise SfmnetError(f"{path}: {what} is empty: save at least one row")
    return array


# Not .tsv: two tabs there are an empty cell, where runs of whitespace are one separator.
WHITESPACE_SUFFIXES = (".txt", ".dat")


def _read_whitespace(path: Path, columns: list[str] | None) -> Table:
    """A numeric table separated by spaces or tabs; named by ``columns``, else by its first line.

    Blank lines and ``#`` comments are skipped, as ``np.loadtxt`` does; each row keeps its file line.
    """
    with path.open(encoding="utf-8-sig") as stream:
        rows = [(number, text.split("#")[0].split()) for number, text in enumerate(stream, 1) if text.split("#")[0].strip()]
    header = None
    if not columns:
        header = rows.pop(0)[1] if rows else []
    if header and all(_is_number(name) for name in header):
        raise SfmnetError(
            f"{path} has no header row (its first line is numbers): name its {len(header)} columns with data.columns=[...]"
        )
    width = len(columns or header)
    values = []
    for number, cells in rows:
        if len(cells) != width:
            raise SfmnetError(f"{path} line {number} has {len(cells)} values but the table has {width} columns")
        try:
            values.append([float(cell) for cell in cells])
        except ValueError:
            refused = next(cell for cell in cells if not _is_number(cell))
            raise SfmnetError(f"{path} line {number} has a non-numeric value ('{refused}'): a .txt or .dat table holds numbers only") from None
    array = np.array(values, dtype=np.float64).reshape(len(rows), width)
    return replace(_from_array(path, array, columns or header), lines=np.array([number for number, _ in rows]))


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _read_csv(path: Path) -> Table:
    source = open_delimited(path)
    header, records = source.header_and_rows()
    lines, body = [], []
    for line, cells in records:
        source.check_width(line, cells, len(header))
        lines.append(line)
        body.append(cells)
    if not body:
        raise SfmnetError(f"{path} has a header but no data rows")
    columns: dict[str, np.ndarray] = {}
    text: dict[str, list[str]] = {}
    cells_of: dict[str, list[str]] = {}
    corrupt: set[str] = set()
    hints: dict[str, str] = {}
    for index, name in enumerate(header):
        cells = [row[index] for row in body]
        values = [source.number(cell) for cell in cells]
        if any(value is None for value in values):
            bad = [(line, cell) for line, cell, value in zip(lines, cells, values) if value is None]
            text[name] = [f"line {line}: '{cell}'" for line, cell in bad[:3]] + ([f"... {len(bad)} cells"] if len(bad) > 3 else [])
            hints[name] = decimal_comma_hint(cell for _, cell in bad) or clock_time_hint(cell for _, cell in bad)
            cells_of[name] = cells
            if len(bad) < len(cells) / 2:
                corrupt.add(name)
        else:
            columns[name] = np.array(values, dtype=np.float64)
    return Table(path, columns, text, frozenset(corrupt), cells_of, np.array(lines), hints)




def check_finite(values: np.ndarray, names: list[str], table: Table, role: str) -> None:
    """Refuse NaN, infinite or implausibly large readings (``values``: ``table``'s columns ``names``), saying how many and where."""
    refuse_cells(~np.isfinite(values), values, names, table, f"empty, NaN or infinite {role} values", "remove or repair those rows", False)
    refuse_cells(
        np.abs(values) > IMPLAUSIBLE, values, names, table, f"{role} values beyond {IMPLAUSIBLE:.0e}",
        "a corrupt cell or a unit slip; repair those rows", True,
    )


def check_far_cells(values: np.ndarray, names: list[str], table: Table, role: str) -> None:
    """Refuse the far cells of ``values`` (``table``'s columns ``names``; :func:`~sfmnet.preprocessing.far_cells.far_cells`:
    the few at either end of a column that stand 1e4 times the rest's range away from it)."""
    bad = far_cells(values)
    refuse_cells(bad, values, names, table, far_cells_what(role, int(bad.sum())), FAR_CELLS_REMEDY, True)


def refuse_cells(
    bad: np.ndarray, values: np.ndarray, names: list[str], table: Table, what: str, remedy: str, show_value: bool
) -> None:
    """Raise naming how many cells ``bad`` marks and the first three (file line, column, value)."""
    if not bad.any():
        return
    rows, cols = np.nonzero(bad)
    where = ", ".join(
        f"{table.row_place(r)} column {names[c]}" + (f" ({values[r, c]:.3g})" if show_value else "")
        for r, c in zip(rows[:3], cols[:3])
    )
    raise SfmnetError(f"{table.path} has {int(bad.sum())} {what} (first: {where}): {remedy}")


def refuse_columns_named_twice(roles: dict[str, list[str]]) -> None:
    """A column named twice would be counted twice (a channel) or read as two things (a time that is also a channel; a
    command that is also a sensor, which reads the command from itself)."""
    seen: dict[str, str] = {}
    for role, names in roles.items():
        for name in names:
            if name in seen:
                both = f"as a {role} column twice" if seen[name] == role else f"as both a {seen[name]} and a {role} column"
                raise SfmnetError(f"column '{name}' is named {both}: give each column one role, once")
            seen[name] = role
