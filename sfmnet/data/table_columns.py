"""Tables given to the Python API (a pandas DataFrame, or anything with ``columns``) are read by column name.

By position, a table whose columns come in another order is read as other channels, with no error: a hostile
tester's reordered frame gave loads 222 % off through ``Calibration.apply``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sfmnet.errors import SfmnetError


def column_names(values: Any, name: str) -> list[Any] | None:
    """``values``'s column names (a pandas DataFrame's, strings or numbers), None for an array; a name given twice is
    refused (the command line refuses a column named twice)."""
    columns = getattr(values, "columns", None)
    if columns is None:
        return None
    names = [column.item() if hasattr(column, "item") else column for column in columns]
    twice = sorted({str(column) for column in names if names.count(column) > 1})
    if twice:
        raise SfmnetError(f"{name} has columns named twice ({', '.join(twice)}): give each column its own name")
    return names


def row_labels(values: Any) -> Any | None:
    """``values``'s row labels (a pandas DataFrame's or Series' index), None for an array or a list."""
    index = getattr(values, "index", None)
    return index if hasattr(index, "equals") else None


def require_same_row_labels(arguments: dict[str, Any]) -> None:
    """Arguments given together are paired row by row, by position; where two carry row labels (a pandas index) of
    the same length that differ, position pairs other rows than the labels say: a one-line error naming both."""
    labelled = [(name, index) for name, index in ((name, row_labels(value)) for name, value in arguments.items()) if index is not None]
    if not labelled:
        return
    first, labels = labelled[0]
    for name, other in labelled[1:]:
        if len(labels) == len(other) and not labels.equals(other):
            raise SfmnetError(
                f"{name} and {first} have different row labels (index): rows are paired by position, so align them "
                f"first (e.g. {name}.reindex({first}.index)), or give .to_numpy() to pair them by position"
            )


def columns_by_name(values: Any, wanted: Sequence[Any], name: str, fitted_on: str) -> Any:
    """``values`` (a table) with the ``wanted`` columns, in that order; a missing one is one line naming it.

    Args:
        fitted_on: what ``wanted`` are, for the message (e.g. ``"the calibration's channels"``).
    """
    names = column_names(values, name)
    if names is None:
        return values
    missing = [column for column in wanted if column not in names]
    if missing:
        raise SfmnetError(
            f"{name} has no column {', '.join(map(str, missing))}: {fitted_on} are {', '.join(map(str, wanted))} "
            "(a table's columns are read by name; give .to_numpy() to read them by position)"
        )
    return values[list(wanted)]
