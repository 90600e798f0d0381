"""Rows of numbers too many to hold in memory: a ``.npy`` read through a memory map, block by block (method §11).

A CSV is converted once to ``.npy`` named by a digest of its bytes, so later runs stream it
like any ``.npy``. Blocks are shared out between processes by the data module itself (block
``i`` to rank ``i mod world``), never by a distributed sampler, which pads with repeated
samples: ranks left short get empty blocks instead, so every row is counted exactly once and
every rank takes the same number of steps (the strategy's collectives pair up).
"""

from __future__ import annotations

import hashlib
import itertools
import math
import os
from pathlib import Path

import lightning as L
import numpy as np
import torch
import torch.distributed as dist
from torch.utils.data import DataLoader, Dataset, Sampler

from sfmnet.data.rows import BLOCK_BYTES, IMPLAUSIBLE, SHIFT_ROWS, NpyLayout, RowBlock, RowData, mapped_rows, npy_layout
from sfmnet.errors import SfmnetError
from sfmnet.io import temporary_beside
from sfmnet.readers.clock_times import ClockTimes, clock_time_hint
from sfmnet.readers.delimited import DelimitedFile, decimal_comma_hint, open_delimited
from sfmnet.readers.input_file import check_input_file
from sfmnet.readers.table_file import WHITESPACE_SUFFIXES, missing_column


class BlockDataset(Dataset):
    """Block ``i`` is rows ``[i B, (i + 1) B)`` as a :class:`RowBlock`, read through its own memory map.

    Mapping one block at a time (and dropping the map after the copy) keeps the resident
    memory to about a few blocks, whatever the file's size. Conversion and shift are one pass
    into a ring of reused buffers (no fresh allocation per block); the ring is longer than
    the trainer's one-batch prefetch, so a block is consumed before its buffer is refilled.
    """

    RING = 3

    def __init__(self, data: RowData, block_rows: int) -> None:
        self.data = data
        self.block_rows = block_rows
        self.shift = data.shift.numpy()
        # Every column in order (the usual PCA case): no gather before the conversion.
        self.all_columns = data.channel_index == list(range(data.layout.shape[1]))
        self.buffers: list[np.ndarray] = []
        self.turn = 0

    def __len__(self) -> int:
        return math.ceil(self.data.rows / self.block_rows)

    def __getitem__(self, index: int) -> RowBlock:
        """Block ``index``; ``-1`` is an empty block (padding for a rank with fewer blocks)."""
        p, n = len(self.data.channel_index), len(self.data.load_index)
        if index < 0:
            return RowBlock(self.data.rows, torch.zeros(0, p, dtype=torch.float64), torch.zeros(0, n, dtype=torch.float64))
        start = index * self.block_rows
        count = min(self.block_rows, self.data.rows - start)
        mapped = mapped_rows(self.data.layout, start, count)
        if len(self.buffers) < self.RING:
            self.buffers.append(np.empty((self.block_rows, p)))
        buffer = self.buffers[self.turn % self.RING][:count]
        self.turn += 1
        np.subtract(mapped if self.all_columns else mapped[:, self.data.channel_index], self.shift, out=buffer, dtype=np.float64)
        loads = np.array(mapped[:, self.data.load_index], dtype=np.float64)
        del mapped
        return RowBlock(start, torch.from_numpy(buffer), torch.from_numpy(loads))


class ShardSampler(Sampler[int]):
    """Blocks ``rank, rank + world, ...``: each block to exactly one process, then ``-1`` (empty) up to the longest rank."""

    def __init__(self, blocks: int) -> None:
        self.blocks = blocks

    @staticmethod
    def rank_and_world() -> tuple[int, int]:
        if dist.is_available() and dist.is_initialized():
            return dist.get_rank(), dist.get_world_size()
        return 0, 1

    def __iter__(self):
        rank, world = self.rank_and_world()
        mine = list(range(rank, self.blocks, world))
        return iter(mine + [-1] * (len(self) - len(mine)))

    def __len__(self) -> int:
        _, world = self.rank_and_world()
        return math.ceil(self.blocks / world)


