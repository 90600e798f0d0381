"""What a calibration data module hands to the models: recordings, evaluation sweeps, and (simulated) truth."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
import torch

from sfmnet.errors import SfmnetError
from sfmnet.linalg.frame import MirrorHint
from sfmnet.preprocessing.revisited_poses import RevisitedPoses
from sfmnet.preprocessing.row_repeats import RowRepeats
from sfmnet.preprocessing.static_intervals import StaticIntervals
from sfmnet.preprocessing.stuck_channels import StuckReading


@dataclass(frozen=True)
class CalibrationRecording:
    """Raw readings, with the load of each row where it is known.

    A row whose load is unknown carries a known mass in an unknown orientation: its load is
    ``u D_c`` with ``u`` an unknown unit direction (``d``) and ``D_c`` (``d x n``) the
    direction map of its mass configuration ``c``. For force sensors ``D = F I`` (one
    configuration, the constant magnitude ``F``); for a six-axis sensor ``D_c = m_c g [I, [r_c]x^T]``
    turns the gravity direction into the wrench of mass ``m_c`` at centre of mass ``r_c`` (method §6).

    Attributes:
        readings: ``f x p`` raw units.
        loads: ``f x n`` load units; NaN on the rows whose load is unknown.
        magnitude: ``F``, the constant load magnitude of the unknown rows (load units).
        mirror_hint: the bit that picks the frame's mirror side when only ``n - 1`` loads are known.
        true_loads: ``f x n``, the loads really applied, where known (simulations, reference data).
        configuration: ``f`` (long), each row's mass configuration; None: all one.
        direction_maps: ``C x d x n``, ``D_c`` per configuration; None: ``F I``.
        groups: ``f`` (long), e.g. the pose each row was recorded in, for leave-one-group-out.
    """

    readings: torch.Tensor
    loads: torch.Tensor
    magnitude: float = float("nan")
    mirror_hint: MirrorHint | None = None
    true_loads: torch.Tensor | None = None
    configuration: torch.Tensor | None = None
    direction_maps: torch.Tensor | None = None
    groups: torch.Tensor | None = None

    @property
    def known(self) -> torch.Tensor:
        """Boolean ``f``: rows whose load is known."""
        return ~torch.isnan(self.loads).any(dim=1)

    @property
    def rank(self) -> int:
        return self.loads.shape[1]

    @property
    def maps(self) -> torch.Tensor:
        """``C x d x n``: :attr:`direction_maps`, or ``F I`` for one constant-magnitude mass."""
        if self.direction_maps is not None:
            return self.direction_maps
        return self.magnitude * torch.eye(self.rank, dtype=self.readings.dtype)[None]

    @property
    def row_configuration(self) -> torch.Tensor:
        """``f`` (long): :attr:`configuration`, or zeros."""
        if self.configuration is not None:
            return self.configuration
        return torch.zeros(len(self.readings), dtype=torch.long)

    @cached_property
    def same_load_groups(self) -> torch.Tensor | None:
        """``f`` (long): :attr:`groups` split so that each holds rows of one load, or None without groups.

        One pose under another mass configuration, or with another known load, is another load; the
        unknown rows of one group share one orientation (a static interval, a pose). Computed once (a sort of
        every row; the fit, its error bars and its checks each ask).
        """
        if self.groups is None:
            return None
        configuration = self.row_configuration.to(self.loads.dtype)
        # NaN (unknown) loads compare equal to each other this way.
        loads = torch.nan_to_num(self.loads, nan=math.inf)
        key = torch.cat([self.groups[:, None].to(loads.dtype), configuration[:, None], loads], dim=1)
        return torch.unique(key, dim=0, return_inverse=True)[1]

    @property
    def distinct_known_loads(self) -> int:
        """How many different known loads the rows hold (each gives ``n`` equations of the shape)."""
        return len(torch.unique(self.loads[self.known], dim=0))

    def whole_batch(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Every row as one batch, as the data module deals them: row indices ``f``, readings ``f x p``, loads ``f x n``."""
        return torch.arange(len(self.readings)), self.readings, self.loads

    def without(self, rows: torch.Tensor) -> CalibrationRecording:
        """This recording with the boolean ``f`` mask ``rows`` removed (the mirror hint dropped)."""
        keep = ~rows

        def take(value: torch.Tensor | None) -> torch.Tensor | None:
            return None if value is None else value[keep]

        return replace(
            self,
            readings=self.readings[keep],
            loads=self.loads[keep],
            true_loads=take(self.true_loads),
            configuration=take(self.configuration),
            groups=take(self.groups),
            mirror_hint=None,
        )


@dataclass(frozen=True)
class EvaluationSweep:
    """A test mass turned through a full rotation (paper section 5, method §7).

    Attributes:
        magnitude: the true load magnitude (load units).
        readings: ``k x p``, in the order of the rotation (so smoothing along it makes sense).
        loads: ``k x n``, the true loads.
    """

    magnitude: float
    readings: torch.Tensor
    loads: torch.Tensor


@dataclass(frozen=True)
class SensorTruth:
    """The simulated sensor's true calibration, for error metrics."""

    matrix: torch.Tensor
    offset: torch.Tensor


