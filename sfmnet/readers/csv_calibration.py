"""A calibration session recorded in a file: raw channels, and loads on the rows where they are known."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from sfmnet.data.calibration_datamodule import CalibrationDataModule
from sfmnet.data.recording import (
    CalibrationData, CalibrationRecording, empty_load_columns, first_magnitude_mismatch, first_torque_mismatch, load_unit_for,
)
from sfmnet.preprocessing.revisited_poses import RevisitedPoses, hold_ids, holds_per_pose, revisited_poses
from sfmnet.preprocessing.row_repeats import row_repeats
from sfmnet.preprocessing.static_intervals import StaticIntervals
from sfmnet.preprocessing.stuck_channels import stuck_readings
from sfmnet.readers.clock_times import all_clock_times
from sfmnet.readers.static_rows import fitted_rows, intervals_needed, static_settings
from sfmnet.readers.table_file import (
    Table, check_far_cells, check_finite, read_table, refuse_cells, refuse_columns_named_twice,
)
from sfmnet.errors import SfmnetError
from sfmnet.linalg.channel_dependence import dependent_channels, dependent_channels_message
from sfmnet.linalg.frame import MirrorHint
from sfmnet.linalg.wrench import STANDARD_GRAVITY, wrench_map


class CsvCalibrationDataModule(CalibrationDataModule):
    """One mass turned through unknown orientations, from a CSV (or ``.npy``/``.npz``) file.

    One row per sample. The load columns are filled only on rows whose load is known (the
    few reference loads) and empty elsewhere; every row is taken with the same load
    magnitude, the calibration mass. For a six-axis sensor (method §6) a configuration column
    says which mass configuration each row holds, each with its mass and centre of mass.

    Args:
        path: the file (for messages only when ``table`` is given).
        load_columns: the ``n`` load columns, e.g. ``[fx, fy, fz]``; their names become the axes.
            Empty (no known loads): give ``axes``; the frame is then arbitrary (correct up to an
            orthogonal transform, which leaves every load's magnitude right).
        axes: the ``n`` load axis names when ``load_columns`` is empty (e.g. ``[x, y, z]``).
        channel_columns: raw channel columns (default: every other numeric column but ``time_column``).
        time_column: the rows' time (not a channel); with it the static intervals are found.
        columns: names of a ``.npy`` file's columns.
        magnitude: the load magnitude (load units); or give ``mass``.
        mass: the calibration mass in kg; the magnitude is ``mass * 9.80665`` N.
        mirror_hint: ``{row: <data row, 0-based>, axis: <load column>, sign: <+1|-1>}``, the rough
            sign of one unknown row's load component; needed with ``n - 1`` known loads.
        known_load_tolerance: relative disagreement allowed between a known load's magnitude
            and ``magnitude`` (the known loads are the same mass, so they must agree).
        load_unit: for reports, e.g. ``N``; None: ``N``, or ``N, N m`` for six axes (force, then torque).
        configuration_column: six axes: the column naming each row's mass configuration.
        configurations: six axes: ``{<id>: {mass: <kg>, centre_of_mass: [x, y, z] (m, sensor frame)}}``
            for every id in the configuration column; then ``magnitude``/``mass`` are not used.
        group_column: a column of the pose each row was recorded in: its rows share one direction
            (``model.tie_directions``), and leave-one-group-out evaluation; an empty cell is a pose of its own
            (:func:`pose_labels`); a pose held more than once is checked for drift (:func:`pose_revisits`).
        gravity: m/s^2, for ``mass`` and ``configurations``.
        static_intervals: leave out the rows in motion of a continuous recording
            (:mod:`sfmnet.readers.static_rows`): None: with a ``time_column``; True: also without
            one (row order); False: fit every row.
        held_out_intervals: fit on every other static interval (or group) and keep the rest as
            ``test``, scored by how far each held-out interval's mean load is from ``magnitude``.
        time_unit: ``time_column``'s unit: ``s``, ``ms``, ``us`` or ``ns``.
        static: the detector's settings (``window``, ``min_duration``, ``threshold``, ``noise_quantile``).
        table: the columns already in memory (:func:`sfmnet.calibrate`); else ``path`` is read.
    """

    def __init__(
        self,
        path: str,
        load_columns: list[str],
        axes: list[str] | None = None,
        channel_columns: list[str] | None = None,
        time_column: str | None = None,
        columns: list[str] | None = None,
        magnitude: float | None = None,
        mass: float | None = None,
        mirror_hint: dict | None = None,
        known_load_tolerance: float = 0.02,
        load_unit: str | None = None,
        configuration_column: str | None = None,
        configurations: dict | None = None,
        group_column: str | None = None,
        gravity: float = STANDARD_GRAVITY,
        batch_size: int | None = None,
        static_intervals: bool | None = None,
        time_unit: str = "s",
        static: dict | None = None,
        held_out_intervals: bool = False,
        table: Table | None = None,
    ) -> None:
        super().__init__(batch_size=batch_size)
        self.path = Path(path)
        self.load_columns = list(load_columns)
        self.axes = load_axes(self.load_columns, axes)
        self.channel_columns = list(channel_columns) if channel_columns else None
        self.time_column = time_column
        self.columns = columns
        self.magnitude = magnitude
        self.mass = mass
        self.mirror_hint = mirror_hint
        self.known_load_tolerance = known_load_tolerance
        self.load_unit = load_unit_for(load_unit, len(self.axes))
        self.configuration_column = configuration_column
        self.configurations = configurations
        self.group_column = group_column
        self.gravity = gravity
        self.held_out_intervals = held_out_intervals
        self.static = static_settings(static_intervals, time_column, time_unit, static)
        self.table = table

    def build(self) -> CalibrationData:
        roles = self.named_columns()
        refuse_columns_named_twice(roles)
        table = self.table if self.table is not None else read_table(self.path, self.columns)
        for role, names in roles.items():
            # A time column may hold clock times, a pose column labels: each is read on its own below.
            if role not in ("time", "group"):
                table.require(names, role)
        # Read (so checked) even where static intervals are off, though only they use it.
        time = table.times(self.time_column, self.static.time_scale if self.static else 1.0) if self.time_column else None
        time = time if self.static is not None else None
        excluded = {*self.load_columns, *(c for c in (self.time_column, self.configuration_column, self.group_column) if c)}
        # Numeric columns with a few bad cells stay in, so their cells are reported, not skipped.
        candidates = [name for name in [*table.columns, *table.text] if name in table.columns or name in table.corrupt]
        channels = self.channel_columns or [name for name in candidates if name not in excluded]
        if len(channels) < len(self.axes):
            raise SfmnetError(
                f"{len(channels)} channel columns for {len(self.axes)} load axes: a calibration needs at "
                "least as many channels as axes; list them with data.channel_columns=[...]"
            )
        empty = [] if self.channel_columns else [n for n in channels if n in table.columns and np.isnan(table.columns[n]).all()]
        if empty:
            raise SfmnetError(
                f"{'columns' if len(empty) > 1 else 'column'} {', '.join(empty)} of {self.path} "
                f"{'are' if len(empty) > 1 else 'is'} empty on every row, so not a channel: list the channels "
                "with data.channel_columns=[...], or name the known loads' columns in data.load_columns"
            )
        readings = table.numeric(channels, "channel")
        check_finite(readings, channels, table, "reading")
        check_far_cells(readings, channels, table, "reading")
        if len(readings) < 2:
            # Else every channel reads as constant.
            raise SfmnetError(
                f"{self.path} has one data row: a calibration needs the readings of many orientations (dozens)"
            )
        # The range, not the standard deviation: that of a column of 1.234 is ~1e-13 in floating point, not 0.
        constant = [name for name, spread in zip(channels, np.ptp(readings, axis=0)) if spread == 0]
        if constant:
            raise SfmnetError(
                f"channel {', '.join(constant)} of {self.path} is constant: it carries no load information; "
                "leave it out with data.channel_columns=[...]"
            )
        loads = table.numeric(self.load_columns, "load") if self.load_columns else np.full((len(readings), len(self.axes)), np.nan)
        # An empty cell is an unknown load; an infinite one is a corrupt cell, not a missing one.
        refuse_cells(
            np.isinf(loads), loads, self.load_columns, table, "infinite load values", "give the load or leave its cells empty", True
        )
        partial = np.isnan(loads).any(axis=1) & ~np.isnan(loads).all(axis=1)
        if partial.any():
            raise SfmnetError(
                f"{self.path} {table.row_place(int(np.argmax(partial)))} gives only some of {', '.join(self.load_columns)}: "
                "fill every load column on a known row, or none"
            )
        if self.load_columns and np.isnan(loads).all():
            raise SfmnetError(empty_load_columns(self.load_columns, str(self.path)))
        # The rows of unknown load: where they span fewer dimensions than the load space, the fit says why.
        unknown = readings[np.isnan(loads).all(axis=1)]
        centred = torch.from_numpy(unknown - unknown.mean(axis=0))
        dependent = dependent_channels(centred.T @ centred, len(unknown), len(self.axes))
        if dependent:
            raise SfmnetError(dependent_channels_message([channels[k] for k in dependent], f" of {self.path}"))
        groups, labels, label_names = None, None, None
        if self.group_column:
            labels, label_names = pose_column(table, self.group_column)
        detection, keep = None, np.ones(len(readings), dtype=bool)
        if self.static is not None:
            detection = self.static.detect(readings, time, table.where)
            known = np.nonzero(~np.isnan(loads).any(axis=1))[0]
            keep = fitted_rows(
                detection, known, len(self.axes), table.where,
                check_count=not self.configuration_column,
            )
            if not detection.independent:
                groups = torch.from_numpy(detection.interval_of_rows() if labels is None else pose_labels(labels, detection))
        if labels is not None and groups is None:
            groups = torch.from_numpy(pose_labels(labels))
        revisits, unvisited = (
            (None, []) if labels is None else pose_revisits(readings, labels, keep, detection, time, label_names)
        )
        # Every row kept (no motion found, or no detection): views, not a copy of every column.
        rows = slice(None) if keep.all() else torch.from_numpy(keep)
        groups = None if groups is None else groups[rows]
        if self.configuration_column:
            configuration, maps = self.parse_configurations(table)
            self.check_known_magnitudes(loads[:, :3], (maps[:, 0, 0].numpy())[configuration.numpy()], table)
            self.check_known_torques(loads, maps.numpy()[configuration.numpy()], table)
            recording = CalibrationRecording(
                readings=torch.from_numpy(readings)[rows],
                loads=torch.from_numpy(loads)[rows],
                configuration=configuration[rows],
                direction_maps=maps,
                groups=groups,
            )
        else:
            if len(self.axes) == 6 and np.isnan(loads).any():
                raise six_axes_need_configurations()
            magnitude = calibration_magnitude(self.magnitude, self.mass, self.gravity)
            self.check_known_magnitudes(loads, np.full(len(loads), magnitude), table)
            recording = CalibrationRecording(
                readings=torch.from_numpy(readings)[rows],
                loads=torch.from_numpy(loads)[rows],
                magnitude=magnitude,
                mirror_hint=self.parse_mirror_hint(loads, keep),
                groups=groups,
            )
        test = None
        if self.held_out_intervals:
            recording, test = self.hold_out_alternate_groups(recording)
        return CalibrationData(
            recordings={"rotation": recording}, channels=channels, axes=self.axes, load_unit=self.load_unit,
            static_intervals=detection, test=test,
            warnings=[
                *monotonic_channel_warnings(readings, channels, "the file's rows"), *channel_scale_warnings(readings, channels),
                *self.unread_time_warnings(table),
                *unvisited, *self.hint_line_warnings(table),
            ],
            row_repeats=row_repeats(readings) if detection is None else detection.repeats,
            stuck_readings=[stuck for stuck in stuck_readings(readings, len(self.axes)) if keep[stuck.first : stuck.stop].any()],
            revisited_poses=revisits,
        )

    def hint_line_warnings(self, table: Table) -> list[str]:
        if self.mirror_hint is None or self.configuration_column or table.lines is None:
            return []
        row = int(self.mirror_hint["row"])
        return hint_row_warnings(row, int(table.lines[0]), int(table.lines[row]), table.where(row))

    def unread_time_warnings(self, table: Table) -> list[str]:
        """Without a time column, a note for each column of dates or clock times left unread: named, it would find the
        static intervals, and a continuous recording's rows in motion would be left out of the fit."""
        if self.time_column:
            return []
        return [
            f"column '{name}' holds dates or clock times and was not read: if the rows were recorded in one stream, "
            f"name it (data.time_column={name}) so that only the static intervals are fitted"
            for name, cells in table.cells.items()
            if name not in table.corrupt and all_clock_times(cells)
        ]

    def named_columns(self) -> dict[str, list[str]]:
        """Every column the config names, by role: each must be in the file (a misspelt time column would become a channel)."""
        roles = {"load": self.load_columns, "channel": self.channel_columns or []}
        for role, name in (("time", self.time_column), ("configuration", self.configuration_column), ("group", self.group_column)):
            if name:
                roles[role] = [name]
        return roles

    def hold_out_alternate_groups(self, recording: CalibrationRecording) -> tuple[CalibrationRecording, CalibrationRecording]:
        """Intervals (groups) 0, 2, 4, ... to fit, 1, 3, 5, ... held out (their known loads, if any, stay in the fit)."""
        if recording.groups is None or self.configuration_column or self.mirror_hint is not None:
            raise SfmnetError(
                "data.held_out_intervals needs static intervals (a time_column, with data.static_intervals not false) or "
                "a group_column, one mass, and no mirror_hint"
            )
        held_out = (recording.groups % 2 == 1) & ~recording.known
        fitted = recording.without(held_out)
        # Fitted on half the intervals, a session with enough for the unknowns may have too few: say so, not what a
        # fit of too few poses then trips over (a tester's 12 holds: "coverage 0.14 ... turned about one axis only").
        n = len(self.axes)
        known = int(len(torch.unique(fitted.loads[fitted.known], dim=0)))
        needed = intervals_needed(n, known)
        kept = len(torch.unique(fitted.groups))
        if kept < needed:
            total = len(torch.unique(recording.groups))
            raise SfmnetError(
                f"data.held_out_intervals fits every other interval (or group): {kept} of the {total} found, but a {n}-axis "
                f"calibration with offsets needs at least {needed}; record at least {2 * needed} poses held still, or fit "
                "them all (data.held_out_intervals=false)"
            )
        return fitted, recording.without(~held_out)

    def check_known_magnitudes(self, forces: np.ndarray, magnitudes: np.ndarray, table: Table) -> None:
        """Known (force) loads must have their row's mass's magnitude: they are that mass in a known pose."""
        known = np.nonzero(~np.isnan(forces).any(axis=1))[0]
        off = first_magnitude_mismatch(forces[known], magnitudes[known], self.known_load_tolerance)
        if off is not None:
            source = "its configuration's mass gives" if self.configuration_column else "data.magnitude is"
            raise SfmnetError(
                f"the known load on {table.where(int(known[off]))} has magnitude "
                f"{np.linalg.norm(forces[known[off]]):.6g} but {source} {magnitudes[known[off]]:.6g} "
                f"({100 * self.known_load_tolerance:g} % allowed): the known loads must be the calibration mass; "
                "check the load columns, units and masses"
            )

    def check_known_torques(self, wrenches: np.ndarray, maps: np.ndarray, table: Table) -> None:
        """Known torques must be their force's about the row's centre of mass: ``M = r x F``."""
        known = np.nonzero(~np.isnan(wrenches).any(axis=1))[0]
        off = first_torque_mismatch(wrenches[known], maps[known], self.known_load_tolerance)
        if off is not None:
            row, expected = int(known[off[0]]), off[1]
            torque_unit = self.load_unit.partition(", ")[2]
            raise SfmnetError(
                f"the known torque on {table.where(row)} is ({', '.join(f'{v:.4g}' for v in wrenches[row, 3:])}) "
                f"{torque_unit} but its configuration's centre of mass puts its force at r x F = "
                f"({', '.join(f'{v:.4g}' for v in expected)}) {torque_unit}: check that the torque columns are in N m, "
                "the centres of mass in m in the sensor's frame, and the load columns force then torque"
            )

    def parse_configurations(self, table: Table) -> tuple[torch.Tensor, torch.Tensor]:
        """Each row's configuration index (``f``) and the ``C x 3 x 6`` wrench maps (method §6)."""
        if len(self.load_columns) != 6:
            raise SfmnetError(
                f"data.configuration_column is for six-axis sensors: give six load_columns (force, then torque), "
                f"not {len(self.load_columns)}"
            )
        ids = table.numeric([self.configuration_column], "configuration")[:, 0]
        given = {float(key): value for key, value in (self.configurations or {}).items()}
        missing = sorted(set(np.unique(ids)) - set(given))
        if missing:
            raise SfmnetError(
                f"configuration {missing[0]:g} of column '{self.configuration_column}' has no entry in "
                "data.configurations: give {<id>: {mass: <kg>, centre_of_mass: [x, y, z]}} for every configuration"
            )
        used = sorted(set(np.unique(ids)))
        maps = []
        for key in used:
            entry = dict(given[key])
            if set(entry) != {"mass", "centre_of_mass"} or len(entry["centre_of_mass"]) != 3:
                raise SfmnetError(
                    f"data.configurations[{key:g}] needs exactly mass (kg) and centre_of_mass ([x, y, z], m)"
                )
            maps.append(wrench_map(float(entry["mass"]), torch.tensor(entry["centre_of_mass"], dtype=torch.float64), self.gravity))
        configuration = torch.from_numpy(np.searchsorted(np.array(used), ids))
        return configuration, torch.stack(maps)

    def parse_mirror_hint(self, loads: np.ndarray, keep: np.ndarray) -> MirrorHint | None:
        """The hint on data row ``row``, as the index of its sample among the fitted (``keep``) unknown rows."""
        if self.mirror_hint is None:
            return None
        row, axis, sign = mirror_hint_fields(self.mirror_hint, self.load_columns)
        unknown = np.isnan(loads).any(axis=1) & keep
        if not 0 <= row < len(loads) or not unknown[row]:
            raise SfmnetError(
                f"data.mirror_hint.row {row} must be a data row (0-based) whose load is unknown, in a static interval"
            )
        return MirrorHint(sample=int(unknown[:row].sum()), axis=axis, sign=sign, axis_name=self.load_columns[axis])


def pose_column(table: Table, name: str) -> tuple[np.ndarray, list[str] | None]:
    """A pose column's ``f`` labels as numbers (NaN where empty: a row of a pose of its own), and where the file labels
    poses with text (``A``, ``1-0``; among numbers too) the text of each number (0, 1, ...), in order of first
    appearance; else None."""
    if name in table.columns:
        return table.columns[name], None
    cells = table.categorical(name, "group")
    names: dict[str, int] = {}
    labels = np.array([math.nan if cell == "" else names.setdefault(cell, len(names)) for cell in cells], dtype=np.float64)
    return labels, list(names)


def pose_revisits(
    readings: np.ndarray, labels: np.ndarray, keep: np.ndarray, detection: StaticIntervals | None, time: np.ndarray | None,
    label_names: list[str] | None = None,
) -> tuple[RevisitedPoses | None, list[str]]:
    """:func:`~sfmnet.preprocessing.revisited_poses.revisited_poses` of the rows fitted (``keep``): a hold is a run of
    rows with one pose label, within one static interval where a stream was split into them. And a note where a pose
    labelled in several runs of rows kept fewer than two holds (a revisit too short for a static interval), so the
    check a user arranged for is not skipped in silence."""
    intervals = None if detection is None or detection.independent else detection.interval_of_rows()[keep]
    holds = hold_ids(labels[keep], intervals)
    revisits = revisited_poses(readings[keep], labels[keep], holds, None if time is None else time[keep])
    if revisits is not None:
        # The rows of the file, not of the rows kept, so that a message's row can be found in it; the label as written.
        revisits = replace(
            revisits, worst_starts=np.flatnonzero(keep)[revisits.worst_starts].tolist(),
            worst_pose=revisits.worst_pose if label_names is None else label_names[int(revisits.worst_pose)],
        )
    notes = []
    if not keep.all():
        visits, kept = holds_per_pose(labels, hold_ids(labels, None)), holds_per_pose(labels[keep], holds)
        lost = [label for label, count in visits.items() if count > 1 and kept.get(label, 0) < 2]
        if lost:
            written = [f"{label:.15g}" if label_names is None else label_names[int(label)] for label in lost[:5]]
            names = ", ".join(written) + (" ..." if len(lost) > 5 else "")
            notes.append(
                f"pose{'s' if len(lost) > 1 else ''} {names} {'are' if len(lost) > 1 else 'is'} labelled in separate "
                "runs of rows (held more than once), but fewer than two of those holds were kept as static intervals, "
                "so they were not compared for drift: hold each visit longer than data.static.min_duration"
            )
    return revisits, notes


def pose_labels(values: np.ndarray, detection: StaticIntervals | None = None) -> np.ndarray:
    """``f`` int64 labels 0..k-1 of a pose column's values (its rows' directions are tied). A row with an empty cell
    is a pose of its own (a missing label must not tie every unlabelled row to one direction), except within a static
    interval of ``detection``, whose unlabelled rows are one pose, as with no pose column: a label that starts after
    the hold or ends before the move (the detector's interval reaching a row or two into it) leaves its edge rows in
    the hold's pose, not each with a direction resting on one row."""
    missing = np.isnan(values)
    # Codes, not the values plus one: a label of 1e20 plus one is itself.
    codes = np.zeros(len(values), dtype=np.int64)
    codes[~missing] = np.unique(values[~missing], return_inverse=True)[1].reshape(-1)
    first_free = int(codes[~missing].max()) + 1 if (~missing).any() else 0
    interval = np.full(len(values), -1) if detection is None else detection.interval_of_rows()
    alone = missing & (interval < 0)
    codes[missing & ~alone] = first_free + interval[missing & ~alone]
    codes[alone] = first_free + len(values) + np.arange(int(alone.sum()))
    return np.unique(codes, return_inverse=True)[1].reshape(-1)


# The loads a constant-magnitude calibration can have: a plane's, space's, or a wrench's (force and torque).
LOAD_AXES = (2, 3, 6)


def six_axes_need_configurations(streamed: bool = False) -> SfmnetError:
    """The error for six load axes (a wrench) given without mass configurations: a tester's were asked for
    data.magnitude, and with it fitted as one 6-D load of constant size, newtons and newton metres mixed."""
    experiment = "experiment=calibrate_csv (in memory: the streamed fit takes one mass)" if streamed else "experiment=calibrate_csv"
    return SfmnetError(
        "six load axes (force, then torque) need each row's mass configuration, as a wrench's size is not constant: "
        "give data.configuration_column (the column naming it) and data.configurations ({<id>: {mass: <kg>, "
        f"centre_of_mass: [x, y, z]}}}}), with {experiment}"
    )


def load_axes(load_columns: list[str], axes: list[str] | None) -> list[str]:
    """The ``n`` load axis names: the load columns, or ``axes`` when no load is known."""
    if load_columns and axes and list(axes) != list(load_columns):
        raise SfmnetError("data.axes names the load axes only when data.load_columns is empty: drop one of them")
    names = list(load_columns) or list(axes or [])
    if not names:
        raise SfmnetError(
            "no load axes: give the known loads' columns (data.load_columns=[fx,fy,fz]) or, with no known load, "
            "name the axes (data.load_columns=[] data.axes=[x,y,z])"
        )
    if len(names) not in LOAD_AXES:
        raise SfmnetError(
            f"{len(names)} load ax{'is' if len(names) == 1 else 'es'} ({', '.join(map(str, names))}): a calibration has 2 (a fingertip), 3 (a force "
            "sensor, an accelerometer or a magnetometer) or 6 (force and torque), one load column or axis name each"
        )
    return names


def calibration_magnitude(magnitude: float | None, mass: float | None, gravity: float) -> float:
    """The calibration load's magnitude (load units) from exactly one of ``magnitude`` or ``mass`` (kg)."""
    if (magnitude is None) == (mass is None):
        raise SfmnetError("give the calibration load as exactly one of data.magnitude (load units) or data.mass (kg)")
    value = magnitude if magnitude is not None else mass * gravity
    if not value > 0:
        raise SfmnetError(f"the load magnitude must be positive, got {value}")
    return float(value)


def mirror_hint_fields(hint: dict, load_columns: list[str]) -> tuple[int, int, int]:
    """``data.mirror_hint`` (``{row, axis: <load column>, sign}``) as (data row, axis index, sign)."""
    hint = dict(hint)
    if set(hint) != {"row", "axis", "sign"}:
        raise SfmnetError("data.mirror_hint needs exactly row, axis and sign, e.g. {row: 17, axis: fz, sign: 1}")
    if hint["axis"] not in load_columns:
        raise SfmnetError(f"data.mirror_hint.axis '{hint['axis']}' is not one of the load columns {load_columns}")
    return int(hint["row"]), load_columns.index(hint["axis"]), int(hint["sign"])


# Fewer rows than this may rise or fall throughout by chance.
MONOTONIC_MIN_ROWS = 10


def hint_row_warnings(row: int, first_line: int, line: int, where: str) -> list[str]:
    """A note where lines that are not rows (blank lines, comments, a quoted cell's further lines) lie above the
    mirror hint's data ``row``, which starts on file ``line`` (data row 0 on ``first_line``): counted by the
    file's lines, as in an editor or a spreadsheet, the row meant is another (a hostile tester's hint picked the
    wrong mirror, every check passing)."""
    skipped = line - first_line - row
    if skipped <= 0:
        return []
    return [
        f"data.mirror_hint.row {row} is {where}: {skipped} blank or comment line{'s' if skipped > 1 else ''} above it "
        "are not rows, so counting the file's lines gives another row; check that this is the row meant (rows count "
        "from 0 after the header, skipping such lines), since its sign sets the frame's mirror"
    ]


# Channels whose spreads differ more than this are most likely in different units.
CHANNEL_SPREAD_RATIO = 100.0


def channel_scale_warnings(readings: np.ndarray, channels: list[str]) -> list[str]:
    """A warning where the channels' spreads (2-98 % range over ``readings``) differ by more than
    :data:`CHANNEL_SPREAD_RATIO`: the fit weighs channels alike in raw units, so a channel in small units counts for
    little (a hostile tester's channels in units 1e5, 1, 1e-3 and 50 apart were fitted 5x less accurately than the same
    channels in one unit, and the checks disowned them blaming motion and bias)."""
    spreads = np.subtract(*np.percentile(readings, [98, 2], axis=0))
    moving = spreads > 0
    if moving.sum() < 2 or spreads[moving].max() <= CHANNEL_SPREAD_RATIO * spreads[moving].min():
        return []
    wide, narrow = int(np.argmax(np.where(moving, spreads, -np.inf))), int(np.argmin(np.where(moving, spreads, np.inf)))
    return [
        f"the channels' spreads differ {spreads[wide] / spreads[narrow]:.3g}x (channel '{channels[wide]}' "
        f"{spreads[wide]:.3g}, '{channels[narrow]}' {spreads[narrow]:.3g} raw units): the fit weighs every channel alike "
        "in raw units, so a channel in small units counts for little; if the channels are in different units, give them "
        "in comparable ones (scale the columns)"
    ]


def monotonic_channel_warnings(readings: np.ndarray, channels: list[str], span: str) -> list[str]:
    """A warning for each channel that only rises (or only falls) over ``readings``, the rows ``span`` names:
    most likely a timestamp or a counter taken as a channel, which would swamp the calibration."""
    if len(readings) < MONOTONIC_MIN_ROWS:
        return []
    steps = np.diff(readings, axis=0)
    # A constant channel neither rises nor falls (it is refused as constant, on its own).
    moving = (steps != 0).any(axis=0)
    rising, falling = (steps >= 0).all(axis=0) & moving, (steps <= 0).all(axis=0) & moving
    return [
        f"channel '{name}' only {'rises' if up else 'falls'} over {span}, like a timestamp or a counter: if it is one, "
        f"leave it out of the channels (data.time_column={name}, or data.channel_columns=[...])"
        for name, up, down in zip(channels, rising, falling) if up or down
    ]
