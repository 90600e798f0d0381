"""Row files as the models see them: where the rows lie on disk, and the blocks a pass serves (method §11)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from sfmnet.errors import SfmnetError
from sfmnet.linalg.frame import MirrorHint
from sfmnet.linalg.moments import Moments
from sfmnet.preprocessing.chunked_rows import CHUNK_ROWS
from sfmnet.preprocessing.far_cells import FAR_CELLS_REMEDY, far_cell_limits_chunked, far_cells_what

SHIFT_ROWS = 10_000
BLOCK_BYTES = 32 * 2**20


# Beyond this no sensor reads: a corrupt cell or a unit slip, which would swamp every other row.
IMPLAUSIBLE = 1e15


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
    if np.issubdtype(dtype, np.complexfloating):
        raise SfmnetError(f"{path} holds complex numbers: save real values (e.g. the real part or the magnitude)")
    if fortran_order or len(shape) != 2:
        raise SfmnetError(
            f"{path} holds {'a Fortran-order' if fortran_order else 'an'} array of shape {shape}: "
            "save a C-order 2-D array (np.save of a row matrix)"
        )
    expected = offset + shape[0] * shape[1] * dtype.itemsize
    size = path.stat().st_size
    if size < expected:
        raise SfmnetError(
            f"{path} is cut off: its header says {shape[0]} x {shape[1]} {dtype} values ({expected} bytes) but the file "
            f"has {size} bytes: copy or save it again"
        )
    return NpyLayout(path, offset, dtype, shape)


def mapped_rows(layout: NpyLayout, start: int, count: int) -> np.memmap:
    """Rows ``[start, start + count)`` through a memory map of just those rows."""
    p = layout.shape[1]
    return np.memmap(
        layout.path, dtype=layout.dtype, mode="r", shape=(count, p), offset=layout.offset + start * p * layout.dtype.itemsize
    )


class RowBlock(NamedTuple):
    """One training step's rows: ``start`` (the first row's index in the file), ``readings``
    (``b x p`` float64, the channel columns minus the data's shift) and ``loads`` (``b x n``
    float64, NaN where unknown; ``b x 0`` without load columns)."""

    start: int
    readings: torch.Tensor
    loads: torch.Tensor


@dataclass
class RowData:
    """A row matrix on disk: where it lies (``layout``, ``f x columns``), the ``channels`` the statistics
    are of (``p`` names, at ``channel_index``), their ``shift`` (``p``, the first rows' mean) and any
    ``load_columns`` (at ``load_index``). The loader's blocks arrive as :class:`RowBlock`.
    """

    layout: NpyLayout
    channels: list[str]
    channel_index: list[int]
    shift: torch.Tensor
    load_columns: list[str] = field(default_factory=list)
    load_index: list[int] = field(default_factory=list)
    # Where a row is in the user's file, for messages (the reader's: a CSV's rows lie in a converted .npy).
    place: Callable[[int], str] | None = None

    recording = "rows"

    def row_place(self, row: int) -> str:
        """Data row ``row`` (0-based) as the user finds it: ``line 17 of x.csv``, or ``data row 15 (0-based) of x.npy``."""
        return self.place(row) if self.place is not None else f"data row {row} (0-based) of {self.layout.path}"

    @property
    def rows(self) -> int:
        return self.layout.shape[0]

    @property
    def recordings(self) -> dict[str, RowData]:
        return {self.recording: self}

    def first_bad_row(self) -> int | None:
        """The first row with a NaN, empty, infinite or implausible (beyond :data:`IMPLAUSIBLE`) channel cell (a scan)."""
        block = max(1, BLOCK_BYTES // (8 * self.layout.shape[1]))
        for start in range(0, self.rows, block):
            values = np.asarray(mapped_rows(self.layout, start, min(block, self.rows - start))[:, self.channel_index])
            bad = ~(np.abs(values) <= IMPLAUSIBLE).all(axis=1)
            if bad.any():
                return start + int(np.argmax(bad))
        return None

    def refuse_bad_rows(self) -> None:
        """Refuse the first NaN, empty, infinite or implausible channel cell, naming its row (a scan of the file)."""
        row = self.first_bad_row()
        if row is not None:
            raise SfmnetError(
                f"{self.row_place(row)} has a NaN, empty or infinite channel cell, or one beyond "
                f"{IMPLAUSIBLE:.0e} (a corrupt cell or a unit slip): repair or drop that row"
            )

    def refuse_far_cells(self) -> None:
        """Refuse the channels' far cells (:mod:`sfmnet.preprocessing.far_cells`), naming the first three: a pass of the
        file, and a second where there are any. Every cell finite (:meth:`refuse_bad_rows` first)."""
        channels = MappedColumns(self.layout, self.channel_index)
        above, below = far_cell_limits_chunked(channels)
        if np.isinf(above).all() and np.isinf(below).all():
            return
        count, first = 0, []
        for start in range(0, self.rows, CHUNK_ROWS):
            values = channels[start : start + CHUNK_ROWS]
            rows, columns = np.nonzero((values >= above) | (values <= below))
            count += len(rows)
            first += [
                f"{self.row_place(start + int(r))} column {self.channels[c]} ({values[r, c]:.3g})"
                for r, c in zip(rows[: 3 - len(first)], columns[: 3 - len(first)])
            ]
        raise SfmnetError(
            f"{count} {far_cells_what('reading', count)} (first: {', '.join(first)}): {FAR_CELLS_REMEDY}"
        )

    def require_plausible(self, moments: Moments) -> None:
        """:meth:`refuse_bad_rows` where such a cell shows in the sums ``moments`` it poisons (the scan on suspicion only)."""
        if not bool(torch.isfinite(moments.cross).all()) or float(moments.cross.diagonal().max()) > IMPLAUSIBLE**2:
            self.refuse_bad_rows()


class MappedColumns:
    """Some columns of a ``.npy`` row file, sliced by rows through a memory map of just those rows (float64, times ``scale``).

    ``vector``: one column read as ``f`` values (a time column), else ``f x c``: what the static-interval detector takes.
    """

    def __init__(self, layout: NpyLayout, index: list[int], scale: float = 1.0, vector: bool = False) -> None:
        self.layout = layout
        self.index = index
        self.scale = scale
        self.vector = vector
        self.shape = (layout.shape[0],) if vector else (layout.shape[0], len(index))

    def __getitem__(self, rows: slice) -> np.ndarray:
        start, stop, _ = rows.indices(self.layout.shape[0])
        values = np.asarray(mapped_rows(self.layout, start, stop - start)[:, self.index], dtype=np.float64)
        values = values[:, 0] if self.vector else values
        return values * self.scale if self.scale != 1.0 else values


class IntervalSums(NamedTuple):
    """Sums over each static interval's rows of a stream, every row once (``k`` intervals, ``p`` channels): what the
    pose checks need without the rows in memory.

    Attributes:
        counts: ``k``, the rows.
        readings: ``k x p``, ``sum z`` (raw units, less the stream's shift).
        squares: ``k``, ``sum |z|^2`` of the same.
        residuals: ``k x p``, ``sum (z - m S - o)`` at the fit.
        dof: ``k``, the rows' residual degrees of freedom summed (``p`` a known row, ``p - d + 1`` an unknown one).
    """

    counts: torch.Tensor
    readings: torch.Tensor
    squares: torch.Tensor
    residuals: torch.Tensor
    dof: torch.Tensor


@dataclass
class StreamedRecording(RowData):
    """A row file of raw channels and load columns (NaN where the load is unknown), every row the same mass.

    Attributes (beyond :class:`RowData`):
        magnitude: ``F``, the calibration load's magnitude (load units).
        known_load_tolerance: relative disagreement allowed between a known load's magnitude and ``F``.
        mirror_hint: which side of the mirror the row ``hint_reading`` lies on (``sample`` unused), or None.
        hint_reading: ``p`` raw readings of the mirror hint's row.
        keep: ``f`` bool, the rows fitted (the static intervals of a continuous recording); None: all.
        intervals: ``k x 2`` int64, those static intervals' half-open row ranges, in order (the poses the rows were
            held in, for the goodness of fit); None without them.
    """

    magnitude: float = math.nan
    known_load_tolerance: float = 0.02
    mirror_hint: MirrorHint | None = None
    hint_reading: torch.Tensor | None = None
    keep: np.ndarray | None = None
    intervals: np.ndarray | None = None
    axes: list[str] = field(default_factory=list)

    recording = "streamed_rotation"

    @property
    def rank(self) -> int:
        return len(self.axes)
