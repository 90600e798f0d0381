"""Delimited text as people write it: a byte-order mark, ``,`` ``;`` or tab separators, decimal commas, quoted cells.

Every reader of a CSV goes through :class:`DelimitedFile`, so a file reads the same whatever
the command: Excel's "CSV UTF-8" (a UTF-8 BOM) and "Unicode Text" (UTF-16, tabs), and the
``;``-separated files of locales whose decimal mark is a comma (``1,23`` read as 1.23 when the
separator is ``;`` or a tab). Rows whose every cell is empty (blank lines, ``,,,``) are skipped
by every reader alike.
"""

from __future__ import annotations

import codecs
import csv
import itertools
import math
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from sfmnet.errors import SfmnetError

# In the order they are tried (see sniff_separator).
SEPARATORS = ("\t", ";", ",")

# A cell refused as a number that would be one with a decimal point for its comma, e.g. '1,23' quoted in a CSV.
DECIMAL_COMMA = re.compile(r"[-+]?\d*,\d+")

# Excel's first line naming the separator, e.g. ``sep=;``; quoted, or padded with separators by a spreadsheet that
# saved the file again (``sep=;;;;``).
EXCEL_SEPARATOR_LINE = re.compile(r'"?sep=(.)"?(.*)')

# A line number and the cells of that row (whitespace stripped); a quoted cell may run over several lines.
Record = tuple[int, list[str]]


@dataclass(frozen=True)
class DelimitedFile:
    """A CSV's text encoding and separator, as found by :func:`open_delimited`."""

    path: Path
    encoding: str
    separator: str
    # The file opens with Excel's ``sep=;`` line, which names the separator and is no part of the table.
    separator_line: bool = False

    @property
    def decimal_comma(self) -> bool:
        """``1,23`` is 1.23: the separator is not a comma, so a comma in a cell can only be a decimal mark."""
        return self.separator != ","

    def number(self, cell: str) -> float | None:
        """A stripped cell's value: NaN when empty, None when it is not a number."""
        if not cell:
            return math.nan
        try:
            return float(cell.replace(",", ".") if self.decimal_comma else cell)
        except ValueError:
            return None

    def records(self) -> Iterator[Record]:
        """Every row with a non-empty cell, the header first, each with the line it starts on."""
        with self.path.open(encoding=self.encoding, newline="") as stream:
            reader = csv.reader(stream, delimiter=self.separator, skipinitialspace=True, strict=True)
            line = 1
            # Excel's separator line, the first that is not blank, is no row.
            skip = self.separator_line
            while True:
                try:
                    row = next(reader)
                except StopIteration:
                    return
                except csv.Error as error:
                    raise SfmnetError(
                        f"{self.path} line {line}: {error} (a stray '\"'?): quote whole cells (\"...\") or remove the quote"
                    ) from None
                except UnicodeDecodeError:
                    raise undecodable(self.path, self.encoding) from None
                cells = [cell.strip() for cell in row]
                if any(cells) and skip:
                    skip = False
                elif any(cells):
                    yield line, cells
                line = reader.line_num + 1

    def header_and_rows(self) -> tuple[list[str], Iterator[Record]]:
        """The column names (refused when absent or repeated) and the data rows after them."""
        records = self.records()
        first = next(records, None)
        if first is None:
            raise SfmnetError(f"{self.path} is empty: give a CSV with a header row and one row per sample")
        header = first[1]
        if len(header) > 1 and header[-1] == "" and "" not in header[:-1]:
            # A separator ending every line (a spreadsheet's export) makes no column: each row's empty last cell goes.
            header = header[:-1]
            records = ((line, cells[:-1] if len(cells) > len(header) and cells[-1] == "" else cells) for line, cells in records)
        # Names may be numbers ("1", "2", ...), but most with a sign, a point or an exponent make a line of data.
        numbers = [name for name in header if name and not name.isdigit() and self.number(name) is not None]
        if len(numbers) > len(header) / 2:
            raise SfmnetError(
                f"the first line of {self.path} holds numbers ({', '.join(header[:3])}{', ...' if len(header) > 3 else ''}), "
                "not column names: add a first line naming the columns"
            )
        duplicates = sorted({name for name in header if header.count(name) > 1})
        if duplicates:
            raise SfmnetError(f"{self.path} has duplicate column names: {', '.join(duplicates)}; rename them")
        return header, records

    def line_of_row(self, row: int) -> int:
        """The line data row ``row`` (0-based, after the header and skipped rows) starts on; reads the file again."""
        records = self.records()
        next(records, None)
        return next(itertools.islice(records, row, None))[0]

    def check_width(self, line: int, cells: list[str], width: int) -> None:
        """Refuse a row whose cell count is not the header's, saying what most likely went wrong."""
        if len(cells) == width:
            return
        hint = ""
        if any("\n" in cell for cell in cells):
            hint = " (a quoted cell runs over several lines: a stray '\"'?)"
        elif self.separator == "," and len(cells) > width:
            hint = " (if ',' is also the decimal mark, save the file ';'-separated)"
        raise SfmnetError(f"{self.path} line {line} has {len(cells)} cells but the header has {width}{hint}")


