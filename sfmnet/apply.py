"""``python -m sfmnet apply calibration=<json> input=<csv> output=<csv> [overwrite=true]``: readings in, loads out."""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import torch

from sfmnet.calibration import Calibration
from sfmnet.readers.delimited import open_delimited
from sfmnet.readers.table_file import WHITESPACE_SUFFIXES, check_finite, read_table
from sfmnet.errors import SfmnetError
from sfmnet.io import refuse_overwrite, write_csv_atomic

OPTIONS = {"calibration", "input", "output", "overwrite"}


def parse_options(args: list[str]) -> dict[str, str]:
    options: dict[str, str] = {}
    for arg in args:
        key, sep, value = arg.partition("=")
        if not sep or key not in OPTIONS:
            raise SfmnetError(
                f"apply does not understand '{arg}': use calibration=<json> input=<csv> output=<csv> [overwrite=true]"
            )
        options[key] = value
    missing = sorted({"calibration", "input", "output"} - set(options))
    if missing:
        raise SfmnetError(f"apply needs {', '.join(f'{m}=' for m in missing)}: calibration=<json> input=<csv> output=<csv>")
    return options


def output_names(axes: list[str], existing: list[str]) -> list[str]:
    """The load columns' names: the axes, or where the input already uses any of them, every axis suffixed
    ``_calibrated`` (``_calibrated_2``, ``_calibrated_3``, ... where it uses those too: an earlier output applied
    again). All of them or none: a reader taking ``fx, fy`` by name would otherwise get one old load beside one new."""
    copy = 0
    while True:
        suffix = "" if copy == 0 else "_calibrated" if copy == 1 else f"_calibrated_{copy}"
        names = [f"{axis}{suffix}" for axis in axes]
        if not set(names) & set(existing):
            return names
        copy += 1


def taken_names(axes: list[str], existing: list[str]) -> list[str]:
    """The input's columns named as a load column of ``axes`` is (an axis, or one suffixed ``_calibrated...``): the
    names :func:`output_names` stepped past."""
    return [name for name in existing if any(name == axis or name.startswith(f"{axis}_calibrated") for axis in axes)]


def apply_calibration(
    calibration_path: Path, input_path: Path, output_path: Path, overwrite: bool
) -> tuple[int, list[str], list[str], Calibration]:
    """Write ``output_path``: every input row and column, then the calibrated loads. Returns the row count, the load
    columns' names (:func:`output_names`), the input's columns that took theirs (:func:`taken_names`) and the
    calibration applied."""
    refuse_overwrite(output_path, overwrite, "output=", "loads.csv", "add overwrite=true")
    if output_path.resolve() == input_path.resolve():
        raise SfmnetError("output= is the input file: write the loads to a new file")
    if output_path.resolve() == calibration_path.resolve():
        raise SfmnetError("output= is the calibration file: write the loads to a new file")
    calibration = Calibration.load(calibration_path)
    if input_path.suffix in (".npy", ".npz", *WHITESPACE_SUFFIXES):
        raise SfmnetError(f"input={input_path} is not a CSV: apply copies the input's cells, so give it a CSV with a header row")
    table = read_table(input_path, option="input=")
    missing = [name for name in calibration.channels if name not in table.columns and name not in table.text]
    if missing:
        raise SfmnetError(
            f"{input_path} lacks channel{'s' if len(missing) > 1 else ''} {', '.join(missing)} of the calibration "
            f"(which needs {', '.join(calibration.channels)}): these readings are not from the calibrated sensor"
        )
    readings = table.numeric(calibration.channels, "channel")
    check_finite(readings, calibration.channels, table, "reading")
    loads = calibration.apply(torch.from_numpy(readings)).numpy()

    # The same rows as the table's (the same reader skips the same empty rows), written as the input was: its
    # separator, and its decimal comma where its readings have one, so that the output reads back as the input did.
    source = open_delimited(input_path)
    header, rows = source.header_and_rows()
    first = next(rows)
    comma = source.decimal_comma and any("," in first[1][header.index(name)] for name in calibration.channels)

    def number(value: float) -> str:
        return f"{value:.9g}".replace(".", ",") if comma else f"{value:.9g}"

    names = output_names(calibration.axes, header)
    write_csv_atomic(
        output_path,
        [*header, *names],
        ([*cells, *map(number, load)] for (_, cells), load in zip(itertools.chain([first], rows), loads)),
        delimiter=source.separator,
    )
    return len(loads), names, taken_names(calibration.axes, header), calibration


def apply_command(args: list[str]) -> None:
    options = parse_options(args)
    output = Path(options["output"])
    count, names, taken, calibration = apply_calibration(
        Path(options["calibration"]),
        Path(options["input"]),
        output,
        overwrite=options.get("overwrite", "false").lower() in ("1", "true", "yes"),
    )
    renamed = f" (the input has {', '.join(taken)} already)" if taken else ""
    print(
        f"wrote {count} rows of loads ({calibration.extra.get('load_unit', 'N')}) to {output}, columns "
        f"{', '.join(names)}{renamed}"
    )
    if not calibration.error_bars_trustworthy:
        # Its loads are still what the fit gives; the user should not take them as the sensor's without knowing.
        first = calibration.warnings[0] if calibration.warnings else "the fit failed"
        first = first if len(first) <= 120 else first[:117].rstrip() + "..."
        print(
            f"warning: {options['calibration']} was marked NOT TRUSTWORTHY when it was fitted ({first}; its "
            "\"warnings\" list every check that failed): these loads may be off by more than its error bars",
            file=sys.stderr,
        )
