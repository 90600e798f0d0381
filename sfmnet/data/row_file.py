"""Rows of numbers too many to hold in memory: a ``.npy`` read through a memory map, block by block (NOTES 11).

A CSV is converted once to ``.npy`` beside a cache key of its size and modification time, so
later runs stream it like any ``.npy``. Blocks are shared out between processes by the data
module itself (block ``i`` to rank ``i mod world``), never by a distributed sampler, which pads
with repeated samples: ranks left short get empty blocks instead, so every row is counted
exactly once and every rank takes the same number of steps (the strategy's collectives pair up).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import lightning as L
import numpy as np
import torch
import torch.distributed as dist
from torch.utils.data import DataLoader, Dataset, Sampler

from sfmnet.errors import SfmnetError

SHIFT_ROWS = 10_000
BLOCK_BYTES = 32 * 2**20


@dataclass(frozen=True)
class NpyLayout:
    """Where a C-order ``.npy``'s rows lie in its file."""

    path: Path
    offset: int
    dtype: np.dtype
    shape: tuple[int, int]


def npy_layout(path: Path) -> NpyLayout:
    with path.open("rb") as stream:
        version = np.lib.format.read_magic(stream)
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, fortran_order, dtype = read_header(stream)
        offset = stream.tell()
    if fortran_order or len(shape) != 2:
        raise SfmnetError(
            f"{path} holds {'a Fortran-order' if fortran_order else 'an'} array of shape {shape}: "
            "save a C-order 2-D array (np.save of a row matrix)"
        )
    return NpyLayout(path, offset, dtype, shape)


def mapped_rows(layout: NpyLayout, start: int, count: int) -> np.memmap:
    """Rows ``[start, start + count)`` through a memory map of just those rows."""
    p = layout.shape[1]
    return np.memmap(
        layout.path, dtype=layout.dtype, mode="r", shape=(count, p), offset=layout.offset + start * p * layout.dtype.itemsize
    )


@dataclass
class RowData:
    """A row matrix on disk: where it lies (``layout``, ``f x p``), ``columns``, and ``shift`` (``p``, first rows' mean).

    The loader's blocks arrive minus ``shift`` (see :class:`BlockDataset`).
    """

    layout: NpyLayout
    columns: list[str]
    shift: torch.Tensor

    @property
    def recordings(self) -> dict[str, RowData]:
        return {"rows": self}