def decimal_comma_hint(cells: Iterable[str]) -> str:
    """What to do when refused ``cells`` hold decimal commas (a comma-separated file cannot also use ',' for decimals)."""
    if any(DECIMAL_COMMA.fullmatch(cell) for cell in cells):
        return " (',' as the decimal mark: save the file ';'-separated, or with '.' decimals)"
    return ""


def open_delimited(path: Path) -> DelimitedFile:
    """The file's encoding (by its byte-order mark; UTF-8 without one) and separator (:func:`sniff_separator`)."""
    path = Path(path)
    with path.open("rb") as stream:
        start = stream.read(4)
    encoding = "utf-16" if start.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)) else "utf-8-sig"
    try:
        with path.open(encoding=encoding, newline="") as stream:
            lines = list(itertools.islice((line for line in stream if line.strip()), 2))
    except UnicodeDecodeError:
        raise undecodable(path, encoding) from None
    named = EXCEL_SEPARATOR_LINE.fullmatch(lines[0].rstrip("\r\n")) if lines else None
    if named and set(named.group(2)) <= {named.group(1)}:
        return DelimitedFile(path, encoding, named.group(1), separator_line=True)
    return DelimitedFile(path, encoding, sniff_separator(lines))


def sniff_separator(lines: list[str]) -> str:
    """The first of tab, ``;`` and ``,`` that splits the header (``lines[0]``) into several cells and the first
    data row (``lines[1]``, if any) into as many; a comma where none does, so a one-column file is a CSV.

    Tab and ``;`` go first because column names may hold commas (``Kraft, x;Kraft, y``) where the
    cells hold decimal commas (``1,5;2,5``): both split evenly by commas too.
    """
    header, first = (lines + ["", ""])[:2]
    for separator in SEPARATORS:
        cells = cell_count(header, separator)
        if cells > 1 and (not first or cell_count(first, separator) == cells):
            return separator
    return ","


def cell_count(line: str, separator: str) -> int:
    """How many cells ``separator`` splits ``line`` into (quoted separators not counted)."""
    return len(next(csv.reader([line], delimiter=separator), []))


def undecodable(path: Path, encoding: str) -> SfmnetError:
    """The error for a file that its byte-order mark (or its lack) says is ``encoding`` but is not: the first such line."""
    if encoding == "utf-8-sig":
        with path.open("rb") as stream:
            for line, raw in enumerate(stream, start=1):
                try:
                    raw.decode("utf-8")
                except UnicodeDecodeError as error:
                    return SfmnetError(f"{path} line {line} is not UTF-8 text (byte 0x{raw[error.start]:02x}): save it as 'CSV UTF-8'")
    return SfmnetError(f"{path} is not {encoding.removesuffix('-sig').upper()} text: save it as 'CSV UTF-8'")
