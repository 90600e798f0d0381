"""The Python API: :func:`calibrate` arrays in memory through the same config, trainer and checks as the CLI.

``python -m sfmnet train experiment=calibrate_csv data.path=<file> ...`` reads a file into the
columns this module builds from arrays; both then run :func:`sfmnet.training.run.train`, so a
calibration from the API and one from the command line on the same numbers are the same numbers.
"""

from __future__ import annotations

import contextlib
import datetime
import io
import tempfile
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from sfmnet.calibration import Calibration
from sfmnet.data.table_columns import column_names, columns_by_name, require_same_row_labels
from sfmnet.errors import SfmnetError

# Config groups chosen by name (``model="least_squares"``), as on the command line.
CONFIG_GROUPS = ("model", "optimizer", "trainer")
TIME_COLUMN = "time"
POSE_COLUMN = "pose"
CONFIGURATION_COLUMN = "configuration"


def default_axis_names(n: int) -> list[str]:
    return ["x", "y", "z"][:n] if n <= 3 else [f"l{i}" for i in range(n)]


def calibrate(
    readings: Any,
    magnitude: float | None = None,
    loads: Any = None,
    time: Any = None,
    poses: Any = None,
    configurations: Any = None,
    *,
    channels: Sequence[str] | int | None = None,
    axes: Sequence[str] | int | None = None,
    run_dir: str | Path | None = None,
    verbose: bool = False,
    **config_overrides: Any,
) -> Calibration:
    """Calibrate a sensor from raw readings taken while one load of known magnitude is turned (method §2-5).

    The same run as ``python -m sfmnet train experiment=calibrate_csv`` on a file holding these
    columns: shape from motion with offsets and error bars, static intervals found when ``time``
    is given, the goodness-of-fit checks; ``load = matrix @ (reading - offset)``.

    Args:
        readings: ``(f, p)`` raw readings (numpy, torch or nested lists), one row per sample, ``p >= n``; or a
            table (a pandas DataFrame), read by column name: its columns are the channels, or ``channels`` picks them.
            The other arguments' rows pair with these by position; tables or series whose row labels (index) differ
            from these (readings given as an array: from each other's) are refused.
        magnitude: the load's magnitude in load units (e.g. ``9.81`` N for 1 kg, or
            ``9.81`` m/s^2 for an accelerometer); or give ``**{"data.mass": kg}``.
        loads: ``(f, n)`` known loads, NaN on the rows whose load is unknown (at least ``n - 1``
            known rows fix the frame, with ``**{"data.mirror_hint": {"row": r, "axis": a, "sign": s}}``
            for ``n - 1``); None: no known loads, the frame is arbitrary (an orthogonal transform,
            possibly a reflection: every magnitude right) and ``axes`` names the ``n`` load axes. A table's columns
            are the axes, or ``axes`` picks them by name.
        time: ``(f,)`` the rows' time in seconds, or as ``numpy.datetime64`` / ``timedelta64`` (a pandas time
            column's values), read from the first row's (turns on static-interval detection), or None.
        poses: ``(f,)`` the pose each row was held in (numbers, NaN for a row of a pose of its own), or None:
            ``data.group_column``. A pose's rows share one direction, and a pose held more than once (the first
            pose again at the end) is checked for drift between its holds.
        configurations: six axes (``loads`` of force then torque): ``(f,)`` each row's mass configuration, an id of
            ``**{"data.configurations": {id: {"mass": kg, "centre_of_mass": [x, y, z]}}}`` (m, the sensor's frame);
            ``data.configuration_column``. None for one mass.
        channels: the ``p`` channel names (default ``z0, z1, ...``), or their number.
        axes: the ``n`` load axis names, or their number (default ``x, y, z`` for ``n <= 3``, else ``l0, l1, ...``);
            required with ``loads=None``, where they say how many axes there are.
        run_dir: write the full run directory there (calibration.json, metrics.json, figures,
            TensorBoard); None: a temporary directory, removed afterwards.
        verbose: print the run's summary and progress as the CLI does.
        **config_overrides: the CLI's keys, dotted (``**{"model.refinement": "alternation"}``) or as
            mappings (``model={"refinement": "alternation"}``); a group by name (``model="least_squares"``).

    Returns:
        The :class:`Calibration` the CLI writes to ``calibration.json``: ``matrix`` (``n x p``),
        ``offset`` (``p``), ``matrix_std``, ``warnings``, ``error_bars_trustworthy``, and
        :meth:`Calibration.apply` for new readings.

    Raises:
        SfmnetError: bad input, one line naming the problem and what to do.
    """
    require_same_row_labels({"readings": readings, "loads": loads, "time": time, "poses": poses, "configurations": configurations})
    readings, channels = named_columns(readings, channels, "readings", "channels")
    if loads is not None:
        loads, axes = named_columns(loads, axes, "loads", "axes")
    if isinstance(axes, int) and not isinstance(axes, bool):
        axes = default_axis_names(axes)
    if isinstance(channels, int) and not isinstance(channels, bool):
        channels = [f"z{i}" for i in range(channels)]
    readings = as_matrix(readings, "readings")
    f, p = readings.shape
    if loads is None:
        if axes is None:
            raise SfmnetError("with no known loads (loads=None) name the n load axes, e.g. axes=['x', 'y', 'z']")
        n = len(axes)
        known = np.full((f, n), np.nan)
    else:
        known = as_matrix(loads, "loads")
        if len(known) != f:
            raise SfmnetError(f"loads has {len(known)} rows but readings has {f}: give one load row (NaN if unknown) per reading")
        if np.isnan(known).all():
            raise SfmnetError(
                "loads is NaN on every row, so no known load fixes the frame: give the known loads on their rows, or "
                "loads=None and axes=[...] for a calibration in an arbitrary frame"
            )
        n = known.shape[1]
    channels = list(channels) if channels is not None else [f"z{i}" for i in range(p)]
    axes = list(axes) if axes is not None else default_axis_names(n)
    reserved = [TIME_COLUMN, POSE_COLUMN, CONFIGURATION_COLUMN]
    if len(channels) != p or len(axes) != n or len({*channels, *axes, *reserved}) != p + n + len(reserved):
        names = [*channels, *axes, *reserved]
        shared = sorted({str(name) for name in names if names.count(name) > 1})
        # A table made from arrays names channels and axes alike (0, 1, 2); say which names clash.
        clash = f" ({', '.join(repr(name) for name in shared)} named twice)" if shared else ""
        raise SfmnetError(
            f"give {p} distinct channel names and {n} distinct axis names (not {', '.join(map(repr, reserved))}, "
            f"which name the time, poses and configurations arguments), not channels={channels} and axes={axes}{clash}"
        )
    columns = {name: readings[:, i] for i, name in enumerate(channels)}
    columns.update({name: known[:, i] for i, name in enumerate(axes)})
    data: dict[str, Any] = {
        "path": "<arrays given to sfmnet.calibrate>",
        "load_columns": axes if loads is not None else [],
        "axes": None if loads is not None else axes,
        "channel_columns": channels,
        "magnitude": None if magnitude is None else as_number(magnitude, "magnitude"),
    }
    for name, values, column, key, wanted in (
        ("time", time, TIME_COLUMN, "time_column", "one time (s) per reading"),
        ("poses", poses, POSE_COLUMN, "group_column", "one pose label (a number) per reading"),
        ("configurations", configurations, CONFIGURATION_COLUMN, "configuration_column", "one configuration id (a number) per reading"),
    ):
        if values is not None:
            array = seconds_from_first(values) if name == "time" else as_float_array(values, name, wanted)
            if array.shape != (f,):
                raise SfmnetError(f"{name} has shape {array.shape} but readings has {f} rows: give {wanted}")
            columns[column] = array
            data[key] = column
    from sfmnet.readers.table_file import Table

    table = Table(path=Path(data["path"]), columns=columns, text={})
    cfg = calibration_config(data, config_overrides, verbose)
    if time is not None and is_dates(time) and cfg.data.get("time_unit", "s") != "s":
        raise SfmnetError("time is given as dates or durations, which are read as seconds: leave data.time_unit out")
    return run_calibration(cfg, table, run_dir, verbose)