@dataclass
class CalibrationData:
    """Everything a calibration run reads.

    Attributes:
        recordings: by name: ``"rotation"`` (unknown orientations plus a few known loads) and,
            where available, ``"least_squares"`` (every load known).
        evaluations: test sweeps for the paper's accuracy and precision protocol.
        test: held-out readings with their true loads (``true_loads``), where available.
        channels: the ``p`` raw channel names.
        axes: the ``n`` load axis names.
        load_unit: e.g. ``"gf"`` or ``"N"``.
        truth: the true calibration, where the data is simulated.
        static_intervals: where a continuous recording was static (its other rows are left out of
            the recordings), or None where every row was taken as static.
        warnings: what the reader noticed in the file (e.g. a channel that looks like a timestamp).
        row_repeats: how often the fitted rows repeat the row before (within the static intervals where a stream's
            were found, else over every row), or None where not counted.
        stuck_readings: channels stuck at one value or clipped at their range while the others moved, over rows the fit
            uses.
        revisited_poses: how far apart the holds of poses held more than once are (a group column's labels), or None
            where no pose was held twice.
    """

    recordings: dict[str, CalibrationRecording]
    channels: list[str]
    axes: list[str]
    load_unit: str
    evaluations: list[EvaluationSweep] = field(default_factory=list)
    test: CalibrationRecording | None = None
    truth: SensorTruth | None = None
    static_intervals: StaticIntervals | None = None
    warnings: list[str] = field(default_factory=list)
    row_repeats: RowRepeats | None = None
    stuck_readings: list[StuckReading] = field(default_factory=list)
    revisited_poses: RevisitedPoses | None = None

    def without_group(self, group: int) -> CalibrationData:
        """The data with every recording's rows of ``group`` removed (for leave-one-group-out)."""
        recordings = {}
        for name, recording in self.recordings.items():
            if recording.groups is None:
                raise ValueError(f"recording {name} has no groups")
            recordings[name] = recording.without(recording.groups == group)
        return replace(self, recordings=recordings, evaluations=[], test=None)


def empty_load_columns(load_columns: list[str], path: str) -> str:
    """The message for load columns named but empty on every row: the frame would be arbitrary, labelled as theirs."""
    return (
        f"the load columns {', '.join(load_columns)} are empty on every row of {path}, so no known load fixes the frame: "
        "fill them on the known-load rows or, with no known load (the frame arbitrary), set data.load_columns=[] and "
        "name the axes with data.axes=[...]"
    )


def load_unit_for(load_unit: str | None, axes: int) -> str:
    """The unit written beside every load figure: ``load_unit``, checked against the ``axes`` load axes.

    Six axes are forces and torques, reported apart, so their unit names both, force then torque
    (``"N, N m"``); None: ``"N, N m"`` for six axes, ``"N"`` otherwise.
    """
    if load_unit is None:
        return "N, N m" if axes == 6 else "N"
    force_unit, _, torque_unit = str(load_unit).partition(", ")
    if axes == 6 and not (force_unit and torque_unit):
        raise SfmnetError(
            f"data.load_unit={load_unit!r} names one unit, but a six-axis sensor's loads are forces and torques: "
            "give both, force then torque, e.g. data.load_unit='N, N m' (the default)"
        )
    if axes != 6 and torque_unit:
        raise SfmnetError(
            f"data.load_unit={load_unit!r} names a force and a torque unit, but the sensor has {axes} load axes, "
            "all forces: give one unit, e.g. data.load_unit=N"
        )
    return str(load_unit)


def first_torque_mismatch(wrenches: np.ndarray, maps: np.ndarray, tolerance: float) -> tuple[int, np.ndarray] | None:
    """The first known wrench (``k x 6``, force then torque) whose torque is off ``r x F`` (its force about its row's
    centre of mass), with that torque; None where all match.

    ``maps`` (``k x 3 x 6``) is each row's :func:`~sfmnet.linalg.wrench.wrench_map` ``m g [I, [r]x^T]``, so
    ``r x F = F [r]x^T``. Off means by more than ``tolerance`` of ``m g L``, ``L`` the largest ``|r|`` of the rows (a
    torque's size needs a lever: a centre of mass on the sensor's origin expects none).
    """
    weight = maps[:, 0, 0]
    expected = np.einsum("ki,kij->kj", wrenches[:, :3], maps[:, :, 3:]) / weight[:, None]
    lever = np.linalg.norm(maps[:, :, 3:], axis=(1, 2)) / (np.sqrt(2) * weight)
    off = np.linalg.norm(wrenches[:, 3:] - expected, axis=1) > tolerance * weight * lever.max()
    return (int(np.argmax(off)), expected[np.argmax(off)]) if off.any() and lever.max() > 0 else None


def first_magnitude_mismatch(forces: np.ndarray, magnitudes: np.ndarray, tolerance: float) -> int | None:
    """The first of the known ``forces`` (``k x 3``) whose norm is off its ``magnitudes`` (``k``) by more than ``tolerance``."""
    off = np.abs(np.linalg.norm(forces, axis=1) / magnitudes - 1) > tolerance
    return int(np.argmax(off)) if off.any() else None
