"""Time columns as loggers write them (ISO 8601 dates and times, clock times) are read as seconds, in memory, streamed
and through the Python API, and find the same static intervals as the same times in seconds."""

from __future__ import annotations

import csv
import datetime
import json
from pathlib import Path

import numpy as np
import pytest

import sfmnet
from sfmnet.errors import SfmnetError
from sfmnet.readers.clock_times import clock_seconds, clock_time_column
from sfmnet.simulators.simulated_stream import write_stream_csv
from tests.test_static_intervals import MASS, calibrate, stream

START = datetime.datetime(2026, 12, 7, 23, 59, 50)
SPREADSHEET_EPOCH = datetime.datetime(1899, 12, 30)


@pytest.mark.parametrize(
    "cell,day,seconds",
    [
        ("2026-12-07T13:52:41.250", 20794, 49961.25),
        ("2026-12-07 13:52:41,250", 20794, 49961.25),
        ("2026-12-07T13:52:41.250Z", 20794, 49961.25),
        ("2026-12-07T14:52:41.250+01:00", 20794, 49961.25),
        ("2026-12-07T08:52:41.250-0500", 20794, 49961.25),
        # An offset of whole hours (ISO 8601's +01; a hostile tester's were refused as not numeric).
        ("2026-12-07T14:52:41.250+01", 20794, 49961.25),
        ("2026-12-07T19:22:41.250+05:30", 20794, 49961.25),
        ("13:52:41.250", 0, 49961.25),
        ("13:52", 0, 49920.0),
        # A 12-hour clock (a hostile tester's, refused as not numeric).
        ("1:52:41.250 PM", 0, 49961.25),
        ("2026-12-07 01:52:41.250 pm", 20794, 49961.25),
        ("12:00:00 AM", 0, 0.0),
        ("12:00:00 PM", 0, 43200.0),
    ],
)
def test_dates_and_clock_times_are_read_as_a_day_and_seconds_into_it(cell: str, day: int, seconds: float):
    # Day 20794 is 2026-12-07; 0, no date given.
    assert clock_seconds(cell) == (day, pytest.approx(seconds, abs=1e-9), day > 0)


@pytest.mark.parametrize("cell", ["2026-13-40T10:00:00", "13:52:41 CET", "13:52 PM", "0.25", "n/a", ""])
def test_other_cells_are_not_times(cell: str):
    assert clock_seconds(cell) is None


def test_clock_times_that_pass_midnight_keep_counting():
    seconds = clock_time_column(["23:59:59.500", "23:59:59.900", "00:00:00.300", "00:00:01.000"], str)
    np.testing.assert_allclose(seconds, [0.0, 0.4, 0.8, 1.5])
    # Two rows swapped across midnight (a hostile tester's): a step back of 10 ms, not a day.
    seconds = clock_time_column(["23:59:59.980", "00:00:00.000", "23:59:59.990", "00:00:00.010"], str)
    np.testing.assert_allclose(seconds, [0.0, 0.02, 0.01, 0.03], atol=1e-9)


def test_a_time_column_mixing_dates_and_clock_times_is_refused():
    with pytest.raises(SfmnetError, match="gives dates on some rows and clock times alone on others"):
        clock_time_column(["2026-12-07T23:59:59", "00:00:01"], str)


