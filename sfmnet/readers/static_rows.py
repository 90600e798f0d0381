"""Which rows of a calibration file are fitted: the static intervals of a continuous recording (config glue).

The detector itself is :func:`sfmnet.preprocessing.static_intervals.find_static_intervals`;
this module turns ``data.static_intervals``, ``data.time_unit`` and ``data.static`` into its
arguments and applies the calibration's rules: known loads lie in static intervals, and
there are enough intervals for the metric constraint's unknowns.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sfmnet.errors import SfmnetError
from sfmnet.linalg.factorisation import known_load_equations, metric_unknowns
from sfmnet.preprocessing.static_intervals import (
    DEFAULT_NOISE_QUANTILE,
    DEFAULT_THRESHOLD,
    Rows,
    StaticIntervals,
    find_static_intervals,
)

# d: a spreadsheet's serial dates (Excel, LibreOffice) or MATLAB's datenum, days since an epoch.
TIME_UNITS = {"d": 86_400.0, "h": 3_600.0, "min": 60.0, "s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
STATIC_KEYS = {"window", "min_duration", "threshold", "noise_quantile", "trim_ends"}


@dataclass(frozen=True)
class StaticSettings:
    """The detector's settings from the config; ``time_scale`` turns the time column into seconds."""

    window: float | None
    min_duration: float | None
    threshold: float
    noise_quantile: float
    time_scale: float
    trim_ends: bool = False

    def detect(self, readings: Rows, time: Rows | None, where: Callable[[int], str]) -> StaticIntervals:
        """The static intervals; ``where`` names a row's place in the file for messages."""
        return find_static_intervals(
            readings, time, window=self.window, min_duration=self.min_duration,
            threshold=self.threshold, noise_quantile=self.noise_quantile, where=where, trim_ends=self.trim_ends,
        )


def static_settings(enabled: bool | None, time_column: str | None, time_unit: str, static: dict | None) -> StaticSettings | None:
    """The settings, or None when detection is off (``enabled`` false, or null without a time column)."""
    if enabled is False or (enabled is None and not time_column):
        return None
    if time_unit not in TIME_UNITS:
        raise SfmnetError(f"data.time_unit is '{time_unit}': use one of {', '.join(TIME_UNITS)}")
    given = dict(static or {})
    unknown = sorted(set(given) - STATIC_KEYS)
    if unknown:
        raise SfmnetError(f"data.static.{unknown[0]} is not a setting: use {', '.join(sorted(STATIC_KEYS))}")
    settings = StaticSettings(
        window=given.get("window"),
        min_duration=given.get("min_duration"),
        threshold=float(DEFAULT_THRESHOLD if given.get("threshold") is None else given["threshold"]),
        noise_quantile=float(DEFAULT_NOISE_QUANTILE if given.get("noise_quantile") is None else given["noise_quantile"]),
        time_scale=TIME_UNITS[time_unit],
        trim_ends=given.get("trim_ends") or False,
    )
    if not isinstance(settings.trim_ends, bool):
        raise SfmnetError(f"data.static.trim_ends is {settings.trim_ends!r}: give true or false")
    for name in ("window", "min_duration", "threshold"):
        value = getattr(settings, name)
        if value is not None and not value > 0:
            raise SfmnetError(f"data.static.{name} is {value}: give a positive number (or null for the default)")
    if not 0 < settings.noise_quantile < 1:
        raise SfmnetError(f"data.static.noise_quantile is {settings.noise_quantile}: give a fraction between 0 and 1")
    return settings