class BlockDataset(Dataset):
    """Block ``i`` is rows ``[i B, (i + 1) B)`` minus ``shift``, float64, read through its own memory map.

    Mapping one block at a time (and dropping the map after the copy) keeps the resident
    memory to about a few blocks, whatever the file's size. Conversion and shift are one pass
    into a ring of reused buffers (no fresh allocation per block); the ring is longer than
    the trainer's one-batch prefetch, so a block is consumed before its buffer is refilled.
    """

    RING = 3

    def __init__(self, layout: NpyLayout, block_rows: int, shift: np.ndarray) -> None:
        self.layout = layout
        self.block_rows = block_rows
        self.shift = shift
        self.buffers: list[np.ndarray] = []
        self.turn = 0

    def __len__(self) -> int:
        return math.ceil(self.layout.shape[0] / self.block_rows)

    def __getitem__(self, index: int) -> torch.Tensor:
        """Block ``index``; ``-1`` is an empty block (padding for a rank with fewer blocks)."""
        rows, p = self.layout.shape
        if index < 0:
            return torch.zeros(0, p, dtype=torch.float64)
        start = index * self.block_rows
        count = min(self.block_rows, rows - start)
        mapped = mapped_rows(self.layout, start, count)
        if len(self.buffers) < self.RING:
            self.buffers.append(np.empty((self.block_rows, p)))
        buffer = self.buffers[self.turn % self.RING][:count]
        self.turn += 1
        np.subtract(mapped, self.shift, out=buffer, dtype=np.float64)
        del mapped
        return torch.from_numpy(buffer)


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
    """Serves a row file as ``{"rows": loader of float64 blocks}``, one pass per epoch.

    Args:
        path: ``.npy`` (any numeric dtype; read through a memory map) or ``.csv`` (header row;
            converted once to ``.npy`` in ``cache_dir``).
        columns: names for a ``.npy``'s columns (default ``c0, c1, ...``).
        block_rows: rows per block (default: about 32 MB of float64 per block).
        cache_dir: where CSV conversions live (default: ``.sfmnet-cache`` beside the CSV).
    """

    recording = "rows"

    def __init__(
        self, path: str, columns: list[str] | None = None, block_rows: int | None = None, cache_dir: str | None = None
    ) -> None:
        super().__init__()
        self.path = Path(path)
        self.columns = columns
        self.block_rows = block_rows
        self.cache_dir = Path(cache_dir) if cache_dir else None
        self.data: RowData | None = None

    def setup(self, stage: str | None = None) -> None:
        if self.data is not None:
            return
        if not self.path.is_file():
            raise SfmnetError(f"{self.path} is not a file: check data.path (a .npy or .csv of rows)")
        source = self.path if self.path.suffix == ".npy" else csv_to_npy(self.path, self.cache_dir)
        try:
            layout = npy_layout(source)
        except (ValueError, OSError) as error:
            raise SfmnetError(f"{source} cannot be read as .npy: {error}") from None
        rows, p = layout.shape
        if rows < 2 or not np.issubdtype(layout.dtype, np.number):
            raise SfmnetError(f"{source} holds a {layout.dtype} array of shape {layout.shape}: give a 2-D numeric array, one row per sample")
        columns = self.columns or (csv_header(self.path) if self.path.suffix != ".npy" else [f"c{i}" for i in range(p)])
        if len(columns) != p:
            raise SfmnetError(f"{len(columns)} names in data.columns for {p} columns in {self.path}")
        shift = torch.from_numpy(np.asarray(mapped_rows(layout, 0, min(rows, SHIFT_ROWS)), dtype=np.float64).mean(axis=0))
        if not torch.isfinite(shift).all():
            raise SfmnetError(f"{self.path} has NaN or infinite values in its first rows: repair the file")
        self.data = RowData(layout=layout, columns=list(columns), shift=shift)

    def train_dataloader(self) -> dict[str, DataLoader]:
        assert self.data is not None, "setup() runs before the loaders"
        layout = self.data.layout
        rows = self.block_rows or max(1, BLOCK_BYTES // (8 * layout.shape[1]))
        dataset = BlockDataset(layout, rows, self.data.shift.numpy())
        return {self.recording: DataLoader(dataset, batch_size=None, sampler=ShardSampler(len(dataset)))}


def csv_header(path: Path) -> list[str]:
    with path.open(newline="") as stream:
        return [name.strip() for name in next(csv.reader(stream))]


def csv_to_npy(path: Path, cache_dir: Path | None, chunk_rows: int = 100_000) -> Path:
    """Convert a numeric CSV (header row) to float64 ``.npy`` once; reuse it while the CSV's size and mtime match."""
    stat = path.stat()
    cache = (cache_dir or path.parent / ".sfmnet-cache") / f"{path.stem}-{stat.st_size}-{stat.st_mtime_ns}.npy"
    if cache.is_file():
        return cache
    header = csv_header(path)
    with path.open(newline="") as stream:
        rows = sum(1 for line in stream if line.strip()) - 1
    if rows < 2:
        raise SfmnetError(f"{path} has {max(rows, 0)} data rows: give a CSV with a header and at least two rows")
    cache.parent.mkdir(parents=True, exist_ok=True)
    partial = cache.with_name(f".{cache.name}.partial")
    out = np.lib.format.open_memmap(partial, mode="w+", dtype=np.float64, shape=(rows, len(header)))
    with path.open(newline="") as stream:
        reader = csv.reader(stream)
        next(reader)
        written, chunk = 0, []
        for line, row in enumerate(reader, start=2):
            if not any(cell.strip() for cell in row):
                continue
            try:
                chunk.append([float(cell) for cell in row])
            except ValueError:
                partial.unlink(missing_ok=True)
                raise SfmnetError(f"{path} line {line} has a non-numeric cell: every cell must be a number") from None
            if len(chunk[-1]) != len(header):
                partial.unlink(missing_ok=True)
                raise SfmnetError(f"{path} line {line} has {len(chunk[-1])} cells but the header has {len(header)}")
            if len(chunk) == chunk_rows:
                out[written : written + len(chunk)] = chunk
                written, chunk = written + len(chunk), []
        out[written : written + len(chunk)] = chunk
    out.flush()
    del out
    partial.replace(cache)
    return cache
