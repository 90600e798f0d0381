"""Files as people write them: every reader of a table reads Excel's and other locales' CSVs as the plain CSV,
and the CSV-to-npy conversion behind calibrate_stream counts its rows right and is keyed by the file's content."""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from sfmnet.apply import apply_calibration
from sfmnet.readers.csv_calibration import monotonic_channel_warnings
from sfmnet.readers.row_file import csv_to_npy
from sfmnet.readers.table_file import read_table
from sfmnet.training.run import train
from tests.conftest import compose_config, write_session


def plain_rows(path: Path) -> list[list[str]]:
    with path.open(newline="") as stream:
        return list(csv.reader(stream))


def with_bom(rows: list[list[str]], path: Path) -> None:
    """Excel's "CSV UTF-8": a byte-order mark first."""
    path.write_bytes(b"\xef\xbb\xbf" + "".join(",".join(row) + "\r\n" for row in rows).encode())


def semicolons_and_decimal_commas(rows: list[list[str]], path: Path) -> None:
    """The CSV of a locale whose decimal mark is a comma: ';'-separated, 1,23 for 1.23."""
    path.write_text("".join(";".join(cell.replace(".", ",") for cell in row) + "\n" for row in rows))


def excel_separator_line(rows: list[list[str]], path: Path) -> None:
    """Excel's ``sep=;`` first line naming the separator (a hostile tester's: read as a one-column header)."""
    path.write_text("sep=;\n" + "".join(";".join(cell.replace(".", ",") for cell in row) + "\n" for row in rows))


def excel_separator_line_padded_tabs(rows: list[list[str]], path: Path) -> None:
    """The ``sep=`` line naming a tab, padded with separators as a spreadsheet saving the file again writes it."""
    path.write_text("sep=\t\t\t\n" + "".join("\t".join(row) + "\n" for row in rows))


def trailing_separator(rows: list[list[str]], path: Path) -> None:
    """A spreadsheet's export with a separator at the end of every line (a hostile tester's: "column  of ... is empty
    on every row", a blank name)."""
    path.write_text("".join(",".join(row) + ",\n" for row in rows))


def unicode_text(rows: list[list[str]], path: Path) -> None:
    """Excel's "Unicode Text": UTF-16 with its byte-order mark, tab-separated."""
    path.write_text("".join("\t".join(row) + "\n" for row in rows), encoding="utf-16")


def quoted(rows: list[list[str]], path: Path) -> None:
    """Every cell quoted, a space after each separator."""
    path.write_text("".join(", ".join(f'"{cell}"' for cell in row) + "\n" for row in rows))


def with_empty_rows(rows: list[list[str]], path: Path) -> None:
    """Blank lines and rows of empty cells (as a spreadsheet writes below its data) between and after the rows."""
    empty = "," * (len(rows[0]) - 1)
    lines = [",".join(row) for row in rows]
    path.write_text("\n".join([*lines[:5], empty, "", *lines[5:], empty, empty]) + "\n")


def tab_separated(rows: list[list[str]], path: Path) -> None:
    """A ``.tsv``: tabs, and two tabs around an empty load cell."""
    path.write_text("".join("\t".join(row) + "\n" for row in rows))


# Each variant's writer and the file name it is saved under.
VARIANTS: dict[str, tuple[Callable[[list[list[str]], Path], None], str]] = {
    "BOM": (with_bom, "variant.csv"),
    "semicolons and decimal commas": (semicolons_and_decimal_commas, "variant.csv"),
    "Excel's sep= line": (excel_separator_line, "variant.csv"),
    "Excel's sep= line, a tab, padded": (excel_separator_line_padded_tabs, "variant.csv"),
    "a separator ending every line": (trailing_separator, "variant.csv"),
    "UTF-16 with tabs": (unicode_text, "variant.csv"),
    "quoted cells": (quoted, "variant.csv"),
    "empty rows": (with_empty_rows, "variant.csv"),
    "a .tsv with empty cells": (tab_separated, "variant.tsv"),
}


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_every_reader_reads_the_variant_as_the_plain_csv(variant: str, tmp_path: Path):
    plain = tmp_path / "plain.csv"
    write_session(plain)
    writer, name = VARIANTS[variant]
    written = tmp_path / name
    writer(plain_rows(plain), written)
    expected, table = read_table(plain), read_table(written)
    assert list(table.columns) == list(expected.columns) and not table.text
    for name, values in expected.columns.items():
        np.testing.assert_array_equal(table.columns[name], values)
    np.testing.assert_array_equal(np.load(csv_to_npy(written, None)), np.load(csv_to_npy(plain, None)))