def is_dates(time: Any) -> bool:
    """Whether ``time`` holds dates or durations (numpy ``datetime64``/``timedelta64``, Python ``datetime``s)."""
    if hasattr(time, "detach"):
        return False
    array = np.asarray(time)
    return array.dtype.kind in "mM" or (
        array.dtype == object and array.size > 0 and isinstance(array.flat[0], (datetime.datetime, datetime.timedelta))
    )


def seconds_from_first(time: Any) -> np.ndarray:
    """Times in seconds: numbers as given, dates and durations (``datetime64``, ``timedelta64``, ``datetime``) from the
    first's (their integer counts would otherwise be read as seconds: nanoseconds from pandas)."""
    if hasattr(time, "detach"):
        return as_float_array(time, "time", "one time (s) per reading")
    try:
        array = np.asarray(time)
        if is_dates(array) and array.dtype == object:
            # A missing time (NaN or NaT beside dates) or durations among dates fail here; dates with a zone are
            # taken in UTC, which numpy notes each time.
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message="no explicit representation of timezones")
                array = array.astype("datetime64[ns]" if isinstance(array.flat[0], datetime.datetime) else "timedelta64[ns]")
    except (TypeError, ValueError) as error:
        raise SfmnetError(
            f"time cannot be read as dates ({error}): give every reading a time, all as seconds, dates or durations"
        ) from None
    if array.dtype.kind in "mM" and array.ndim == 1 and array.size:
        if np.isnat(array).any():
            raise SfmnetError("time has missing values (NaT): give every reading a time")
        return (array - array[0]) / np.timedelta64(1, "s")
    return as_float_array(array, "time", "one time (s) per reading")