def fitted_rows(
    detection: StaticIntervals, known: np.ndarray, axes: int, where: Callable[[int], str], check_count: bool = True
) -> np.ndarray:
    """``f`` bool, the rows to fit: the static ones.

    A known-load row at an interval's end (within a window: the detector's resolution), or held
    still in a run too short to be an interval, is left out like its neighbours, as long as some
    rows of its known pose (a run of consecutive known rows) are fitted; one in motion farther
    from every interval was recorded in motion, which no calibration can use.

    Args:
        known: row indices (int) of the known-load rows.
        axes: ``n``, for the metric constraint's unknowns (with offsets).
        where: a row's place in the file for messages, e.g. ``line 17 of session.csv``.
        check_count: refuse fewer intervals than unknowns (single-mass sessions).
    """
    if not detection.independent:
        for pose in known_poses(known):
            if len(pose) and not detection.mask[pose].any():
                unfitted_known_pose(detection, pose, where)
    moving = known[~detection.mask[known] & ~detection.near_interval(known) & ~detection.still(known)]
    if len(moving):
        raise SfmnetError(
            f"the known load on {where(int(moving[0]))} was recorded in motion (no static interval within a window): "
            "fill the load columns only while the mass is held still, or tune data.static"
        )
    # A known pose's interval counts once among the intervals, but its known load gives its own equations.
    poses = len([pose for pose in known_poses(known) if len(pose)])
    needed = intervals_needed(axes, poses)
    if check_count and not detection.independent and detection.count < needed:
        with_known = f" and {poses} known poses" if poses else ""
        raise SfmnetError(
            f"{detection.count} static interval{'' if detection.count == 1 else 's'} found but a {axes}-axis calibration "
            f"with offsets{with_known} needs at least {needed} (the unknowns of its metric constraint): record more poses "
            f"held still, each for at least {shortest_hold(detection)} (the shortest interval kept, "
            f"{in_time(detection, detection.min_rows)}, and the moving window, {in_time(detection, detection.window_rows)}, "
            "half of which reaches into the move at each end), tune data.static (window, min_duration, threshold), or fit "
            "every row with data.static_intervals=false (as a magnetometer's should be: moving does not change the field "
            "it reads, so a continuous rotation is all calibration data)"
        )
    return detection.mask


def intervals_needed(axes: int, known_poses: int) -> int:
    """The fewest static intervals (or groups) an ``axes``-axis calibration with offsets can be fitted from, with
    ``known_poses`` of them known loads: the metric constraint's unknowns, less what each known pose gives beyond the
    one equation an unknown pose does."""
    return metric_unknowns(axes, True) - (known_load_equations(axes, known_poses) - known_poses)


def shortest_hold(detection: StaticIntervals) -> str:
    """The shortest hold ``detection`` keeps an interval of: its shortest interval and the window's two halves, which
    reach into the moves at the hold's ends; in seconds where the recording has a time, else in rows."""
    return in_time(detection, detection.min_rows + detection.window_rows - 1)


def in_time(detection: StaticIntervals, rows: int) -> str:
    """``rows`` in seconds where the recording has a time, else in rows."""
    if detection.period is None:
        return f"{rows:,} rows"
    return f"{rows * detection.period:.3g} s"


def known_poses(known: np.ndarray) -> list[np.ndarray]:
    """The runs of consecutive rows in ``known`` (sorted row indices): one per known pose."""
    return np.split(known, np.nonzero(np.diff(known) > 1)[0] + 1)


def unfitted_known_pose(detection: StaticIntervals, pose: np.ndarray, where: Callable[[int], str]) -> None:
    """Refuse a known pose none of whose rows is in an interval, saying why: held still too briefly (its longest
    still run, against what that run needed), or only within a window of motion."""
    runs: list[tuple[int, int, int]] = []
    for row in pose[detection.still(pose)].tolist():
        if not runs or row >= runs[-1][1]:  # each still run once, however long the pose
            runs.append(detection.still_run(row))
    if runs:
        first, stop, fewest = max(runs, key=lambda run: run[1] - run[0])
        rows = stop - first
        seconds = lambda count: f"{count} rows" if detection.period is None else f"{count * detection.period:.3g} s"  # noqa: E731
        limit = "data.static.window" if fewest < detection.min_rows else "data.static.min_duration"
        raise SfmnetError(
            f"the known load on {where(int(pose[0]))} was held still for only {seconds(rows)}"
            f"{f' ({rows} rows)' if detection.period is not None else ''}, under the shortest static interval of "
            f"{seconds(fewest)} there: hold the known pose longer, or lower {limit}"
        )
    if detection.near_interval(pose).all():
        raise SfmnetError(
            f"the known load on {where(int(pose[0]))} lies at the edge of a static interval, within a window of "
            "motion, so none of its rows would be fitted: fill the load columns on rows held still (the whole "
            "hold), or shorten data.static.window"
        )