def test_semicolons_are_found_where_names_hold_commas(tmp_path: Path):
    """``Kraft, x;Kraft, y`` over ``1,5;2,5`` splits evenly by commas too: the semicolon is the separator."""
    path = tmp_path / "kraft.csv"
    path.write_text("Kraft, x;Kraft, y\n1,5;2,5\n3;-4,25\n")
    table = read_table(path)
    assert {name: values.tolist() for name, values in table.columns.items()} == {"Kraft, x": [1.5, 3.0], "Kraft, y": [2.5, -4.25]}
    np.testing.assert_array_equal(np.load(csv_to_npy(path, None)), [[1.5, 2.5], [3.0, -4.25]])


def calibration_of(path: Path, run_dir: Path) -> dict:
    cfg = compose_config(["experiment=calibrate_csv", f"data.path={path}", "data.magnitude=9.81", "data.time_column=time"])
    train(cfg, run_dir)
    return json.loads((run_dir / "calibration.json").read_text())


def test_bom_and_semicolon_files_calibrate_and_apply_as_the_plain_csv(tmp_path: Path):
    """The BOM would have made the first column '\\ufefftime', so the timestamp became a channel."""
    plain = tmp_path / "plain.csv"
    write_session(plain)
    expected = calibration_of(plain, tmp_path / "plain")
    assert expected["channels"] == [f"s{i}" for i in range(6)] and expected["warnings"] == []
    apply_calibration(tmp_path / "plain" / "calibration.json", plain, tmp_path / "plain_loads.csv", overwrite=False)
    for name in ("BOM", "semicolons and decimal commas"):
        written = tmp_path / f"{name}.csv"
        VARIANTS[name][0](plain_rows(plain), written)
        calibration = calibration_of(written, tmp_path / name)
        assert calibration["channels"] == expected["channels"]
        for key in ("matrix", "offset", "warnings"):
            assert calibration[key] == expected[key], key
        loads = tmp_path / f"{name}_loads.csv"
        apply_calibration(tmp_path / name / "calibration.json", written, loads, overwrite=False)
        # Written as the input was (its separator and decimal comma), read back as the plain output: no BOM in the
        # copied header, the same loads.
        got, want = read_table(loads), read_table(tmp_path / "plain_loads.csv")
        assert list(got.columns) == list(want.columns)
        for axis in ("fx", "fy", "fz"):
            np.testing.assert_array_equal(got.columns[f"{axis}_calibrated"], want.columns[f"{axis}_calibrated"])


@pytest.mark.parametrize(
    "overrides",
    # The alternation: with a timestamp among the channels the marginal refinement takes its time.
    [["experiment=calibrate_csv", "model.refinement=alternation"], ["experiment=calibrate_stream"]],
    ids=["in memory", "streamed"],
)
def test_a_timestamp_taken_as_a_channel_is_warned_about(overrides: list[str], tmp_path: Path):
    session = tmp_path / "session.csv"
    write_session(session)
    train(compose_config([*overrides, f"data.path={session}", "data.magnitude=9.81"]), tmp_path / "run")
    calibration = json.loads((tmp_path / "run" / "calibration.json").read_text())
    assert "time" in calibration["channels"]
    assert any(warning.startswith("channel 'time' only rises over the file's rows, like a timestamp") for warning in calibration["warnings"])


def test_only_monotonic_channels_of_enough_rows_are_warned_about():
    rows = np.random.default_rng(0).normal(size=(12, 3))
    rows[:, 1] = -np.arange(12.0)  # a countdown
    assert [warning.split(" ", 2)[1] for warning in monotonic_channel_warnings(rows, ["a", "b", "c"], "the rows")] == ["'b'"]
    assert monotonic_channel_warnings(rows[:9], ["a", "b", "c"], "the rows") == []