def as_number(value: Any, name: str) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise SfmnetError(f"{name} is {value!r}: give a number (load units)") from None


def named_columns(values: Any, names: Sequence[str] | int | None, name: str, names_key: str) -> tuple[Any, Any]:
    """A table's columns picked by ``names`` (None or a count: all of them, named as the table does); an array as it
    is, with ``names``."""
    if isinstance(names, str):
        raise SfmnetError(f"{names_key}={names!r} is one string: give a list of names, e.g. {names_key}=[{names!r}, ...]")
    columns = column_names(values, name)
    if columns is None:
        return values, names
    if isinstance(names, int) and names != len(columns):
        raise SfmnetError(f"{names_key}={names} but {name} has {len(columns)} columns: leave {names_key} out, or pick "
                          f"the columns by name, {names_key}=[...]")
    if names is None or isinstance(names, int):
        return values, [str(column) for column in columns]
    return columns_by_name(values, list(names), name, f"the {names_key} asked for"), names


def as_matrix(values: Any, name: str) -> np.ndarray:
    """``values`` as a 2-D float64 numpy array (from numpy, torch or lists), or a one-line error."""
    array = as_float_array(values, name, "an (f, p) array of numbers")
    if array.ndim != 2 or 0 in array.shape:
        raise SfmnetError(f"{name} has shape {array.shape}: give a 2-D array, one row per sample")
    return array


def as_float_array(values: Any, name: str, wanted: str) -> np.ndarray:
    """``values`` (numpy, torch or nested lists) as float64; ragged, text or complex values are one line naming ``name``."""
    if hasattr(values, "detach"):  # a torch tensor (torch is not imported until a fit)
        values = values.detach().cpu().numpy()
    try:
        array = np.asarray(values)
    except ValueError as error:
        raise SfmnetError(f"{name} is not a numeric array ({error}): give {wanted}") from None
    if np.iscomplexobj(array):
        raise SfmnetError(f"{name} is complex: give real raw readings")
    try:
        return array.astype(np.float64)
    except (TypeError, ValueError) as error:
        columns = column_names(values, name)
        for column in columns or []:
            try:
                np.asarray(values[[column]]).astype(np.float64)
            except (TypeError, ValueError):
                # A table's time or label column left among the channels.
                pick = {"readings": "channels=[...]", "loads": "axes=[...]"}.get(name, f"{name}[[...]]")
                raise SfmnetError(
                    f"column {column!r} of {name} is not numbers ({error}): pick the columns to read by name, {pick}"
                    f"{', and give a time column as time=...' if name == 'readings' else ''}"
                ) from None
        raise SfmnetError(f"{name} is not a numeric array ({error}): give {wanted}") from None