class RowFileDataModule(L.LightningDataModule):
    """Serves a row file as ``{"rows": loader of RowBlock}``, one pass per epoch (a subclass may name it otherwise).

    Args:
        path: ``.npy`` (any numeric dtype; read through a memory map) or ``.csv`` (header row;
            empty cells read as NaN; converted once to ``.npy`` in ``cache_dir``).
        columns: names for a ``.npy``'s columns (default ``c0, c1, ...``).
        channel_columns: the columns to fit (default: all).
        block_rows: rows per block (default: about 32 MB of float64 per block).
        cache_dir: where CSV conversions live (default: ``.sfmnet-cache`` beside the CSV).
    """

    task = "pca"

    def __init__(
        self,
        path: str,
        columns: list[str] | None = None,
        channel_columns: list[str] | None = None,
        block_rows: int | None = None,
        cache_dir: str | None = None,
    ) -> None:
        super().__init__()
        self.path = Path(path)
        if self.path.suffix == ".npz":
            raise SfmnetError(f"{self.path} is an .npz archive, which cannot be streamed: save the rows as one 2-D .npy or a CSV")
        self.columns = columns
        self.channel_columns = list(channel_columns) if channel_columns else None
        self.block_rows = block_rows
        self.cache_dir = Path(cache_dir) if cache_dir else None
        self.data: RowData | None = None

    def setup(self, stage: str | None = None) -> None:
        if self.data is None:
            self.data = self.build()

    @property
    def rows(self) -> int:
        """The file's rows, after :meth:`setup`."""
        assert self.data is not None, "setup() runs first"
        return self.data.rows

    def build(self) -> RowData:
        layout, names = self.open_rows()
        return self.row_data(layout, names, self.channel_columns or names)

    def csv_columns(self) -> list[str] | None:
        """The CSV columns the run reads, converted alone (other columns may hold text); None: every column."""
        return self.channel_columns

    def time_columns(self) -> tuple[str, ...]:
        """The CSV columns that may hold dates or clock times (read as seconds)."""
        return ()

    def open_rows(self) -> tuple[NpyLayout, list[str]]:
        """The file's layout and its column names (a CSV converted to ``.npy`` first)."""
        self.path = check_input_file(self.path, "data.path", "a .npy or .csv of rows")
        if self.path.suffix in WHITESPACE_SUFFIXES:
            raise SfmnetError(
                f"{self.path} is a {self.path.suffix} table, which is read whole: a streamed run reads a .csv or a .npy "
                "block by block; save the rows as .npy (np.save) or .csv, or calibrate in memory (experiment=calibrate_csv)"
            )
        source, kept = self.path, None
        if self.path.suffix != ".npy":
            kept = self.csv_columns()
            source = csv_to_npy(self.path, self.cache_dir, kept, time_columns=self.time_columns())
        try:
            layout = npy_layout(source)
        except (ValueError, OSError) as error:
            raise SfmnetError(f"{source} cannot be read as .npy ({error}): it is truncated or not a .npy file; check data.path") from None
        rows, p = layout.shape
        if rows < 2 or not np.issubdtype(layout.dtype, np.number):
            raise SfmnetError(f"{source} holds a {layout.dtype} array of shape {layout.shape}: give a 2-D numeric array, one row per sample")
        names = self.columns or kept or (csv_header(self.path) if self.path.suffix != ".npy" else [f"c{i}" for i in range(p)])
        if len(names) != p:
            raise SfmnetError(f"{len(names)} names in data.columns for {p} columns in {self.path}")
        return layout, list(names)

    def row_data(self, layout: NpyLayout, names: list[str], channels: list[str], data_class: type = RowData, **extra) -> RowData:
        """``data_class`` over ``channels`` (and ``extra``), with the shift: the channels' mean over the first rows."""
        index = column_index(names, channels, "channel", self.path)
        first = np.asarray(mapped_rows(layout, 0, min(layout.shape[0], SHIFT_ROWS))[:, index], dtype=np.float64)
        finite = np.abs(first) <= IMPLAUSIBLE
        if not finite.all():
            empty = [channels[i] for i in np.nonzero(~finite.any(axis=0))[0]]
            if empty:
                raise SfmnetError(
                    f"{'columns' if len(empty) > 1 else 'column'} {', '.join(empty)} of {self.path} "
                    f"{'are' if len(empty) > 1 else 'is'} empty on each of the first {len(first)} rows, so not a channel: "
                    "list the channels with data.channel_columns=[...], or name the known loads' columns in data.load_columns"
                )
            row = int(np.argmax(~finite.all(axis=1)))
            columns = ", ".join(channels[i] for i in np.nonzero(~finite[row])[0])
            raise SfmnetError(
                f"{self.row_place(row)} has a NaN, empty or infinite channel cell, or one beyond {IMPLAUSIBLE:.0e} ({columns}): "
                "repair or drop that row"
            )
        return data_class(
            layout=layout, channels=list(channels), channel_index=index, shift=torch.from_numpy(first.mean(axis=0)),
            place=self.row_place, **extra,
        )

    def row_place(self, row: int) -> str:
        """Where data row ``row`` (0-based) of the user's file is: ``line 17 of x.csv`` or ``data row 15 (0-based) of x.npy``."""
        if self.path.suffix == ".npy":
            return f"data row {row} (0-based) of {self.path}"
        return f"line {open_delimited(self.path).line_of_row(row)} of {self.path}"

    def train_dataloader(self) -> dict[str, DataLoader]:
        assert self.data is not None, "setup() runs before the loaders"
        loaders = {}
        for name, rows in self.data.recordings.items():
            dataset = BlockDataset(rows, self.block_rows or max(1, BLOCK_BYTES // (8 * rows.layout.shape[1])))
            loaders[name] = DataLoader(dataset, batch_size=None, sampler=ShardSampler(len(dataset)))
        return loaders


def column_index(names: list[str], wanted: list[str], role: str, path: Path) -> list[int]:
    """Positions of ``wanted`` among the file's column ``names``."""
    missing = [name for name in wanted if name not in names]
    if missing:
        raise missing_column(missing[0], role, path, names)
    return [names.index(name) for name in wanted]


def csv_header(path: Path) -> list[str]:
    return open_delimited(path).header_and_rows()[0]


def content_key(path: Path) -> str:
    """A digest of the file's bytes: a cache made from other contents is never reused, whatever the file's size and mtime."""
    digest = hashlib.blake2b(digest_size=16)
    with path.open("rb") as stream:
        while block := stream.read(2**20):
            digest.update(block)
    return digest.hexdigest()


def csv_to_npy(
    path: Path, cache_dir: Path | None, columns: list[str] | None = None, chunk_rows: int = 100_000,
    time_columns: tuple[str, ...] = (),
) -> Path:
    """Convert a numeric CSV (header row; empty cells NaN) to float64 ``.npy`` once; reuse it while the CSV's bytes are the same.

    ``columns``: convert only these, in this order (the others are not parsed, so they may hold
    text); None: every column. ``time_columns`` may hold dates or clock times, read as seconds
    (:func:`~sfmnet.readers.clock_times.clock_seconds`: Unix time where a date is given). The conversion is written
    under a name of its own and renamed into place, so runs converting one CSV at once never read or clobber each
    other's half-written file.
    """
    chosen = (columns, time_columns) != (None, ())
    key = ",".join(columns or []) + ";" + ",".join(time_columns)
    selection = "-" + hashlib.blake2b(key.encode(), digest_size=8).hexdigest() if chosen else ""
    cache = (cache_dir or path.parent / ".sfmnet-cache") / f"{path.stem}-{content_key(path)}{selection}.npy"
    if cache.is_file():
        return cache
    source = open_delimited(path)
    header, records = source.header_and_rows()
    index = list(range(len(header))) if columns is None else column_index(header, columns, "listed", path)
    rows = sum(1 for _ in records)
    if rows < 2:
        raise SfmnetError(f"{path} has {rows} data rows: give a CSV with a header and at least two rows")
    try:
        handle, temporary = temporary_beside(cache, ".partial")
    except OSError as error:
        raise SfmnetError(
            f"the CSV's conversion cannot be written to {cache.parent} ({error.strerror}): set data.cache_dir to a writable folder"
        ) from None
    os.close(handle)
    try:
        out = np.lib.format.open_memmap(temporary, mode="w+", dtype=np.float64, shape=(rows, len(index)))
        times = {header.index(name): ClockTimes() for name in time_columns if name in header}
        written = fill_rows(out, source, header, index, chunk_rows, times)
        out.flush()
        del out
        if written != rows:
            raise SfmnetError(f"{path} changed while it was being converted: run again once it is written")
        os.replace(temporary, cache)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    return cache


def fill_rows(
    out: np.ndarray, source: DelimitedFile, header: list[str], index: list[int], chunk_rows: int,
    times: dict[int, ClockTimes],
) -> int:
    """Parse the CSV's data rows' columns ``index`` into ``out``, ``chunk_rows`` at a time (dates or clock times allowed
    in columns ``times``); returns the rows written."""
    records = source.header_and_rows()[1]
    written = 0
    while chunk := list(itertools.islice(records, chunk_rows)):
        if written + len(chunk) > len(out):
            raise SfmnetError(f"{source.path} changed while it was being converted: run again once it is written")
        out[written : written + len(chunk)] = [row_values(source, header, index, line, cells, times) for line, cells in chunk]
        written += len(chunk)
    return written


def row_values(
    source: DelimitedFile, header: list[str], index: list[int], line: int, cells: list[str],
    times: dict[int, ClockTimes],
) -> list[float]:
    """One data row's numbers in columns ``index`` (NaN where empty; seconds for a date or clock time in a column of
    ``times``); a short or long row, or a non-numeric cell among them, is refused naming its line."""
    source.check_width(line, cells, len(header))
    values = [source.number(cells[column]) for column in index]
    for k, column in enumerate(index):
        if values[k] is None and column in times and (clock := times[column](cells[column])) is not None:
            values[k] = clock[0]
    if None in values:
        column = index[values.index(None)]
        hint = decimal_comma_hint([cells[column]]) or clock_time_hint([cells[column]])
        if not hint and len(index) == len(header):
            hint = "; a column of text (notes, labels) is left unread when data.channel_columns lists the channels"
        raise SfmnetError(
            f"{source.path} line {line} has a non-numeric cell ('{cells[column]}' in column {header[column]}): "
            f"every cell must be a number{hint}"
        )
    return values