def rewrite_time(path: Path, out: Path, stamp) -> None:
    rows = list(csv.reader(path.open()))
    for row in rows[1:]:
        row[0] = stamp(START + datetime.timedelta(milliseconds=round(float(row[0]) * 1000)))
    csv.writer(out.open("w", newline="")).writerows(rows)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One continuous recording (passing midnight) with its time in seconds, as ISO 8601 stamps with an offset from
    UTC, and as clock times alone."""
    folder = tmp_path_factory.mktemp("clock")
    recording, _ = stream(poses=10)
    paths = {name: folder / f"{name}.csv" for name in ("seconds", "iso", "clock", "serial")}
    write_stream_csv(recording, paths["seconds"])
    rewrite_time(paths["seconds"], paths["iso"], lambda t: t.isoformat(timespec="milliseconds") + "+01:00")
    rewrite_time(paths["seconds"], paths["clock"], lambda t: t.strftime("%H:%M:%S.%f")[:-3])
    # A spreadsheet's serial dates: days since 1899-12-30 (a hostile tester's were refused with a hint about ms).
    rewrite_time(paths["seconds"], paths["serial"], lambda t: f"{(t - SPREADSHEET_EPOCH) / datetime.timedelta(days=1):.10f}")
    return paths


@pytest.mark.parametrize(
    "form,experiment,overrides",
    [("iso", "calibrate_csv", ()), ("clock", "calibrate_stream", ()), ("serial", "calibrate_csv", ("data.time_unit=d",))],
)
def test_a_time_column_of_dates_or_clock_times_finds_the_intervals_of_seconds(
    recordings: dict[str, Path], tmp_path: Path, form: str, experiment: str, overrides: tuple[str, ...]
):
    reference = calibrate(recordings["seconds"], tmp_path / "seconds", experiment=experiment)
    stamped = calibrate(recordings[form], tmp_path / form, *overrides, experiment=experiment)
    assert stamped["static/intervals"] == reference["static/intervals"] >= 10
    assert stamped["static/rows_kept"] == reference["static/rows_kept"]
    matrices = [np.array(json.loads((tmp_path / run / "calibration.json").read_text())["matrix"]) for run in ("seconds", form)]
    np.testing.assert_allclose(matrices[1], matrices[0], rtol=0, atol=1e-9 * np.abs(matrices[0]).max())


def test_a_column_of_clock_times_left_unnamed_is_pointed_out(recordings: dict[str, Path], tmp_path: Path):
    calibrate(recordings["iso"], tmp_path / "run", "data.time_column=null")
    warnings = json.loads((tmp_path / "run" / "calibration.json").read_text())["warnings"]
    assert any(w.startswith("column 'time' holds dates or clock times and was not read") for w in warnings)


def test_the_python_api_reads_numpy_and_python_dates_as_seconds_from_the_first():
    recording, _ = stream(poses=10)
    seconds = recording.time.numpy()
    readings, loads = recording.readings.numpy(), recording.known_loads.numpy()
    reference = sfmnet.calibrate(readings, MASS * 9.80665, loads=loads, time=seconds)
    stamps = np.datetime64("2026-12-07T13:00", "ns") + (seconds * 1e9).round().astype("timedelta64[ns]")
    for time in (stamps, stamps - stamps[0], list(stamps.astype("datetime64[us]").tolist())):
        calibration = sfmnet.calibrate(readings, MASS * 9.80665, loads=loads, time=time)
        np.testing.assert_allclose(calibration.matrix, reference.matrix, rtol=0, atol=1e-9 * np.abs(reference.matrix).max())


@pytest.mark.parametrize("experiment", ["calibrate_csv", "calibrate_stream"])
def test_a_time_unit_beside_dates_is_refused(recordings: dict[str, Path], tmp_path: Path, experiment: str):
    """Dates are read as seconds: a hostile tester's data.time_unit=ms scaled them again in a stream (and was ignored
    in memory)."""
    with pytest.raises(SfmnetError, match="time column 'time' holds dates or clock times, which are read as seconds"):
        calibrate(recordings["iso"], tmp_path / "run", "data.time_unit=ms", experiment=experiment)


def test_api_times_that_cannot_be_dates_are_one_line():
    recording, _ = stream(poses=10)
    readings, loads = recording.readings.numpy(), recording.known_loads.numpy()
    stamps = list(np.datetime64("2026-12-07T13:00", "ns") + (recording.time.numpy() * 1e9).astype("timedelta64[ns]"))
    with pytest.raises(SfmnetError, match="time is given as dates or durations, which are read as seconds: leave data.time_unit out"):
        sfmnet.calibrate(readings, MASS * 9.80665, loads=loads, time=np.array(stamps), **{"data.time_unit": "ms"})
    mixed = [stamp.astype("datetime64[us]").astype(datetime.datetime) for stamp in stamps]
    mixed[7] = datetime.timedelta(seconds=1)
    with pytest.raises(SfmnetError, match=r"time cannot be read as dates .*: give every reading a time"):
        sfmnet.calibrate(readings, MASS * 9.80665, loads=loads, time=mixed)