def calibration_config(data: Mapping[str, Any], overrides: Mapping[str, Any], verbose: bool) -> DictConfig:
    """The CLI's ``experiment=calibrate_csv`` config with ``data`` set and ``overrides`` applied."""
    groups = [f"{key}={value}" for key, value in overrides.items() if key in CONFIG_GROUPS and isinstance(value, str)]
    values: dict[str, Any] = {f"data.{key}": value for key, value in data.items()}
    values["trainer.enable_progress_bar"] = verbose
    for key, value in overrides.items():
        if key in CONFIG_GROUPS and isinstance(value, str):
            continue
        values[key] = value
    return compose_run_config(["experiment=calibrate_csv", *groups], values)


def compose_run_config(choices: list[str], values: Mapping[str, Any]) -> DictConfig:
    """The CLI's config: ``choices`` (Hydra overrides: ``experiment=...``, ``model=...``), then each dotted
    key of ``values`` set (a key the config does not have is a one-line error)."""
    from hydra import compose, initialize_config_dir

    from sfmnet.cli import config_dir

    for choice in choices:
        group, option = choice.split("=", 1)
        options = sorted(path.stem for path in (Path(config_dir()) / group).glob("*.yaml"))
        if option not in options:
            raise SfmnetError(
                f"{group}={option} is not an option of the config group {group}: choose one of {', '.join(options)}"
            )
    with initialize_config_dir(config_dir=config_dir(), version_base="1.3"):
        cfg = compose(config_name="train", overrides=choices)
    for key, value in values.items():
        set_value(cfg, key, value)
    return cfg


def set_value(cfg: DictConfig, key: str, value: Any) -> None:
    """``cfg.<key> = value``; a mapping is set key by key where the config has a mapping there (keeping its
    other keys), whole where it has a leaf (e.g. ``data.mirror_hint``, null by default)."""
    node = OmegaConf.select(cfg, key, default=None)
    if isinstance(value, Mapping) and isinstance(node, DictConfig):
        for inner, item in value.items():
            set_value(cfg, f"{key}.{inner}", item)
        return
    try:
        OmegaConf.update(cfg, key, value, merge=False)
    except OmegaConfBaseException:
        raise SfmnetError(f"{key} is not a config key here: see python -m sfmnet train --help") from None


def run_calibration(cfg: DictConfig, table: Any, run_dir: str | Path | None, verbose: bool) -> Calibration:
    """Fit through :func:`sfmnet.training.run.train` into ``run_dir`` (or a temporary one) and read its calibration."""
    from hydra.utils import instantiate

    from sfmnet.cli import unwrapped_user_errors
    from sfmnet.config_values import check_config
    from sfmnet.console import lines_to_stdout
    from sfmnet.training.run import train
    from sfmnet.training.run_directory import claim_run_dir, release_run_dir

    with contextlib.ExitStack() as stack:
        if run_dir is None:
            run_dir = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="sfmnet-"))) / "run"
        claim_run_dir(Path(run_dir), "run_dir")
        stack.callback(release_run_dir, Path(run_dir))
        stack.enter_context(lines_to_stdout() if verbose else contextlib.redirect_stdout(io.StringIO()))
        # The data module is built here, before train() checks the config: check it first.
        check_config(cfg)
        with unwrapped_user_errors():
            datamodule = instantiate(cfg.data, _partial_=True)(table=table)
        train(cfg, Path(run_dir), datamodule=datamodule)
        return Calibration.load(Path(run_dir) / "calibration.json")