def test_cache_follows_the_content_not_the_size_and_mtime(tmp_path: Path):
    path = tmp_path / "rows.csv"
    path.write_text("a,b\n1,2\n3,4\n")
    first = csv_to_npy(path, None)
    stamp = path.stat()
    path.write_text("a,b\n1,2\n3,5\n")  # same size
    os.utime(path, ns=(stamp.st_atime_ns, stamp.st_mtime_ns))
    assert path.stat().st_size == stamp.st_size and path.stat().st_mtime_ns == stamp.st_mtime_ns
    second = csv_to_npy(path, None)
    assert second != first
    np.testing.assert_array_equal(np.load(second), [[1, 2], [3, 5]])


def test_conversion_of_a_multiple_of_the_chunk_rows(tmp_path: Path):
    path = tmp_path / "rows.csv"
    values = np.arange(400_000, dtype=np.float64).reshape(200_000, 2)
    path.write_text("a,b\n" + "".join(f"{a:g},{b:g}\n" for a, b in values))
    np.testing.assert_array_equal(np.load(csv_to_npy(path, None, chunk_rows=100_000)), values)


def test_conversion_leaves_another_runs_half_written_file_alone(tmp_path: Path):
    """Two runs converting one CSV each write under a name of their own: neither reads, truncates nor renames the other's."""
    path = tmp_path / "rows.csv"
    path.write_text("a,b\n1,2\n3,4\n")
    cache = csv_to_npy(path, None)
    cache.unlink()
    others = [cache.with_name(f".{cache.name}.partial"), cache.with_name(f".{cache.name}.other.partial")]
    for other in others:
        other.write_bytes(b"another run's half-written conversion")
    assert csv_to_npy(path, None) == cache
    np.testing.assert_array_equal(np.load(cache), [[1, 2], [3, 4]])
    assert [other.read_bytes() for other in others] == [b"another run's half-written conversion"] * 2
    assert sorted(p.name for p in cache.parent.iterdir()) == sorted([cache.name, *(other.name for other in others)])


def test_a_whitespace_table_reads_past_blank_and_comment_lines_and_names_their_lines(tmp_path: Path):
    """A logger's or MATLAB's ``save -ascii`` table (.txt): its blank and '#' lines are skipped, and a bad value is
    refused by the line an editor shows, not by numpy's count of the rows it kept."""
    from sfmnet.errors import SfmnetError

    text = "a b c\n1 2 3\n\n# moved the mass\n4 5 6  # settled\n7 8 9\n"
    (tmp_path / "rows.txt").write_text(text)
    table = read_table(tmp_path / "rows.txt")
    assert table.numeric(["a", "b", "c"], "channel").tolist() == [[1, 2, 3], [4, 5, 6], [7, 8, 9]]
    assert table.row_place(2) == "line 6"
    (tmp_path / "word.txt").write_text(text.replace("8", "n/a"))
    with pytest.raises(SfmnetError, match=r"word.txt line 6 has a non-numeric value \('n/a'\): a .txt or .dat table holds numbers only"):
        read_table(tmp_path / "word.txt")
    (tmp_path / "short.txt").write_text(text.replace("4 5 6", "4 5"))
    with pytest.raises(SfmnetError, match=r"short.txt line 5 has 2 values but the table has 3 columns"):
        read_table(tmp_path / "short.txt")


def test_a_constant_channel_is_not_called_a_timestamp():
    """A stuck channel neither rises nor falls (a hostile tester's stream was told its stuck gauge looked like a
    timestamp); it is refused as constant on its own."""
    readings = np.stack([np.full(50, 1.234), np.arange(50.0), np.sin(np.arange(50.0))], axis=1)
    warnings = monotonic_channel_warnings(readings, ["stuck", "clock", "gauge"], "the file's rows")
    assert len(warnings) == 1 and warnings[0].startswith("channel 'clock' only rises")
