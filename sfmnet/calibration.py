"""A calibration: the matrix and offsets that turn raw readings into loads, and its JSON file."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from sfmnet.data.table_columns import columns_by_name
from sfmnet.errors import SfmnetError
from sfmnet.io import refuse_overwrite, write_json_atomic
from sfmnet.readers.input_file import special_kind


def calibration_matrix(shape: torch.Tensor) -> torch.Tensor:
    """``C = pinv(S)^T = (S S^T)^-1 S``, ``n x p``: the least-squares load of a reading, ``load = C (z - o)``.

    ``S`` (``n x p``) has full row rank. The normal-equations form, unlike an SVD, has a derivative
    that stays exact when ``S``'s singular values are equal (an isotropic sensor, an accelerometer
    triad), which the error bars' Jacobian needs.
    """
    return torch.linalg.solve(shape @ shape.T, shape)


@dataclass
class Calibration:
    """``load = matrix @ (reading - offset)`` for each reading.

    Attributes:
        matrix: ``n x p`` (load units per raw unit).
        offset: ``p`` raw units (zeros where not estimated).
        channels: the ``p`` raw channel names.
        axes: the ``n`` load axis names.
        singular_values: spectrum of the readings the calibration came from.
        residual_rms: RMS of the reconstruction residual per channel entry, raw units.
        matrix_std: ``n x p`` standard errors of ``matrix`` (Cramer-Rao bound), if known.
        offset_std: ``p`` standard errors of ``offset``, if known.
        extra: anything else worth keeping in the file (method, frame, units).
    """

    matrix: torch.Tensor
    offset: torch.Tensor
    channels: list[str]
    axes: list[str]
    singular_values: list[float] = field(default_factory=list)
    residual_rms: float = float("nan")
    matrix_std: torch.Tensor | None = None
    offset_std: torch.Tensor | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def apply(self, readings: Any) -> Any:
        """Loads of a batch of readings: ``(Z - 1 o^T) C^T``, ``f x p`` in, ``f x n`` out (load units).

        A floating torch tensor gives a tensor in its dtype (integer counts: float64); anything else
        (numpy, lists) a float64 numpy array. A table (a pandas DataFrame) is read by column name, as
        ``python -m sfmnet apply`` reads a file: the calibration's channels, in any order, other columns ignored.
        """
        if not isinstance(readings, torch.Tensor):
            readings = columns_by_name(readings, self.channels, "readings", "the calibration's channels")
            # A copy where numpy's strides are negative (a reversed view), which torch cannot share.
            return self.apply(torch.from_numpy(np.ascontiguousarray(readings, dtype=np.float64))).numpy()
        if readings.ndim != 2 or readings.shape[1] != len(self.channels):
            raise SfmnetError(
                f"readings of shape {tuple(readings.shape)}: give (f, {len(self.channels)}) raw readings, "
                f"channels {', '.join(self.channels)}"
            )
        if not readings.is_floating_point():
            # Raw counts are integers; the loads are not.
            readings = readings.to(torch.float64)
        matrix = self.matrix.to(readings.dtype)
        return (readings - self.offset.to(readings.dtype)) @ matrix.T

    @property
    def warnings(self) -> list[str]:
        """What the fit's checks found (empty when the model describes the data)."""
        return list(self.extra.get("warnings", []))

    @property
    def error_bars_trustworthy(self) -> bool:
        """False when a goodness-of-fit check or the fit itself failed: ``matrix_std`` then understates the error."""
        return bool(self.extra.get("error_bars_trustworthy", True))

    def to_dict(self) -> dict[str, Any]:
        optional = {"matrix_std": self.matrix_std, "offset_std": self.offset_std}
        return {
            "matrix": self.matrix.tolist(),
            "offset": self.offset.tolist(),
            "channels": list(self.channels),
            "axes": list(self.axes),
            "singular_values": [float(v) for v in self.singular_values],
            "residual_rms": float(self.residual_rms),
            **{key: value.tolist() for key, value in optional.items() if value is not None},
            **self.extra,
        }

    def save(self, path: str | Path, overwrite: bool = False) -> None:
        """Write the calibration as JSON (the run's ``calibration.json`` format); an existing file only with ``overwrite``,
        as ``apply`` refuses to replace its output."""
        path = Path(path)
        refuse_overwrite(path, overwrite, "", "calibration.json", "pass overwrite=True")
        write_json_atomic(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a calibration file, checking its shape; a bad file raises :class:`SfmnetError`."""
        kind = special_kind(Path(path))
        if kind:
            raise SfmnetError(f"calibration file {path} is {kind}, not a regular file: give the calibration.json of a run")
        try:
            text = Path(path).read_text()
            if not text.strip():
                raise SfmnetError(f"calibration file {path} is empty: give the calibration.json of a run")
            raw = json.loads(text)
        except FileNotFoundError:
            raise SfmnetError(f"calibration file {path} does not exist: give the calibration.json of a run") from None
        except SfmnetError:
            raise
        except (OSError, ValueError) as error:
            raise SfmnetError(f"calibration file {path} cannot be read as JSON ({error}): give the calibration.json of a run") from None
        if not isinstance(raw, dict):
            raise SfmnetError(f"calibration file {path} is not a calibration (a JSON object): give the calibration.json of a run")
        known = {"matrix", "offset", "channels", "axes", "singular_values", "residual_rms", "matrix_std", "offset_std"}
        missing = sorted({"matrix", "offset", "channels", "axes"} - set(raw))
        if missing:
            raise SfmnetError(f"calibration file {path} lacks {', '.join(missing)}: give the calibration.json of a run")
        if not all(isinstance(raw[key], list) and all(isinstance(name, str) for name in raw[key]) for key in ("channels", "axes")):
            raise SfmnetError(f"calibration file {path}: channels and axes must be lists of names: give the calibration.json of a run")
        for key in ("channels", "axes"):
            twice = sorted({name for name in raw[key] if raw[key].count(name) > 1})
            if twice:
                raise SfmnetError(
                    f"calibration file {path} names {key[:-1]} {', '.join(twice)} twice: each {key[:-1]} has one column; "
                    "give the calibration.json of a run"
                )
        matrix = numbers(raw, "matrix", path)
        offset = numbers(raw, "offset", path)
        if matrix.ndim != 2 or matrix.shape != (len(raw["axes"]), len(raw["channels"])) or offset.shape != (len(raw["channels"]),):
            raise SfmnetError(
                f"calibration file {path} is inconsistent: matrix must be axes x channels and offset one per channel"
            )
        return cls(
            matrix=matrix,
            offset=offset,
            channels=list(raw["channels"]),
            axes=list(raw["axes"]),
            singular_values=numbers(raw, "singular_values", path, finite=False).tolist() if "singular_values" in raw else [],
            residual_rms=float(numbers(raw, "residual_rms", path, finite=False)) if "residual_rms" in raw else float("nan"),
            matrix_std=numbers(raw, "matrix_std", path, finite=False) if "matrix_std" in raw else None,
            offset_std=numbers(raw, "offset_std", path, finite=False) if "offset_std" in raw else None,
            extra={k: v for k, v in raw.items() if k not in known},
        )


def numbers(raw: dict[str, Any], key: str, path: str | Path, finite: bool = True) -> torch.Tensor:
    """``raw[key]`` as float64; text, uneven rows, or (where ``finite``) NaN, infinity or null are one line naming the
    file. Where not ``finite``, null (an undefined figure, as :func:`~sfmnet.io.write_json_atomic` writes NaN and
    infinity) reads as NaN."""
    value = raw[key]
    if not finite:
        value = null_as_nan(value)
    try:
        values = torch.tensor(value, dtype=torch.float64)
    except (TypeError, ValueError, RuntimeError):
        raise SfmnetError(
            f"calibration file {path}: {key} holds something other than numbers (text, null or uneven rows): "
            "give the calibration.json of a run"
        ) from None
    if finite and not torch.isfinite(values).all():
        raise SfmnetError(
            f"calibration file {path}: {key} holds NaN or infinite values, which would turn every load into NaN: "
            "give the calibration.json of a successful run"
        )
    return values


def null_as_nan(value: Any) -> Any:
    """``value`` (a number or nested lists of them) with every None as NaN."""
    if value is None:
        return math.nan
    if isinstance(value, list):
        return [null_as_nan(item) for item in value]
    return value
