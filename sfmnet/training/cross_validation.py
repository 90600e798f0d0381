"""Leave-one-group-out errors (e.g. leave one pose out on real recordings): every method refitted per fold."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
from hydra.utils import instantiate
from matplotlib import pyplot as plt
from matplotlib.figure import Figure
from omegaconf import DictConfig

from sfmnet.data.calibration_datamodule import FixedCalibrationDataModule
from sfmnet.data.recording import CalibrationData
from sfmnet.eval.held_out import load_errors
from sfmnet.io import write_csv_atomic
from sfmnet.training.fitting import fit
from sfmnet.training.progress import each_with_progress


@dataclass(frozen=True)
class FoldError:
    method: str
    group: int
    rows: int
    errors: dict[str, float]


def held_out_groups(data: CalibrationData, recording: str) -> list[int]:
    """Groups of ``recording`` with no known load: holding out a known pose would change the method, not test it."""
    rec = data.recordings[recording]
    if rec.groups is None:
        raise ValueError(f"recording {recording} has no groups")
    known_groups = set(rec.groups[rec.known].tolist())
    return sorted(set(rec.groups.tolist()) - known_groups)


def leave_one_group_out(
    cfg: DictConfig, data: CalibrationData, models: dict[str, DictConfig], main_recording: str, progress: bool
) -> list[FoldError]:
    """Refit every method without each held-out group and measure its load error on that group.

    The groups held out are those of the main method's recording that carry no known load,
    so every method is scored on the same rows. The error is against the rows' true loads.
    """
    folds = []
    for group in each_with_progress(held_out_groups(data, main_recording), "leave one group out", progress):
        fold = FixedCalibrationDataModule(data.without_group(group))
        for name, model_cfg in models.items():
            model = instantiate(model_cfg)
            fit(model, cfg, fold, logger=False, enable_checkpointing=False, enable_progress_bar=False, callbacks=[])
            recording = data.recordings[model.recording]
            held = recording.groups == group
            truth = recording.true_loads if recording.true_loads is not None else recording.loads
            calibration = model.to_calibration(data.channels, data.axes)
            errors = load_errors(calibration, recording.readings[held], truth[held])
            folds.append(FoldError(name, group, int(held.sum()), errors))
    return folds


def summarise_folds(folds: list[FoldError]) -> dict[str, dict[str, float]]:
    """Per method, the RMS over all held-out rows: ``{method: {force_rms, [torque_rms]}}``."""
    summary: dict[str, dict[str, float]] = {}
    for method in dict.fromkeys(f.method for f in folds):
        mine = [f for f in folds if f.method == method]
        rows = sum(f.rows for f in mine)
        summary[method] = {
            key: (sum(f.errors[key] ** 2 * f.rows for f in mine) / rows) ** 0.5 for key in mine[0].errors
        }
    return summary


def write_folds(folds: list[FoldError], path: Path) -> None:
    keys = list(folds[0].errors)
    write_csv_atomic(path, ["method", "group", "rows", *keys], [[f.method, f.group, f.rows, *f.errors.values()] for f in folds])


def folds_figure(folds: list[FoldError], unit: str) -> Figure:
    """Held-out force (and torque) error per group, methods side by side."""
    keys = list(folds[0].errors)
    methods = list(dict.fromkeys(f.method for f in folds))
    groups = sorted({f.group for f in folds})
    figure, axes = plt.subplots(1, len(keys), figsize=(5 * len(keys), 3.5), squeeze=False)
    width = 0.8 / len(methods)
    for axis, key in zip(axes[0], keys):
        for i, method in enumerate(methods):
            values = {f.group: f.errors[key] for f in folds if f.method == method}
            positions = torch.arange(len(groups)) + i * width
            axis.bar(positions.tolist(), [values[g] for g in groups], width=width, label=method)
        axis.set_xticks([g + 0.4 - width / 2 for g in range(len(groups))], [str(g) for g in groups])
        axis.set_xlabel("held-out group (pose)")
        axis.set_ylabel(f"{key} ({unit.split(', ')[0] if key == 'force_rms' else 'N m'})")
        axis.legend(fontsize=8)
    figure.suptitle("leave-one-group-out error")
    figure.tight_layout()
    return figure
